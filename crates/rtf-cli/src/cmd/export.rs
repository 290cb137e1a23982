//! `rtf export`: a network with its weights as a deployment file.
//!
//! - `torchscript`: the eval-mode forward traced by libtorch's JIT tracer (tch
//!   `CModule::create_by_tracing`), weights frozen in, saved as a TorchScript archive that
//!   `torch.jit.load` (Python) and `torch::jit::load` (C++) run. The trace is checked against
//!   the eager network on a second input before anything is written: a network whose forward
//!   is not a fixed graph for the traced size is refused.
//! - `onnx`: that TorchScript module through PyTorch's TorchScript-based ONNX exporter in the
//!   project's `.venv` (`scripts/export_onnx.py`), checked with `onnx.checker` and onnxruntime.
//!
//! Both carry the input convention as metadata: `extra/rtf.json` in the TorchScript archive
//! (`torch.jit.load(path, _extra_files={"rtf.json": ""})`), `metadata_props` in the ONNX model.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};
use rtf_models::fast::Precision;
use tch::{CModule, Device, Kind, Tensor};

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
    /// Weights and arithmetic inside the graph; input and logits stay fp32.
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

/// Schema tag of the metadata.
pub const EXPORT_SCHEMA: &str = "rtf-export/1";

/// The metadata written into the exported file.
/// Class names and colours (the weights' record, else MF's or Freiburg's set of that count)
/// and the thermal rule the network was trained with, where known.
struct Trained {
    classes: Option<rtf_core::ClassSet>,
    /// Where the class names come from (the weights' record, the run's dataset, or an
    /// assumption from the class count), written as `class_names_from`.
    from: String,
    thermal: Option<String>,
}

impl Trained {
    fn of(record: Option<rtf_data::TrainedOn>, weights: &Path, classes: i64) -> Self {
        let thermal = record
            .as_ref()
            .and_then(|t| t.thermal.as_ref())
            .map(|t| t.describe());
        let (classes, from) = match record {
            Some(t) => (Some(t.classes), "the weights' record".to_string()),
            None => match class_set_of_run(weights, classes) {
                Some((set, from)) => (Some(set), from),
                None => (None, "unknown".to_string()),
            },
        };
        Self {
            classes,
            from,
            thermal,
        }
    }
}

fn metadata(
    network: &dyn rtf_models::Network,
    trained: &Trained,
    in_channels: i64,
    inputs: rtf_models::Modality,
    size: (usize, usize),
    precision: Precision,
) -> serde_json::Value {
    let convention = network.input_convention();
    let classes = network.num_classes();
    let class_names = trained.classes.as_ref().map(|set| set.names());
    let class_colors = trained
        .classes
        .as_ref()
        .map(|set| set.classes.iter().map(|c| c.color).collect::<Vec<_>>());
    let scaling = match convention {
        rtf_core::InputConvention::UnitRange => {
            "R,G,B = pixel / 255; T = thermal in [0, 1] (MF: byte / 255)".to_string()
        }
        rtf_core::InputConvention::MeanStd { mean, std } => format!(
            "R,G,B = (pixel / 255 - {mean}) / {std}; T = (thermal in [0, 1] - {mean}) / {std}"
        ),
    };
    let (layout, scaling) = if in_channels == 4 {
        ("NCHW, channels R, G, B, T".to_string(), scaling)
    } else {
        (
            format!("NCHW, {in_channels} channels: the segmenter's per-class softmax"),
            "probabilities in [0, 1]".to_string(),
        )
    };
    let outputs = network.num_classes();
    serde_json::json!({
        "schema": EXPORT_SCHEMA,
        "model": network.name(),
        "num_classes": classes,
        "class_names": class_names,
        "class_names_from": trained.from,
        "class_colors": class_colors,
        // How the T channel was made [0, 1] in training (a dataset.yaml's `thermal:`).
        "thermal": trained.thermal,
        "input": {
            "name": "input",
            "shape": [1, in_channels, size.0, size.1],
            "dtype": "float32",
            "layout": layout,
            "convention": convention,
            "scaling": scaling,
            // A network trained on one modality: the graph zeroes the channels it does not
            // see, so every input is fed the same 4-channel way.
            "sees": inputs.name(),
        },
        "output": {"name": "logits", "shape": [1, outputs, size.0, size.1],
                   "dtype": "float32", "meaning": "class scores; argmax over dim 1 = class id"},
        "precision": format!("{precision:?}").to_lowercase(),
    })
}

