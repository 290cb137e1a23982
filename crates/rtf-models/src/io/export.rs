//! Export of a network with its weights as a deployment file (`rtf export`).
//!
//! - TorchScript: the eval-mode forward traced by libtorch's JIT tracer (tch
//!   `CModule::create_by_tracing`), weights frozen in, saved as a TorchScript archive that
//!   `torch.jit.load` (Python) and `torch::jit::load` (C++) run. The trace is checked against
//!   the eager network on a second input before anything is written: a network whose forward
//!   is not a fixed graph for the traced size is refused.
//! - ONNX: that TorchScript module through PyTorch's TorchScript-based ONNX exporter in the
//!   project's `.venv` (`export_onnx.py`, beside this file), checked with `onnx.checker` and onnxruntime.
//!
//! Both carry the input convention as metadata: `extra/rtf.json` in the TorchScript archive
//! (`torch.jit.load(path, _extra_files={"rtf.json": ""})`), `metadata_props` in the ONNX model.
//! It lives beside the networks it traces; what a network was trained on (its class names)
//! comes from the caller ([`Labels`]), since only a run folder knows it.

use rtf_amp::PrecisionOnDevice;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

use tch::{CModule, Device, Kind, Tensor};

use rtf_core::refusal::{flattened, refused, Refusal};

use crate::fast::Precision;
use crate::Network;

