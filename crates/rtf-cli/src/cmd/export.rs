//! `rtf export`: a network with its weights as a deployment file (TorchScript or ONNX, with
//! its input convention and classes as metadata; rtf_models::io::export). Parses its flags,
//! loads the network, exports it and prints what it wrote.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use rtf_models::fast::Precision;
use rtf_models::io::export::Export;
use rtf_models::io::loaded::NetworkRequest;
use tch::Device;

use super::load_network;

#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
pub enum Format {
    Torchscript,
    Onnx,
}

#[derive(clap::Args)]
pub struct Args {
    /// Network name (see `rtf models`).
    #[arg(long)]
    pub model: String,
    /// Weights (safetensors, reference names), e.g. RUN/final.safetensors.
    #[arg(long)]
    pub weights: PathBuf,
    /// Output file (.pt for TorchScript, .onnx for ONNX).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, value_enum)]
    pub format: Format,
    /// Input size HxW the graph is traced at (height first), e.g. 480x640.
    #[arg(long, value_parser = parse_hw, default_value = "480x640")]
    pub size: (usize, usize),
    /// Weights and arithmetic inside the graph (fp32 or bf16: the export traces on the CPU,
    /// which runs no fp16); input and logits stay fp32.
    #[arg(long, default_value = "fp32", value_parser = Precision::parse_inference)]
    pub precision: Precision,
    /// Class count of the weights. Default: the class set the weights record (rtf train writes
    /// it), else the network's usual count (see `rtf models`).
    #[arg(long)]
    pub classes: Option<i64>,
    /// Channels the network sees (rgb_t, rgb, thermal; the others are zeroed inside the
    /// graph). Default: what the weights file records, else all four.
    #[arg(long, value_parser = rtf_models::Modality::parse)]
    pub inputs: Option<rtf_models::Modality>,
}

/// Parses `HxW` (height first).
fn parse_hw(text: &str) -> Result<(usize, usize), String> {
    super::parse_size(text).map_err(|e| e.replace("WxH", "HxW").replace("640x480", "480x640"))
}

/// `--out` naming the weights it reads (also through `..` or a link) is refused before any
/// work: the export would replace them.
fn refuse_overwriting_weights(args: &Args) -> Result<()> {
    if let (Ok(out), Ok(weights)) = (args.out.canonicalize(), args.weights.canonicalize()) {
        if out == weights {
            bail!(
                "--out {}: is the --weights file; refusing to overwrite the weights with the export",
                args.out.display()
            );
        }
    }
    Ok(())
}

/// `--classes`, else the count the weights record, else the network's usual count; with the
/// weights' record. A `--classes` that contradicts the record is refused.
fn class_count(args: &Args) -> Result<(i64, Option<rtf_data::TrainedOn>)> {
    let record = super::trained_on(&args.weights)?;
    let recorded = record.as_ref().map(|t| t.classes.len() as i64);
    if let (Some(asked), Some(recorded)) = (args.classes, &record) {
        anyhow::ensure!(
            asked == recorded.classes.len() as i64,
            "{}: trained on {}; --classes {asked} does not fit (drop --classes)",
            args.weights.display(),
            rtf_data::trained_on::list(&recorded.classes)
        );
    }
    let classes = args
        .classes
        .or(recorded)
        .unwrap_or_else(|| rtf_models::default_num_classes(&args.model));
    Ok((classes, record))
}

pub fn run(args: Args) -> Result<()> {
    refuse_overwriting_weights(&args)?;
    rtf_models::fast::check_precision_on(args.precision, Device::Cpu)?;
    let (classes, record) = class_count(&args)?;
    let rtf_models::io::loaded::LoadedNetwork {
        mut vs,
        net: network,
        inputs,
        ..
    } = load_network(&NetworkRequest {
        name: &args.model,
        num_classes: classes,
        weights: &args.weights,
        device: Device::Cpu,
        precision: None,
        kernels: rtf_models::fast::InferenceKernels::unmeasured(),
        foreign_weights: false,
        inputs: args.inputs,
    })
    .with_context(|| format!("loading {} into {}", args.weights.display(), args.model))?;
    // Weights become constants of the graph: no autograd on them.
    vs.freeze();
    if args.precision == Precision::Bf16 {
        // bf16 weights; the traced graph casts its input to bf16 and its logits back to fp32.
        vs.bfloat16();
    }
    let labels = rtf_train::folder::export_labels(record, &args.weights, classes);
    let format = match args.format {
        Format::Torchscript => rtf_models::io::export::Format::Torchscript,
        Format::Onnx => rtf_models::io::export::Format::Onnx,
    };
    // The Python of the ONNX exporter: `$RTF_PYTHON`, else the library's search for `.venv`.
    let python = std::env::var_os("RTF_PYTHON").map(PathBuf::from);
    let spec = Export {
        format,
        out: &args.out,
        size: args.size,
        precision: args.precision,
        inputs,
        labels: &labels,
        python: python.as_deref(),
    };
    rtf_models::io::export::export(network.as_ref(), &spec)?;
    println!(
        "{} ({}x{}, {:?}) -> {} ({:?})",
        args.model,
        args.size.0,
        args.size.1,
        args.precision,
        args.out.display(),
        args.format
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn size_is_height_first() {
        assert_eq!(parse_hw("480x640"), Ok((480, 640)));
        assert!(parse_hw("480").unwrap_err().contains("HxW"));
    }
}