/// The class set of weights without a record, and where it comes from: the dataset of the run
/// folder the weights sit in (the classes its config.json records, else its dataset's: a
/// dataset.yaml's own names), else MF's or Freiburg's names when the class count is theirs
/// (said as an assumption), else none.
fn class_set_of_run(weights: &Path, classes: i64) -> Option<(rtf_core::ClassSet, String)> {
    let dir = weights.parent()?;
    // `--weights final.safetensors` inside the run folder: the folder is the current one.
    let folder = match dir.as_os_str().is_empty() {
        true => Path::new("."),
        false => dir,
    };
    let run_classes = rtf_train::TrainedRun::open(folder)
        .ok()
        .and_then(|run| run.class_set());
    if let Some(set) = run_classes.filter(|set| set.len() as i64 == classes) {
        let config_path = dir.join(rtf_run::CONFIG_FILE);
        return Some((
            set,
            format!("the run's dataset ({})", config_path.display()),
        ));
    }
    [rtf_core::ClassSet::mf(), rtf_core::ClassSet::freiburg()]
        .into_iter()
        .find(|set| set.len() as i64 == classes)
        .map(|set| {
            let from = format!(
                "assumed from the class count: {}'s {classes} classes",
                set.name
            );
            (set, from)
        })
}

/// Adds `<archive>/extra/rtf.json` to a TorchScript archive written by libtorch.
fn add_extra_file(archive: &Path, name: &str, contents: &[u8]) -> Result<()> {
    let file = std::fs::File::options()
        .read(true)
        .write(true)
        .open(archive)
        .with_context(|| format!("opening {}", archive.display()))?;
    let prefix = {
        let mut zip = zip::ZipArchive::new(&file)
            .with_context(|| format!("{}: not a TorchScript archive", archive.display()))?;
        let first = zip.by_index(0)?.name().to_string();
        first
            .split_once('/')
            .map(|(p, _)| p.to_string())
            .with_context(|| format!("{}: unexpected archive layout", archive.display()))?
    };
    let mut zip = zip::ZipWriter::new_append(file)?;
    let options = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Stored)
        .with_alignment(64);
    zip.start_file(format!("{prefix}/extra/{name}"), options)?;
    zip.write_all(contents)?;
    zip.finish()?;
    Ok(())
}

/// The project's Python: `$RTF_PYTHON`, else `.venv/bin/python` in a folder above the `rtf`
/// binary or the current directory.
fn project_python() -> Result<PathBuf> {
    if let Some(p) = std::env::var_os("RTF_PYTHON") {
        return Ok(PathBuf::from(p));
    }
    let mut starts = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        starts.push(exe);
    }
    if let Ok(cwd) = std::env::current_dir() {
        starts.push(cwd);
    }
    for start in starts {
        for dir in start.ancestors() {
            let python = dir.join(".venv/bin/python");
            if python.exists() {
                return Ok(python);
            }
        }
    }
    bail!(
        "ONNX export needs the project's .venv (PyTorch's ONNX exporter): run `cargo xtask \
         setup`, or set RTF_PYTHON to a Python with torch and onnx"
    )
}

/// Traces `network` at `size` and checks the trace against the eager forward.
fn trace(
    network: &dyn rtf_models::Network,
    in_channels: i64,
    size: (usize, usize),
    precision: Precision,
) -> Result<CModule> {
    let (h, w) = (size.0 as i64, size.1 as i64);
    network
        .check_input(&[1, in_channels, h, w])
        .map_err(|e| anyhow::anyhow!("--size {}x{}: {e}", size.0, size.1))?;
    let _guard = tch::no_grad_guard();
    let kind = precision.kind();
    // fp32 graphs get no casts at all (a cast's output carries no type for ONNX export).
    let forward = |x: &Tensor| {
        if kind == Kind::Float {
            network.forward_t(x, false)
        } else {
            network
                .forward_t(&x.to_kind(kind), false)
                .to_kind(Kind::Float)
        }
    };
    let example = Tensor::rand([1, in_channels, h, w], (Kind::Float, Device::Cpu));
    // A panic inside libtorch's tracing callback must not unwind through C++: catch it,
    // return the input as a placeholder output and report the panic afterwards.
    let mut failure: Option<String> = None;
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let traced = CModule::create_by_tracing("rtf", "forward", &[example], &mut |xs| {
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| forward(&xs[0]))) {
            Ok(out) => vec![out],
            Err(payload) => {
                failure = Some(
                    payload
                        .downcast_ref::<String>()
                        .cloned()
                        .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                        .unwrap_or_else(|| "panic".into()),
                );
                vec![xs[0].shallow_clone()]
            }
        }
    });
    std::panic::set_hook(hook);
    if let Some(why) = failure {
        let first_line = why.lines().next().unwrap_or_default().to_string();
        bail!("{} cannot be traced: {first_line}", network.name());
    }
    let module = traced.with_context(|| format!("{}: the JIT tracer failed", network.name()))?;
    // A second input: a graph that baked in data-dependent choices gives other logits.
    // Its values span [-0.5, 2.5] (mean 1), unlike the example's [0, 1]: a branch on the input
    // statistics shows up.
    let probe = Tensor::rand([1, in_channels, h, w], (Kind::Float, Device::Cpu)) * 3.0 - 0.5;
    let eager = forward(&probe);
    let traced = module.forward_ts(&[&probe])?;
    let delta = (eager - traced).abs().max().double_value(&[]);
    let tolerance = if kind == Kind::Float { 1e-4 } else { 1e-2 };
    if delta.is_nan() || delta > tolerance {
        bail!(
            "{} cannot be traced: the traced graph's logits differ from the network's by {delta:.3e} \
             on a second input (forward depends on the input's values)",
            network.name()
        );
    }
    Ok(module)
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
    let (classes, record) = class_count(&args)?;
    let super::LoadedNetwork {
        mut vs,
        net: network,
        inputs,
    } = load_network(
        &args.model,
        classes,
        &args.weights,
        Device::Cpu,
        None,
        false,
        args.inputs,
    )
    .with_context(|| format!("loading {} into {}", args.weights.display(), args.model))?;
    // Weights become constants of the graph: no autograd on them.
    vs.freeze();
    if args.precision == Precision::Bf16 {
        // bf16 weights; the traced graph casts its input to bf16 and its logits back to fp32.
        vs.bfloat16();
    }
    let network = network.as_ref();
    // Every segmentation network reads R, G, B, T.
    let in_channels = 4;
    let module = trace(network, in_channels, args.size, args.precision)?;
    let meta = metadata(
        network,
        &Trained::of(record, &args.weights, classes),
        in_channels,
        inputs,
        args.size,
        args.precision,
    );
    let meta_bytes = serde_json::to_vec_pretty(&meta)?;
    let save_torchscript = |path: &Path| -> Result<()> {
        module
            .save(path)
            .with_context(|| format!("saving TorchScript to {}", path.display()))?;
        // `{:#}`: the whole chain, as the atomic writer shows only the top error.
        add_extra_file(path, "rtf.json", &meta_bytes).map_err(|e| anyhow::anyhow!("{e:#}"))
    };
    match args.format {
        Format::Torchscript => {
            rtf_core::write_atomic(&args.out, |tmp| save_torchscript(tmp))
                .map_err(|e| anyhow::anyhow!("{e:#}"))?;
        }
        Format::Onnx => {
            let python = project_python()?;
            let dir = tempfile::tempdir()?;
            let ts = dir.path().join("module.pt");
            save_torchscript(&ts)?;
            torchscript_to_onnx(&python, &ts, &args.out, in_channels, args.size)?;
        }
    }
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