/// Why an export failed. Each message reads as `rtf export` says it; a wrapped error keeps
/// its own message as the source.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The network or what was asked cannot be exported, or failed on the file or step the
    /// message names.
    #[error(transparent)]
    Request(#[from] Refusal),
    #[error(transparent)]
    Tensor(#[from] tch::TchError),
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Zip(#[from] zip::result::ZipError),
    #[error(transparent)]
    Json(#[from] serde_json::Error),
}

/// The deployment file's kind.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Format {
    Torchscript,
    Onnx,
}

/// Schema tag of the metadata.
pub const EXPORT_SCHEMA: &str = "rtf-export/1";

/// What the network was trained on, for the metadata: class names and colours (the weights'
/// record, else MF's or Freiburg's set of that count) and the thermal rule, where known.
pub struct Labels {
    pub classes: Option<rtf_core::ClassSet>,
    /// Where the class names come from (the weights' record, the run's dataset, or an
    /// assumption from the class count), written as `class_names_from`.
    pub from: String,
    pub thermal: Option<String>,
}

/// What to export and how: `size` (height, width) the graph is traced at, the arithmetic
/// inside it, and the channels the network sees (the others zeroed inside the graph).
pub struct Export<'a> {
    pub format: Format,
    pub out: &'a Path,
    pub size: (usize, usize),
    pub precision: Precision,
    pub inputs: crate::Modality,
    pub labels: &'a Labels,
    /// The Python that runs PyTorch's ONNX exporter (ONNX only; `rtf export` passes
    /// `$RTF_PYTHON`). `None`: `.venv/bin/python` in a folder above the running binary or
    /// the current directory.
    pub python: Option<&'a Path>,
}

/// Every segmentation network reads R, G, B, T.
const IN_CHANNELS: i64 = 4;

fn input_description(convention: rtf_core::InputConvention, in_channels: i64) -> (String, String) {
    let scaling = match convention {
        rtf_core::InputConvention::UnitRange => {
            "R,G,B = pixel / 255; T = thermal in [0, 1] (MF: byte / 255)".to_string()
        }
        rtf_core::InputConvention::MeanStd { mean, std } => format!(
            "R,G,B = (pixel / 255 - {mean}) / {std}; T = (thermal in [0, 1] - {mean}) / {std}"
        ),
    };
    if in_channels == 4 {
        ("NCHW, channels R, G, B, T".to_string(), scaling)
    } else {
        (
            format!("NCHW, {in_channels} channels: the segmenter's per-class softmax"),
            "probabilities in [0, 1]".to_string(),
        )
    }
}

fn metadata(network: &dyn Network, spec: &Export, in_channels: i64) -> serde_json::Value {
    let (size, labels) = (spec.size, spec.labels);
    let convention = network.input_convention();
    let classes = network.num_classes();
    let class_names = labels.classes.as_ref().map(|set| set.names());
    let class_colors = labels
        .classes
        .as_ref()
        .map(|set| set.classes.iter().map(|c| c.color).collect::<Vec<_>>());
    let (layout, scaling) = input_description(convention, in_channels);
    let outputs = network.num_classes();
    serde_json::json!({
        "schema": EXPORT_SCHEMA,
        "model": network.name(),
        "num_classes": classes,
        "class_names": class_names,
        "class_names_from": labels.from,
        "class_colors": class_colors,
        // How the T channel was made [0, 1] in training (a dataset.yaml's `thermal:`).
        "thermal": labels.thermal,
        "input": {
            "name": "input",
            "shape": [1, in_channels, size.0, size.1],
            "dtype": "float32",
            "layout": layout,
            "convention": convention,
            "scaling": scaling,
            // A network trained on one modality: the graph zeroes the channels it does not
            // see, so every input is fed the same 4-channel way.
            "sees": spec.inputs.name(),
        },
        "output": {"name": "logits", "shape": [1, outputs, size.0, size.1],
                   "dtype": "float32", "meaning": "class scores; argmax over dim 1 = class id"},
        "precision": format!("{:?}", spec.precision).to_lowercase(),
    })
}

/// The TorchScript archive's first entry's folder (every entry sits under it).
fn archive_prefix(file: &std::fs::File, archive: &Path) -> Result<String, ExportError> {
    let mut zip = zip::ZipArchive::new(file).map_err(|e| {
        Refusal::because(
            format!("{}: not a TorchScript archive", archive.display()),
            e,
        )
    })?;
    let first = zip.by_index(0)?.name().to_string();
    first
        .split_once('/')
        .map(|(p, _)| p.to_string())
        .ok_or_else(|| refused(format!("{}: unexpected archive layout", archive.display())))
}

/// Adds `<archive>/extra/rtf.json` to a TorchScript archive written by libtorch.
fn add_extra_file(archive: &Path, name: &str, contents: &[u8]) -> Result<(), ExportError> {
    let file = std::fs::File::options()
        .read(true)
        .write(true)
        .open(archive)
        .map_err(|e| Refusal::because(format!("opening {}", archive.display()), e))?;
    let prefix = archive_prefix(&file, archive)?;
    let mut zip = zip::ZipWriter::new_append(file)?;
    let options = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Stored)
        .with_alignment(64);
    zip.start_file(format!("{prefix}/extra/{name}"), options)?;
    zip.write_all(contents)?;
    zip.finish()?;
    Ok(())
}

