//! `rtf.load_network` and the network object: logits and class ids of a frame given as NumPy
//! arrays (the frame `rtf predict` builds from files, run by the same function,
//! `rtf_eval::predict::frame_logits`), the forward pass on torch tensors (no copy in or out),
//! its classes and palette. The GIL is released while the network runs.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use pyo3::prelude::*;
use pyo3::types::PyDict;
use rtf_core::ClassSet;
use rtf_data::TrainedOn;
use rtf_eval::kernels::probe::Probe;
use rtf_eval::kernels::KernelPolicy;
use rtf_eval::predict;
use rtf_models::fast::{FoldOptions, InferenceKernels, InferenceNet, Precision};
use rtf_models::{Modality, ModelConfig, Network};
use tch::nn::VarStore;

use crate::errors::{input, PyResultExt};

/// A network and its variables (kept alive with it), behind a lock so that Python threads may
/// share the object while the GIL is released.
pub struct Held {
    pub vs: VarStore,
    pub net: Box<dyn Network>,
}

/// How a network was built: its configuration, the channels it sees, its inference path.
pub struct Built {
    pub cfg: ModelConfig,
    pub modality: Modality,
    pub precision: Option<Precision>,
}

/// A segmentation network loaded for inference (`rtf.load_network`).
#[pyclass(module = "rtf", name = "Network")]
pub struct PyNetwork {
    pub held: Mutex<Held>,
    #[pyo3(get)]
    pub name: String,
    pub built: Built,
    pub classes: ClassSet,
    pub trained: Option<TrainedOn>,
    pub device: tch::Device,
    #[pyo3(get)]
    pub weights: Option<PathBuf>,
    /// The channels the network sees (`rgb_t`, `rgb`, `thermal`).
    #[pyo3(get)]
    pub inputs: String,
    /// Training mode for `__call__` (BatchNorm batch statistics, dropout), `train()` / `eval()`.
    #[pyo3(get)]
    pub training: bool,
}

/// The kernels a fold for `precision` takes: the library's choice for any caller
/// (`rtf_eval::kernels`), under the policy and probe cache that `environ` (the Python layer
/// passes `os.environ`: it is this process's edge) gives, as `rtf predict` makes it
/// (`RTF_WINOGRAD`, `RTF_BF16_WINOGRAD`, `RTF_BF16_CONVOLUTIONS`, oneDNN's ISA cap,
/// `RTF_CACHE_DIR`), with the policy; the library's warning where bf16 is slow or emulated
/// here (measured in this process where bf16 is native). A bad variable is refused naming it.
fn inference_kernels(
    precision: Option<Precision>,
    device: tch::Device,
    environ: &HashMap<String, String>,
) -> PyResult<(InferenceKernels, KernelPolicy)> {
    let policy = KernelPolicy::from_vars(|var| environ.get(var).cloned())
        .map_err(|e| input(e.to_string()))?;
    let Some(precision) = precision else {
        let kernels = InferenceKernels {
            winograd: policy.winograd,
            bf16_convolutions: policy.inference_convolutions(),
            ..InferenceKernels::unmeasured()
        };
        return Ok((kernels, policy));
    };
    let probe = Probe::from_vars(|var| environ.get(var).map(std::ffi::OsString::from));
    let (kernels, warnings) =
        rtf_eval::kernels::inference_kernels(&policy, precision, device, &probe);
    let measured = || rtf_eval::kernels::probe::measured_inference(&probe, kernels);
    let slow = rtf_eval::kernels::inference_warning(&policy, precision, device, measured);
    for warning in warnings.into_iter().chain(slow) {
        eprintln!("warning: {warning}");
    }
    Ok((kernels, policy))
}

/// The network `name` with random weights (libtorch's generator: `torch.manual_seed` seeds
/// it), as `rtf_models::io::loaded::load_network` builds it, folded for `precision` (one this
/// device runs: fp16 only on CUDA).
fn random_network(
    cfg: &ModelConfig,
    device: tch::Device,
    precision: Option<Precision>,
    kernels: InferenceKernels,
) -> Result<Held, rtf_models::ModelError> {
    let vs = VarStore::new(device);
    let net = rtf_models::build(&vs.root(), cfg)?;
    let net = match precision {
        Some(p) => {
            rtf_models::fast::check_precision_on(p, device)?;
            Box::new(InferenceNet::fold(
                net,
                &FoldOptions::new(p).kernels(kernels),
            )?) as _
        }
        None => net,
    };
    Ok(Held { vs, net })
}

