//! Weights in and out as safetensors state_dicts with the reference parameter names.
//!
//! Loading is strict: every network variable must be present with the same shape and the file
//! may hold nothing else (PyTorch's `num_batches_tracked` counters carry no weights and are
//! skipped). On any difference the error lists all missing, unexpected and misshaped names.
//! Every weight must be a finite floating-point number: a file with one NaN or infinity, or
//! an integer tensor where a weight belongs, is refused naming the tensor (it would otherwise
//! load and score like an untrained network, with exit 0).
//!
//! Files written by [`save_safetensors`] carry the network in the safetensors header's
//! `__metadata__` (format: <https://github.com/huggingface/safetensors#format>): `rtf.format`
//! ([`FORMAT_VERSION`]), `rtf.model` (the canonical name) and `rtf.config` (the
//! [`ModelConfig`] as JSON) and `rtf.inputs` (the [`Modality`] the network was trained to
//! see). [`load_checked`] compares the configuration with the network asked for, because
//! variants with the same tensor names (`mfnet`, `mfnet-f`, `-h`, `-j`) would otherwise load
//! each other's weights silently, and returns the inputs, because an RGB-only network scored
//! on RGB-T input gives a wrong score just as silently. Files without it (converted published weights, older runs)
//! load with [`Provenance::Unchecked`], for the caller to warn about.
//!
//! Library errors of the `safetensors` crate are translated into what is wrong with the file
//! (e.g. `HeaderTooLarge` on a PyTorch `.pth` archive).

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;

use safetensors::{tensor::TensorView, Dtype, SafeTensorError, SafeTensors};
use tch::nn::VarStore;
use tch::{Kind, Tensor};

use crate::error::{ModelError, ShapeMismatch};
use crate::inputs::Modality;
use crate::ModelConfig;

/// Metadata key of the weights format version.
pub const FORMAT_KEY: &str = "rtf.format";
/// Metadata key of the canonical model name ([`ModelConfig::name`]).
pub const MODEL_KEY: &str = "rtf.model";
/// Metadata key of the model configuration (JSON of [`ModelConfig`]).
pub const CONFIG_KEY: &str = "rtf.config";
/// Metadata key of the inputs the network sees ([`Modality::name`]; absent = unknown).
pub const INPUTS_KEY: &str = "rtf.inputs";
/// The weights format this build writes and reads.
pub const FORMAT_VERSION: &str = "1";

/// PyTorch BatchNorm counters; present in reference state_dicts, absent from tch's VarStore.
pub fn is_ignored_name(name: &str) -> bool {
    name.ends_with("num_batches_tracked")
}

/// A safetensors file as read: its tensors in file order and its header metadata.
pub struct WeightsFile {
    pub tensors: Vec<(String, Tensor)>,
    pub metadata: HashMap<String, String>,
}

impl WeightsFile {
    /// The model configuration recorded by [`save_safetensors`], if the file has one.
    pub fn saved_config(&self, path: &Path) -> Result<Option<ModelConfig>, ModelError> {
        let Some(json) = self.metadata.get(CONFIG_KEY) else {
            return Ok(None);
        };
        serde_json::from_str(json)
            .map(Some)
            .map_err(|e| ModelError::Read {
                path: path.to_path_buf(),
                message: format!(
                    "metadata `{CONFIG_KEY}` is not a model configuration this build knows \
                     ({e}); --foreign-weights loads the tensors regardless"
                ),
            })
    }

    /// The inputs recorded by [`save_safetensors`], if the file has them.
    pub fn saved_inputs(&self, path: &Path) -> Result<Option<Modality>, ModelError> {
        let Some(name) = self.metadata.get(INPUTS_KEY) else {
            return Ok(None);
        };
        Modality::parse(name)
            .map(Some)
            .map_err(|e| ModelError::Read {
                path: path.to_path_buf(),
                message: format!("metadata `{INPUTS_KEY}`: {e}"),
            })
    }
}

/// Reads every tensor of a safetensors file, in file order.
pub fn read_safetensors(path: &Path) -> Result<Vec<(String, Tensor)>, ModelError> {
    Ok(read_weights_file(path)?.tensors)
}

/// Reads only the header metadata of a safetensors file (the tensors list comes back empty):
/// what a caller needs to learn which network a file holds without reading gigabytes. A file
/// whose header does not parse is read whole, for [`read_weights_file`]'s error.
pub fn read_weights_metadata(path: &Path) -> Result<WeightsFile, ModelError> {
    use std::io::Read;
    let header = || -> Option<HashMap<String, String>> {
        let mut file = std::fs::File::open(path).ok()?;
        let mut len = [0u8; 8];
        file.read_exact(&mut len).ok()?;
        let len = u64::from_le_bytes(len);
        if len > file.metadata().ok()?.len().saturating_sub(8) {
            return None;
        }
        let mut json = vec![0u8; usize::try_from(len).ok()?];
        file.read_exact(&mut json).ok()?;
        let header: serde_json::Value = serde_json::from_slice(&json).ok()?;
        match header.get("__metadata__") {
            None => Some(HashMap::new()),
            Some(meta) => serde_json::from_value(meta.clone()).ok(),
        }
    };
    match header() {
        Some(metadata) => Ok(WeightsFile {
            tensors: Vec::new(),
            metadata,
        }),
        None => read_weights_file(path).map(|file| WeightsFile {
            tensors: Vec::new(),
            metadata: file.metadata,
        }),
    }
}