/// The project's Python: `given`, else `.venv/bin/python` in a folder above the running
/// binary or the current directory.
fn project_python(given: Option<&Path>) -> Result<PathBuf, ExportError> {
    if let Some(p) = given {
        return Ok(p.to_path_buf());
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
    Err(refused(
        "ONNX export needs the project's .venv (PyTorch's ONNX exporter): run `cargo xtask \
         setup`, or set RTF_PYTHON to a Python with torch and onnx",
    ))
}

/// libtorch's JIT trace of `forward` on `example`, and the message of a panic inside it: a
/// panic inside libtorch's tracing callback must not unwind through C++, so it is caught, the
/// input returned as a placeholder output and the panic reported afterwards.
fn trace_catching(
    forward: &dyn Fn(&Tensor) -> Tensor,
    example: Tensor,
) -> (Result<CModule, tch::TchError>, Option<String>) {
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
    (traced, failure)
}

/// Traces `network` at `size` and checks the trace against the eager forward.
pub fn trace(
    network: &dyn crate::Network,
    in_channels: i64,
    size: (usize, usize),
    precision: Precision,
) -> Result<CModule, ExportError> {
    let (h, w) = (size.0 as i64, size.1 as i64);
    network
        .check_input(&[1, in_channels, h, w])
        .map_err(|e| Refusal::Refused(format!("--size {}x{}: {e}", size.0, size.1)))?;
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
    let (traced, failure) = trace_catching(&forward, example);
    if let Some(why) = failure {
        let first_line = why.lines().next().unwrap_or_default().to_string();
        return Err(refused(format!(
            "{} cannot be traced: {first_line}",
            network.name()
        )));
    }
    let module = traced
        .map_err(|e| Refusal::because(format!("{}: the JIT tracer failed", network.name()), e))?;
    // A second input: a graph that baked in data-dependent choices gives other logits.
    // Its values span [-0.5, 2.5] (mean 1), unlike the example's [0, 1]: a branch on the input
    // statistics shows up.
    let probe = Tensor::rand([1, in_channels, h, w], (Kind::Float, Device::Cpu)) * 3.0 - 0.5;
    let eager = forward(&probe);
    let traced = module.forward_ts(&[&probe])?;
    let delta = (eager - traced).abs().max().double_value(&[]);
    let tolerance = if kind == Kind::Float { 1e-4 } else { 1e-2 };
    if delta.is_nan() || delta > tolerance {
        return Err(refused(format!(
            "{} cannot be traced: the traced graph's logits differ from the network's by {delta:.3e} \
             on a second input (forward depends on the input's values)",
            network.name()
        )));
    }
    Ok(module)
}

/// Traces `network` (its weights frozen, in `spec.precision`) and writes `spec.out` with its
/// metadata.
pub fn export(network: &dyn Network, spec: &Export) -> Result<(), ExportError> {
    let module = trace(network, IN_CHANNELS, spec.size, spec.precision)?;
    let meta = metadata(network, spec, IN_CHANNELS);
    let meta_bytes = serde_json::to_vec_pretty(&meta)?;
    let save_torchscript = |path: &Path| -> Result<(), ExportError> {
        module.save(path).map_err(|e| {
            Refusal::because(format!("saving TorchScript to {}", path.display()), e)
        })?;
        // Flattened: the atomic writer shows only the top error.
        add_extra_file(path, "rtf.json", &meta_bytes).map_err(|e| refused(flattened(&e)))
    };
    match spec.format {
        Format::Torchscript => {
            rtf_core::write_atomic(spec.out, save_torchscript).map_err(|e| refused(e.to_string()))
        }
        Format::Onnx => {
            let python = project_python(spec.python)?;
            let dir = tempfile::tempdir()?;
            let ts = dir.path().join("module.pt");
            save_torchscript(&ts)?;
            torchscript_to_onnx(&python, &ts, spec.out, IN_CHANNELS, spec.size)
        }
    }
}

/// Converts the TorchScript file `ts` to ONNX at `out` (written atomically) with PyTorch's
/// exporter (`export_onnx.py`, beside this file, under `python`), traced at `size` (height, width).
fn torchscript_to_onnx(
    python: &Path,
    ts: &Path,
    out: &Path,
    in_channels: i64,
    size: (usize, usize),
) -> Result<(), ExportError> {
    rtf_core::write_atomic(out, |tmp| -> Result<(), ExportError> {
        let output = Command::new(python)
            .arg("-c")
            .arg(include_str!("export_onnx.py"))
            .arg(ts)
            .arg(tmp)
            .arg(in_channels.to_string())
            .arg(size.0.to_string())
            .arg(size.1.to_string())
            .output()
            .map_err(|e| Refusal::because(format!("running {}", python.display()), e))?;
        print!("{}", String::from_utf8_lossy(&output.stdout));
        if !output.status.success() {
            return Err(refused(format!(
                "PyTorch's ONNX export ({}) failed: {}",
                python.display(),
                String::from_utf8_lossy(&output.stderr).trim()
            )));
        }
        Ok(())
    })
    .map_err(|e| refused(format!("{}: {e}", out.display())))
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

    impl crate::Network for Branchy {
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
}