/// Converts the TorchScript file `ts` to ONNX at `out` (written atomically) with PyTorch's
/// exporter (`scripts/export_onnx.py` under `python`), traced at `size` (height,
/// width, as `--size`).
fn torchscript_to_onnx(
    python: &Path,
    ts: &Path,
    out: &Path,
    in_channels: i64,
    size: (usize, usize),
) -> Result<()> {
    rtf_core::write_atomic(out, |tmp| -> Result<()> {
        let output = Command::new(python)
            .arg("-c")
            .arg(include_str!("../../../../scripts/export_onnx.py"))
            .arg(ts)
            .arg(tmp)
            .arg(in_channels.to_string())
            .arg(size.0.to_string())
            .arg(size.1.to_string())
            .output()
            .with_context(|| format!("running {}", python.display()))?;
        print!("{}", String::from_utf8_lossy(&output.stdout));
        if !output.status.success() {
            bail!(
                "PyTorch's ONNX export ({}) failed: {}",
                python.display(),
                String::from_utf8_lossy(&output.stderr).trim()
            );
        }
        Ok(())
    })
    .map_err(|e| anyhow::anyhow!("{}: {e:#}", out.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Doubles the first two channels when the input's mean is above 0.75, else negates them:
    /// a trace records only the branch taken.
    #[derive(Debug)]
    struct Branchy {
        panic: bool,
    }

    impl tch::nn::ModuleT for Branchy {
        fn forward_t(&self, xs: &Tensor, _train: bool) -> Tensor {
            if self.panic {
                panic!("this network has no forward");
            }
            let head = xs.narrow(1, 0, 2);
            if xs.mean(Kind::Float).double_value(&[]) > 0.75 {
                head * 2.0
            } else {
                -head
            }
        }
    }

    impl rtf_models::Network for Branchy {
        fn input_convention(&self) -> rtf_core::InputConvention {
            rtf_core::InputConvention::UnitRange
        }
        fn num_classes(&self) -> i64 {
            2
        }
        fn size_multiple(&self) -> i64 {
            8
        }
        fn name(&self) -> String {
            "branchy".into()
        }
    }

    #[test]
    fn a_network_that_cannot_be_traced_is_refused() {
        let err = trace(&Branchy { panic: false }, 4, (16, 16), Precision::Fp32)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("branchy cannot be traced"), "{err}");
        let err = trace(&Branchy { panic: true }, 4, (16, 16), Precision::Fp32)
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("branchy cannot be traced: this network has no forward"),
            "{err}"
        );
        let err = trace(&Branchy { panic: false }, 4, (12, 16), Precision::Fp32)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("--size 12x16"), "{err}");
    }

    #[test]
    fn size_is_height_first() {
        assert_eq!(parse_hw("480x640"), Ok((480, 640)));
        assert!(parse_hw("480").unwrap_err().contains("HxW"));
    }
}