/// The class set and thermal rule a weights file records (`rtf predict`'s reading).
fn trained_on(weights: &Path) -> PyResult<Option<TrainedOn>> {
    let file = rtf_models::io::weights::read_weights_metadata(weights).py()?;
    rtf_data::trained_on::from_metadata(&file.metadata, weights).py()
}

fn parse_device(name: &str) -> PyResult<tch::Device> {
    rtf_train::config::available_device(name).map_err(|e| input(format!("device: {e}")))
}

fn parse_precision(text: Option<&str>) -> PyResult<Option<Precision>> {
    text.map(|t| Precision::parse_inference(t).map_err(|e| input(format!("precision: {e}"))))
        .transpose()
}

/// Loads network `name` (see `rtf.models()`) with `weights` (a safetensors file, reference
/// names; None: random weights), as `rtf predict` loads it.
#[pyfunction]
#[pyo3(signature = (name, weights=None, classes=None, device="cpu", precision=None, environ=None))]
pub fn load_network(
    py: Python<'_>,
    name: &str,
    weights: Option<PathBuf>,
    classes: Option<String>,
    device: &str,
    precision: Option<&str>,
    environ: Option<HashMap<String, String>>,
) -> PyResult<PyNetwork> {
    let device = parse_device(device)?;
    let precision = parse_precision(precision)?;
    let trained = weights.as_deref().map(trained_on).transpose()?.flatten();
    let path = weights.as_deref().unwrap_or(Path::new(""));
    let classes = predict::class_set(classes.as_deref(), name, path, trained.as_ref()).py()?;
    // The kernels carry how bf16 folds compute their convolutions, as `rtf`'s commands do.
    let (kernels, _policy) = inference_kernels(precision, device, &environ.unwrap_or_default())?;
    let n = classes.len() as i64;
    let cfg = ModelConfig::from_name(name, n)
        .map_err(rtf_models::ModelError::from)
        .py()?;
    let (held, inputs) = py
        .allow_threads(|| match &weights {
            Some(weights) => {
                let request = rtf_models::io::loaded::NetworkRequest {
                    name,
                    num_classes: n,
                    weights,
                    device,
                    precision,
                    kernels,
                    foreign_weights: false,
                    inputs: None,
                };
                rtf_models::io::loaded::load_network(&request).map(|loaded| {
                    for warning in &loaded.warnings {
                        eprintln!("warning: {warning}");
                    }
                    let held = Held {
                        vs: loaded.vs,
                        net: loaded.net,
                    };
                    (held, loaded.inputs)
                })
            }
            None => random_network(&cfg, device, precision, kernels).map(|h| (h, Modality::RgbT)),
        })
        .py()?;
    let built = Built {
        cfg,
        modality: inputs,
        precision,
    };
    Ok(PyNetwork {
        held: Mutex::new(held),
        name: name.to_string(),
        built,
        classes,
        trained,
        device,
        weights,
        inputs: inputs.to_string(),
        training: false,
    })
}

/// One record per network: name, parameters, MiB of float32 parameters, inputs (the 4
/// channels R, G, B, T), default class set.
#[pyfunction]
pub fn models(py: Python<'_>) -> PyResult<Vec<Bound<'_, PyDict>>> {
    let infos = rtf_models::model_infos().py()?;
    infos
        .into_iter()
        .filter(|info| ModelConfig::from_name(&info.name, 1).is_ok())
        .map(|info| {
            let record = PyDict::new(py);
            let classes = match rtf_models::default_num_classes(&info.name) {
                13 => "freiburg",
                _ => "mf",
            };
            record.set_item("name", &info.name)?;
            record.set_item("parameters", info.params)?;
            record.set_item("megabytes", info.megabytes)?;
            record.set_item("inputs", Modality::RgbT.name())?;
            record.set_item("classes", classes)?;
            Ok(record)
        })
        .collect()
}