/// Reads a safetensors file: tensors (in file order) and metadata. Errors name the file and
/// say what is wrong with it rather than quoting the parser.
pub fn read_weights_file(path: &Path) -> Result<WeightsFile, ModelError> {
    let read_err = |message: String| ModelError::Read {
        path: path.to_path_buf(),
        message,
    };
    if path.is_dir() {
        return Err(read_err(
            "is a directory, expected a .safetensors file".into(),
        ));
    }
    if !path.is_file() {
        return Err(read_err("no such file".into()));
    }
    let bytes = std::fs::read(path).map_err(|e| read_err(e.to_string()))?;
    let (_, header) =
        SafeTensors::read_metadata(&bytes).map_err(|e| read_err(describe_error(&e, &bytes)))?;
    let metadata = header.metadata().clone().unwrap_or_default();
    let st = SafeTensors::deserialize(&bytes).map_err(|e| read_err(describe_error(&e, &bytes)))?;
    let mut views: Vec<(String, TensorView<'_>)> = st.tensors();
    // File order: by data offset (the header's JSON object has no order of its own).
    let offsets: HashMap<String, usize> = header
        .tensors()
        .iter()
        .map(|(n, info)| (n.clone(), info.data_offsets.0))
        .collect();
    views.sort_by_key(|(n, _)| offsets.get(n).copied().unwrap_or(usize::MAX));
    let mut tensors = Vec::with_capacity(views.len());
    for (name, view) in views {
        let kind = kind_of(view.dtype()).ok_or_else(|| ModelError::BadTensor {
            path: path.to_path_buf(),
            name: name.clone(),
            message: format!(
                "dtype {:?} is not supported (weights are F16, BF16, F32 or F64)",
                view.dtype()
            ),
        })?;
        let shape: Vec<i64> = view.shape().iter().map(|&d| d as i64).collect();
        let t = Tensor::f_from_data_size(view.data(), &shape, kind).map_err(|e| {
            ModelError::BadTensor {
                path: path.to_path_buf(),
                name: name.clone(),
                message: e.to_string(),
            }
        })?;
        tensors.push((name, t));
    }
    Ok(WeightsFile { tensors, metadata })
}

fn kind_of(dtype: Dtype) -> Option<Kind> {
    Some(match dtype {
        Dtype::BOOL => Kind::Bool,
        Dtype::U8 => Kind::Uint8,
        Dtype::I8 => Kind::Int8,
        Dtype::I16 => Kind::Int16,
        Dtype::I32 => Kind::Int,
        Dtype::I64 => Kind::Int64,
        Dtype::F16 => Kind::Half,
        Dtype::BF16 => Kind::BFloat16,
        Dtype::F32 => Kind::Float,
        Dtype::F64 => Kind::Double,
        _ => return None,
    })
}

fn dtype_of(kind: Kind) -> Option<Dtype> {
    Some(match kind {
        Kind::Bool => Dtype::BOOL,
        Kind::Uint8 => Dtype::U8,
        Kind::Int8 => Dtype::I8,
        Kind::Int16 => Dtype::I16,
        Kind::Int => Dtype::I32,
        Kind::Int64 => Dtype::I64,
        Kind::Half => Dtype::F16,
        Kind::BFloat16 => Dtype::BF16,
        Kind::Float => Dtype::F32,
        Kind::Double => Dtype::F64,
        _ => return None,
    })
}

/// What a `safetensors` parse error means for the file `bytes` came from.
fn describe_error(e: &SafeTensorError, bytes: &[u8]) -> String {
    let len = bytes.len();
    let announced = bytes
        .get(..8)
        .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")));
    let looks_like = if bytes.starts_with(b"PK\x03\x04") {
        " It is a zip archive, as PyTorch's .pth checkpoints are: convert it with \
         `cargo xtask convert-pth IN.pth OUT.safetensors`."
    } else if bytes.first() == Some(&0x80) {
        " It starts like a Python pickle (a legacy PyTorch .pth): convert it with \
         `cargo xtask convert-pth IN.pth OUT.safetensors --allow-pickle`."
    } else {
        ""
    };
    match e {
        SafeTensorError::HeaderTooLarge => format!(
            "not a safetensors file: its first 8 bytes announce a header of {} bytes, more \
             than safetensors allows (100 MB).{looks_like}",
            announced.unwrap_or(0)
        ),
        SafeTensorError::HeaderTooSmall => format!(
            "not a safetensors file: {len} bytes, too short for a safetensors header \
             (8-byte length, then JSON).{looks_like}"
        ),
        SafeTensorError::InvalidHeaderLength => format!(
            "truncated or not a safetensors file: its first 8 bytes announce a header of {} \
             bytes but the file has {len} bytes.{looks_like}",
            announced.unwrap_or(0)
        ),
        SafeTensorError::InvalidHeader(_)
        | SafeTensorError::InvalidHeaderDeserialization(_)
        | SafeTensorError::JsonError(_) => {
            format!("corrupt safetensors header ({e}).{looks_like}")
        }
        SafeTensorError::MetadataIncompleteBuffer => format!(
            "truncated or padded: the tensors the header describes do not end where the file \
             ends ({len} bytes); the file was probably cut short while being copied or written"
        ),
        SafeTensorError::InvalidOffset(name) => format!(
            "corrupt header: the byte range of tensor `{name}` is inconsistent with the others"
        ),
        SafeTensorError::TensorInvalidInfo | SafeTensorError::ValidationOverflow => {
            "corrupt header: a tensor's shape and dtype do not match its byte range".into()
        }
        other => format!("not a readable safetensors file: {other}"),
    }
}

/// How a [`load_checked`] file relates to the network it was loaded into.
#[derive(Debug, Clone, PartialEq)]
pub enum Provenance {
    /// The file's metadata names this very configuration.
    Checked,
    /// The file has no rtf metadata (converted published weights, older builds): the tensors
    /// matched by name and shape, but the network they were trained for cannot be checked.
    Unchecked,
    /// The metadata names another configuration and the caller allowed it.
    Overridden { saved: String },
}

/// One line for the user about a load that could not be fully checked; None when checked.
pub fn provenance_warning(path: &Path, provenance: &Provenance) -> Option<String> {
    match provenance {
        Provenance::Checked => None,
        Provenance::Unchecked => Some(format!(
            "{}: no rtf model metadata (converted or older weights): tensor names and shapes \
             match, but the network they were trained for cannot be checked",
            path.display()
        )),
        Provenance::Overridden { saved } => Some(format!(
            "{}: saved for `{saved}`, loaded anyway (--foreign-weights)",
            path.display()
        )),
    }
}

/// What [`load_checked`] learnt of a file besides its tensors.
#[derive(Debug, Clone, PartialEq)]
pub struct Loaded {
    pub provenance: Provenance,
    /// The inputs the network was trained to see; None for files without it (converted
    /// published weights, older builds), which are RGB-T networks unless the user says
    /// otherwise.
    pub inputs: Option<Modality>,
}

/// Loads `path` into `vs`, built from `cfg`, checking the file's model metadata first: a file
/// saved for another configuration is refused (naming both) unless `allow_foreign`. Then the
/// strict load of [`load_named`]. Nothing is copied unless everything passes.
pub fn load_checked(
    vs: &mut VarStore,
    cfg: &ModelConfig,
    path: &Path,
    allow_foreign: bool,
) -> Result<Loaded, ModelError> {
    let file = read_weights_file(path)?;
    let inputs = match file.saved_inputs(path) {
        Err(_) if allow_foreign => None,
        other => other?,
    };
    let provenance = match file.metadata.get(FORMAT_KEY) {
        Some(v) if v != FORMAT_VERSION && !allow_foreign => {
            return Err(ModelError::Read {
                path: path.to_path_buf(),
                message: format!(
                    "weights format {v}, this build reads format {FORMAT_VERSION}; \
                     --foreign-weights loads the tensors regardless"
                ),
            })
        }
        _ => match file.saved_config(path) {
            Ok(None) => Provenance::Unchecked,
            Ok(Some(saved)) if &saved == cfg => Provenance::Checked,
            Ok(Some(saved)) => {
                let (saved, requested) = describe_pair(&saved, cfg);
                if !allow_foreign {
                    return Err(ModelError::WrongModel {
                        path: path.to_path_buf(),
                        saved,
                        requested,
                    });
                }
                Provenance::Overridden { saved }
            }
            Err(_) if allow_foreign => Provenance::Overridden {
                saved: file
                    .metadata
                    .get(MODEL_KEY)
                    .cloned()
                    .unwrap_or_else(|| "an unknown configuration".into()),
            },
            Err(e) => return Err(e),
        },
    };
    load_named(vs, file.tensors, path)?;
    Ok(Loaded { provenance, inputs })
}

/// Names two configurations so that they read differently: by name, or by their JSON where
/// the names agree (same variant, other class count).
fn describe_pair(saved: &ModelConfig, requested: &ModelConfig) -> (String, String) {
    let (a, b) = (saved.name(), requested.name());
    if a != b {
        return (a, b);
    }
    let json = |c: &ModelConfig| serde_json::to_string(c).unwrap_or_default();
    (
        format!("{a} {}", json(saved)),
        format!("{b} {}", json(requested)),
    )
}

/// Loads a safetensors state_dict into `vs` without looking at its model metadata (strict;
/// see the module docs). Nothing is copied unless the whole file matches, so a refused file
/// leaves the network untouched. Prefer [`load_checked`] where the configuration is known.
pub fn load_safetensors(vs: &mut VarStore, path: &Path) -> Result<(), ModelError> {
    let tensors = read_safetensors(path)?;
    load_named(vs, tensors, path)
}

/// Refuses a tensor that cannot be a weight: not floating point, or holding NaN or infinity.
pub fn check_weight(name: &str, t: &Tensor, source: &Path) -> Result<(), ModelError> {
    let bad = |message: String| ModelError::BadTensor {
        path: source.to_path_buf(),
        name: name.to_string(),
        message,
    };
    let kind = t.kind();
    if !matches!(
        kind,
        Kind::Half | Kind::BFloat16 | Kind::Float | Kind::Double
    ) {
        return Err(bad(format!(
            "dtype {} is not floating point; weights are F16, BF16, F32 or F64",
            dtype_of(kind).map_or(format!("{kind:?}"), |d| format!("{d:?}"))
        )));
    }
    let torch = |e: tch::TchError| bad(e.to_string());
    let finite = t.f_isfinite().map_err(torch)?;
    let bad_count = finite
        .f_logical_not()
        .and_then(|m| m.f_sum(Kind::Int64))
        .map_err(torch)?
        .int64_value(&[]);
    if bad_count > 0 {
        let nan = t
            .f_isnan()
            .and_then(|m| m.f_sum(Kind::Int64))
            .map_err(torch)?
            .int64_value(&[]);
        return Err(bad(format!(
            "{bad_count} of {} values are not finite ({nan} NaN, {} infinite); the file is \
             corrupt or comes from a diverged training run",
            t.numel(),
            bad_count - nan
        )));
    }
    Ok(())
}

/// Strict load from already-read named tensors; `source` names where they came from.
pub fn load_named(
    vs: &mut VarStore,
    tensors: Vec<(String, Tensor)>,
    source: &Path,
) -> Result<(), ModelError> {
    load_named_except(vs, tensors, source, &BTreeSet::new())
}

/// The variables of a network whose shapes depend on its class count (the classifier head):
/// found by building the network with `cfg`'s class count and with one more, without
/// initialising any weights, and comparing every variable's shape.
pub fn class_dependent_names(cfg: &ModelConfig) -> Result<BTreeSet<String>, ModelError> {
    let shapes = |cfg: &ModelConfig| -> Result<BTreeMap<String, Vec<i64>>, ModelError> {
        let vs = VarStore::new(tch::Device::Cpu);
        crate::build_with(&vs.root(), cfg, &crate::BuildOptions::uninitialised())?;
        Ok(vs
            .variables()
            .into_iter()
            .map(|(name, t)| (name, t.size()))
            .collect())
    };
    let own = shapes(cfg)?;
    let other = shapes(&cfg.with_num_classes(cfg.num_classes() + 1))?;
    Ok(own
        .into_iter()
        .filter(|(name, size)| other.get(name) != Some(size))
        .map(|(name, _)| name)
        .collect())
}

/// [`load_named`], except that the variables named in `keep_fresh` keep their initial values:
/// the file need not hold them, and what it holds under those names (of any shape) is not
/// loaded. Every other variable is checked and loaded strictly.
pub fn load_named_except(
    vs: &mut VarStore,
    tensors: Vec<(String, Tensor)>,
    source: &Path,
    keep_fresh: &BTreeSet<String>,
) -> Result<(), ModelError> {
    let vars: BTreeMap<String, Tensor> = vs
        .variables()
        .into_iter()
        .filter(|(name, _)| !keep_fresh.contains(name))
        .collect();
    let file: BTreeMap<String, Tensor> = tensors
        .into_iter()
        .filter(|(name, _)| !is_ignored_name(name) && !keep_fresh.contains(name))
        .collect();
    let missing: Vec<String> = vars
        .keys()
        .filter(|k| !file.contains_key(*k))
        .cloned()
        .collect();
    let unexpected: Vec<String> = file
        .keys()
        .filter(|k| !vars.contains_key(*k))
        .cloned()
        .collect();
    let mismatched: Vec<ShapeMismatch> = vars
        .iter()
        .filter_map(|(name, var)| {
            let found = file.get(name)?.size();
            (found != var.size()).then(|| ShapeMismatch {
                name: name.clone(),
                expected: var.size(),
                found,
            })
        })
        .collect();
    crate::error::check_names(source, missing, unexpected, mismatched)?;
    for (name, t) in &file {
        check_weight(name, t, source)?;
    }
    tch::no_grad(|| -> Result<(), ModelError> {
        for (name, mut var) in vars {
            let src = &file[&name];
            let converted = src
                .f_to_kind(var.kind())
                .and_then(|t| t.f_to_device(var.device()))
                .and_then(|t| var.f_copy_(&t))
                .map_err(|e| ModelError::Read {
                    path: source.to_path_buf(),
                    message: format!("tensor {name}: {e}"),
                });
            converted?;
        }
        Ok(())
    })
}

/// The variables of `vs` as contiguous CPU tensors, sorted by name.
pub fn state_dict(vs: &VarStore) -> Vec<(String, Tensor)> {
    let mut named: Vec<(String, Tensor)> = vs
        .variables()
        .into_iter()
        .map(|(name, t)| (name, t.detach().to_device(tch::Device::Cpu).contiguous()))
        .collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    named
}

/// The metadata [`save_safetensors`] writes for `cfg` seeing `inputs`.
pub fn model_metadata(cfg: &ModelConfig, inputs: Modality) -> HashMap<String, String> {
    HashMap::from([
        (FORMAT_KEY.to_string(), FORMAT_VERSION.to_string()),
        (MODEL_KEY.to_string(), cfg.name()),
        (
            CONFIG_KEY.to_string(),
            serde_json::to_string(cfg).expect("a model configuration serialises"),
        ),
        (INPUTS_KEY.to_string(), inputs.name().to_string()),
    ])
}

/// Writes the variables of `vs`, the network built from `cfg` and trained on `inputs`, as a
/// safetensors state_dict with the reference names and both in the metadata (module docs),
/// through a temporary file renamed into place.
pub fn save_safetensors(
    vs: &VarStore,
    cfg: &ModelConfig,
    inputs: Modality,
    path: &Path,
) -> Result<(), ModelError> {
    save_named_with_metadata(&state_dict(vs), Some(model_metadata(cfg, inputs)), path)
}

/// Writes named tensors as safetensors without model metadata, atomically.
pub fn save_named(named: &[(String, Tensor)], path: &Path) -> Result<(), ModelError> {
    save_named_with_metadata(named, None, path)
}

/// Writes named tensors (any dtype safetensors has) and optional metadata, atomically.
pub fn save_named_with_metadata(
    named: &[(String, Tensor)],
    metadata: Option<HashMap<String, String>>,
    path: &Path,
) -> Result<(), ModelError> {
    let write_err = |message: String| ModelError::Write {
        path: path.to_path_buf(),
        message,
    };
    let mut raw: Vec<(&str, Dtype, Vec<usize>, Vec<u8>)> = Vec::with_capacity(named.len());
    for (name, t) in named {
        let t = t.to_device(tch::Device::Cpu).contiguous();
        let dtype = dtype_of(t.kind())
            .ok_or_else(|| write_err(format!("tensor {name}: dtype {:?}", t.kind())))?;
        let numel = t.numel();
        let mut bytes = vec![0u8; numel * t.kind().elt_size_in_bytes()];
        t.f_copy_data_u8(&mut bytes, numel)
            .map_err(|e| write_err(format!("tensor {name}: {e}")))?;
        let shape = t.size().iter().map(|&d| d as usize).collect();
        raw.push((name, dtype, shape, bytes));
    }
    let views = raw
        .iter()
        .map(|(n, dtype, shape, bytes)| {
            TensorView::new(*dtype, shape.clone(), bytes).map(|v| (*n, v))
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| write_err(e.to_string()))?;
    let bytes = safetensors::serialize(views, metadata).map_err(|e| write_err(e.to_string()))?;
    rtf_core::write_bytes_atomic(path, &bytes).map_err(|e| write_err(e.to_string()))
}

/// Total number of scalar weights (parameters and BatchNorm running statistics, as counted by
/// the reference `sum(p.numel() for p in state_dict().values())` without the counters).
pub fn count_weights(vs: &VarStore) -> i64 {
    vs.variables().values().map(|t| t.numel() as i64).sum()
}

/// Number of trainable parameters (`sum(p.numel() for p in model.parameters())`).
pub fn count_trainable(vs: &VarStore) -> i64 {
    vs.trainable_variables()
        .iter()
        .map(|t| t.numel() as i64)
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{build, ModelConfig, Network};
    use tch::{Device, Kind};

    fn mfnet(seed: i64) -> (VarStore, Box<dyn Network>) {
        tch::manual_seed(seed);
        let vs = VarStore::new(Device::Cpu);
        let net = build(&vs.root(), &ModelConfig::from_name("mfnet", 9).unwrap()).unwrap();
        (vs, net)
    }

    fn mfnet_cfg(name: &str) -> ModelConfig {
        ModelConfig::from_name(name, 9).unwrap()
    }

    fn eval(net: &dyn Network, x: &Tensor) -> Tensor {
        tch::no_grad(|| net.forward_t(x, false))
    }

    #[test]
    fn save_load_round_trip_gives_identical_outputs() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("w.safetensors");
        let (vs_a, net_a) = mfnet(1);
        // Move the BN running statistics away from their initial values, so they are tested too.
        let _ = net_a.forward_t(
            &Tensor::rand([2, 4, 32, 32], (Kind::Float, Device::Cpu)),
            true,
        );
        save_safetensors(&vs_a, &mfnet_cfg("mfnet"), Modality::RgbT, &file).unwrap();
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "no temp file left"
        );

        let (mut vs_b, net_b) = mfnet(2);
        let x = Tensor::rand([1, 4, 32, 48], (Kind::Float, Device::Cpu));
        assert!(
            !eval(&*net_a, &x).equal(&eval(&*net_b, &x)),
            "different seeds differ"
        );
        load_safetensors(&mut vs_b, &file).unwrap();
        assert!(eval(&*net_a, &x).equal(&eval(&*net_b, &x)));
        // Reference state_dict names: `num_batches_tracked` was never written.
        let names: Vec<String> = read_safetensors(&file)
            .unwrap()
            .into_iter()
            .map(|t| t.0)
            .collect();
        assert!(names.contains(&"conv4_inf.conv3_right.bn.running_var".to_string()));
        assert_eq!(names.len(), 228);
    }

    #[test]
    fn num_batches_tracked_entries_are_accepted() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("w.safetensors");
        let (vs, _net) = mfnet(1);
        let mut named = state_dict(&vs);
        named.push(("decode1.bn.num_batches_tracked".into(), Tensor::from(7i64)));
        save_named(&named, &file).unwrap();
        let (mut vs_b, _net_b) = mfnet(2);
        load_safetensors(&mut vs_b, &file).unwrap();
    }

    #[test]
    fn a_nine_class_file_loads_into_a_five_class_network_except_its_head() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("nine.safetensors");
        let (vs9, _net9) = mfnet(1);
        save_safetensors(&vs9, &mfnet_cfg("mfnet"), Modality::RgbT, &file).unwrap();
        let five = ModelConfig::from_name("mfnet", 5).unwrap();
        let head = class_dependent_names(&five).unwrap();
        assert_eq!(
            head.iter().map(String::as_str).collect::<Vec<_>>(),
            [
                "decode1.bn.bias",
                "decode1.bn.running_mean",
                "decode1.bn.running_var",
                "decode1.bn.weight",
                "decode1.conv.bias",
                "decode1.conv.weight"
            ]
        );
        tch::manual_seed(2);
        let mut vs5 = VarStore::new(Device::Cpu);
        let _net5 = build(&vs5.root(), &five).unwrap();
        let fresh_head = vs5.variables()["decode1.conv.weight"].copy();
        assert!(
            load_safetensors(&mut vs5, &file).is_err(),
            "strict load refuses"
        );
        load_named_except(&mut vs5, read_safetensors(&file).unwrap(), &file, &head).unwrap();
        let (loaded, nine) = (vs5.variables(), vs9.variables());
        assert!(loaded["conv1_rgb.conv.weight"].equal(&nine["conv1_rgb.conv.weight"]));
        assert!(
            loaded["decode1.conv.weight"].equal(&fresh_head),
            "head untouched"
        );
    }

    #[test]
    fn mismatching_file_is_refused_listing_every_offending_name() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("bad.safetensors");
        let (vs, _net) = mfnet(1);
        let mut named: Vec<(String, Tensor)> = state_dict(&vs)
            .into_iter()
            .filter(|(n, _)| n != "decode2.conv.bias") // missing
            .map(|(n, t)| match n.as_str() {
                "conv1_rgb.conv.weight" => ("conv1_rgb.conv.weights".to_string(), t), // renamed
                "decode1.conv.weight" => {
                    (n, Tensor::zeros([5, 32, 3, 3], (Kind::Float, Device::Cpu)))
                }
                _ => (n, t),
            })
            .collect();
        named.push((
            "extra.tensor".into(),
            Tensor::zeros([3], (Kind::Float, Device::Cpu)),
        ));
        save_named(&named, &file).unwrap();

        let (mut vs_b, net_b) = mfnet(2);
        let x = Tensor::rand([1, 4, 32, 32], (Kind::Float, Device::Cpu));
        let before = eval(&*net_b, &x);
        let err = load_safetensors(&mut vs_b, &file).unwrap_err();
        match &err {
            ModelError::Mismatch {
                missing,
                unexpected,
                mismatched,
                ..
            } => {
                assert_eq!(missing, &["conv1_rgb.conv.weight", "decode2.conv.bias"]);
                assert_eq!(unexpected, &["conv1_rgb.conv.weights", "extra.tensor"]);
                assert_eq!(mismatched.len(), 1);
                assert_eq!(mismatched[0].name, "decode1.conv.weight");
                assert_eq!(mismatched[0].expected, vec![9, 32, 3, 3]);
                assert_eq!(mismatched[0].found, vec![5, 32, 3, 3]);
            }
            other => panic!("expected a mismatch error, got {other}"),
        }
        let msg = err.to_string();
        for needle in [
            "bad.safetensors",
            "decode2.conv.bias",
            "extra.tensor",
            "conv1_rgb.conv.weights",
            "[5, 32, 3, 3]",
        ] {
            assert!(msg.contains(needle), "{needle} not in: {msg}");
        }
        assert!(
            eval(&*net_b, &x).equal(&before),
            "a refused file must not change the network"
        );
    }

    #[test]
    fn missing_and_corrupt_files_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let (mut vs, _net) = mfnet(1);
        let absent = dir.path().join("absent.safetensors");
        let err = load_safetensors(&mut vs, &absent).unwrap_err().to_string();
        assert!(
            err.contains("absent.safetensors") && err.contains("no such file"),
            "{err}"
        );
        let corrupt = dir.path().join("corrupt.safetensors");
        std::fs::write(&corrupt, b"this is not a safetensors file").unwrap();
        let err = load_safetensors(&mut vs, &corrupt).unwrap_err().to_string();
        assert!(err.contains("corrupt.safetensors"), "{err}");
    }

    #[test]
    fn other_float_dtypes_are_converted_on_load() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("f64.safetensors");
        let (vs, net) = mfnet(1);
        let named: Vec<(String, Tensor)> = state_dict(&vs)
            .into_iter()
            .map(|(n, t)| (n, t.to_kind(Kind::Double)))
            .collect();
        save_named(&named, &file).unwrap();
        let (mut vs_b, net_b) = mfnet(2);
        load_safetensors(&mut vs_b, &file).unwrap();
        let x = Tensor::rand([1, 4, 32, 32], (Kind::Float, Device::Cpu));
        assert!(eval(&*net, &x).allclose(&eval(&*net_b, &x), 1e-6, 1e-6, false));
    }

    /// The state_dict of a seeded MFNet with one tensor replaced by `f(tensor)`.
    fn tampered(name: &str, f: impl Fn(&Tensor) -> Tensor) -> Vec<(String, Tensor)> {
        let (vs, _net) = mfnet(1);
        state_dict(&vs)
            .into_iter()
            .map(|(n, t)| if n == name { (n, f(&t)) } else { (n, t) })
            .collect()
    }

    fn load_err(file: &Path) -> String {
        let (mut vs, net) = mfnet(2);
        let x = Tensor::rand([1, 4, 32, 32], (Kind::Float, Device::Cpu));
        let before = eval(&*net, &x);
        let err = load_checked(&mut vs, &mfnet_cfg("mfnet"), file, false)
            .unwrap_err()
            .to_string();
        assert!(
            eval(&*net, &x).equal(&before),
            "a refused file leaves the network untouched"
        );
        err
    }

    #[test]
    fn one_nan_or_infinity_is_refused_naming_the_tensor() {
        let dir = tempfile::tempdir().unwrap();
        for (value, what) in [(f64::NAN, "1 NaN"), (f64::INFINITY, "1 infinite")] {
            let file = dir.path().join("nonfinite.safetensors");
            let named = tampered("decode3.bn.running_var", |t| {
                let t = t.copy();
                let _ = t.get(5).fill_(value);
                t
            });
            save_named(&named, &file).unwrap();
            let err = load_err(&file);
            for needle in ["nonfinite.safetensors", "decode3.bn.running_var", what] {
                assert!(err.contains(needle), "{needle} not in: {err}");
            }
        }
    }

    #[test]
    fn integer_weights_are_refused_naming_the_tensor() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("int.safetensors");
        let named = tampered("conv1_rgb.conv.weight", |t| t.to_kind(Kind::Int64));
        save_named(&named, &file).unwrap();
        let err = load_err(&file);
        for needle in [
            "int.safetensors",
            "conv1_rgb.conv.weight",
            "I64",
            "floating",
        ] {
            assert!(err.contains(needle), "{needle} not in: {err}");
        }
        // A whole file of integers too (e.g. a label map saved under a weights name).
        let (vs, _net) = mfnet(1);
        let ints: Vec<(String, Tensor)> = state_dict(&vs)
            .into_iter()
            .map(|(n, t)| (n, t.to_kind(Kind::Uint8)))
            .collect();
        save_named(&ints, &file).unwrap();
        assert!(load_err(&file).contains("U8"));
    }

    #[test]
    fn metadata_names_the_network_and_variants_do_not_load_each_other() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("final.safetensors");
        tch::manual_seed(3);
        let vs = VarStore::new(Device::Cpu);
        let _net = build(&vs.root(), &mfnet_cfg("mfnet")).unwrap();
        save_safetensors(&vs, &mfnet_cfg("mfnet"), Modality::Thermal, &file).unwrap();
        let meta = read_weights_file(&file).unwrap().metadata;
        assert_eq!(meta[MODEL_KEY], "mfnet");
        assert_eq!(meta[INPUTS_KEY], "thermal");
        assert_eq!(meta[FORMAT_KEY], FORMAT_VERSION);
        let saved: ModelConfig = serde_json::from_str(&meta[CONFIG_KEY]).unwrap();
        assert_eq!(saved, mfnet_cfg("mfnet"));

        let mut same = VarStore::new(Device::Cpu);
        let _n = build(&same.root(), &mfnet_cfg("mfnet")).unwrap();
        assert_eq!(
            load_checked(&mut same, &mfnet_cfg("mfnet"), &file, false).unwrap(),
            Loaded {
                provenance: Provenance::Checked,
                inputs: Some(Modality::Thermal)
            }
        );
        for variant in ["mfnet-f", "mfnet-h", "mfnet-j"] {
            let mut other = VarStore::new(Device::Cpu);
            let _n = build(&other.root(), &mfnet_cfg(variant)).unwrap();
            // Same tensor names and shapes: only the metadata tells them apart.
            load_safetensors(&mut other, &file).unwrap();
            let err = load_checked(&mut other, &mfnet_cfg(variant), &file, false)
                .unwrap_err()
                .to_string();
            for needle in ["final.safetensors", "`mfnet`", &format!("`{variant}`")] {
                assert!(err.contains(needle), "{needle} not in: {err}");
            }
            assert_eq!(
                load_checked(&mut other, &mfnet_cfg(variant), &file, true)
                    .unwrap()
                    .provenance,
                Provenance::Overridden {
                    saved: "mfnet".into()
                }
            );
        }
        // Same variant, other class count: the message tells them apart by configuration.
        let (a, b) = describe_pair(
            &mfnet_cfg("mfnet"),
            &ModelConfig::from_name("mfnet", 13).unwrap(),
        );
        assert_ne!(a, b);
        assert!(a.contains("\"num_classes\":9") && b.contains("\"num_classes\":13"));
    }

    #[test]
    fn the_header_alone_names_the_network_and_its_inputs() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("rgb.safetensors");
        let (vs, _net) = mfnet(1);
        save_safetensors(&vs, &mfnet_cfg("mfnet"), Modality::Rgb, &file).unwrap();
        let meta = read_weights_metadata(&file).unwrap();
        assert!(meta.tensors.is_empty());
        assert_eq!(meta.saved_config(&file).unwrap(), Some(mfnet_cfg("mfnet")));
        assert_eq!(meta.saved_inputs(&file).unwrap(), Some(Modality::Rgb));
        // A file that is no safetensors file: the full reader's message.
        let bad = dir.path().join("bad.safetensors");
        std::fs::write(&bad, b"abc").unwrap();
        let err = read_weights_metadata(&bad).err().unwrap().to_string();
        assert!(
            err.contains("bad.safetensors") && err.contains("too short"),
            "{err}"
        );
    }

    #[test]
    fn files_without_metadata_load_unchecked_with_a_warning() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("converted.safetensors");
        let (vs, _net) = mfnet(1);
        save_named(&state_dict(&vs), &file).unwrap();
        let (mut vs_b, _net_b) = mfnet(2);
        let loaded = load_checked(&mut vs_b, &mfnet_cfg("mfnet-f"), &file, false).unwrap();
        let provenance = loaded.provenance;
        assert_eq!(provenance, Provenance::Unchecked);
        assert_eq!(loaded.inputs, None);
        let warning = provenance_warning(&file, &provenance).unwrap();
        assert!(
            warning.contains("converted.safetensors") && warning.contains("cannot be checked"),
            "{warning}"
        );
        assert!(provenance_warning(&file, &Provenance::Checked).is_none());
    }

    #[test]
    fn parser_errors_say_what_is_wrong_with_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("good.safetensors");
        let (vs, _net) = mfnet(1);
        save_safetensors(&vs, &mfnet_cfg("mfnet"), Modality::RgbT, &good).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        let cases: Vec<(&str, Vec<u8>, &[&str])> = vec![
            // A PyTorch zip archive: the first 8 bytes read as a huge header length.
            (
                "model.pth.safetensors",
                b"PK\x03\x04\x14\x00\x00\x00\x08\x00rest of a zip".to_vec(),
                &["not a safetensors file", "header of", "convert-pth"],
            ),
            ("tiny.safetensors", b"abc".to_vec(), &["too short"]),
            (
                "truncated.safetensors",
                bytes[..bytes.len() - 1000].to_vec(),
                &["truncated", "cut short"],
            ),
            (
                "header_cut.safetensors",
                bytes[..200].to_vec(),
                &["truncated or not a safetensors file", "200 bytes"],
            ),
            (
                "badjson.safetensors",
                [&8u64.to_le_bytes()[..], b"{not json"].concat(),
                &["corrupt safetensors header"],
            ),
        ];
        for (name, content, needles) in cases {
            let file = dir.path().join(name);
            std::fs::write(&file, content).unwrap();
            let err = load_err(&file);
            assert!(err.contains(name), "{name}: {err}");
            for needle in needles {
                assert!(err.contains(needle), "{name}: {needle} not in: {err}");
            }
            assert!(!err.contains("HeaderTooLarge"), "{err}");
        }
        let err = load_err(dir.path());
        assert!(err.contains("is a directory"), "{err}");
    }
}
