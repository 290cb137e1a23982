//! Checkpoints: one safetensors file holding, for every trained network (its *role*:
//! `student`, `critic`), its weights under `<role>/w/<name>` and its optimiser's state under
//! `<role>/opt/<key>` (`momentum/<name>`, `square_avg/<name>`), and, in its metadata, the
//! training state. One file, written atomically, so a checkpoint is never half old and half new.
//! Checkpoints of older builds (`model/<name>` plus un-prefixed optimiser keys) load as the
//! `student` role.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use safetensors::{tensor::TensorView, Dtype, SafeTensors};
use serde::{Deserialize, Serialize};
use tch::{nn::VarStore, Device, Kind, Tensor};

#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// Where training stands: after a completed epoch, or inside one (`partial`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainState {
    /// Epochs completed; training resumes at this (0-based) epoch.
    pub epochs_done: usize,
    pub steps_done: u64,
    pub best_val_miou: Option<f64>,
    /// Progress inside epoch `epochs_done` when the checkpoint was written mid-epoch.
    #[serde(default)]
    pub partial: Option<PartialEpoch>,
    /// The log record of the last finished epoch (the log is appended after the checkpoint:
    /// on resume `log.jsonl` gets it back if a kill came between them). Checkpoints written
    /// before issue 30 carry every epoch's record; both read.
    #[serde(default)]
    pub records: Vec<rtf_run::EpochRecord>,
}

/// The part of an epoch done before a mid-epoch checkpoint, with the sums its log record needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartialEpoch {
    /// Batches of the epoch done; training resumes at this batch.
    pub batches: usize,
    pub loss_sum: f64,
    pub images: usize,
    pub seconds: f64,
    pub wait_seconds: f64,
    /// Sums of every named loss term and training metric so far.
    #[serde(default)]
    pub term_sums: BTreeMap<String, f64>,
}

const STATE_KEY: &str = "rtf_train_state";
const FORMAT_KEY: &str = "rtf_checkpoint_format";
const FORMAT: &str = "2";

/// One trained network's share of a checkpoint.
pub struct Part<'a> {
    pub role: &'a str,
    pub vs: &'a VarStore,
    pub optimizer: &'a BTreeMap<String, Tensor>,
}

/// A tensor as safetensors wants it: shape and little-endian f32 bytes.
type RawTensor = (Vec<usize>, Vec<u8>);

fn to_bytes(t: &Tensor) -> RawTensor {
    let t = t.to_device(Device::Cpu).to_kind(Kind::Float).contiguous();
    let shape = t.size().iter().map(|&d| d as usize).collect();
    let values = Vec::<f32>::try_from(t.flatten(0, -1)).expect("float tensor");
    (shape, values.iter().flat_map(|v| v.to_le_bytes()).collect())
}

/// Writes every part's weights and optimiser state and the training state to `path` (temp
/// file + rename).
pub fn save(path: &Path, parts: &[Part], state: &TrainState) -> Result<(), CheckpointError> {
    let mut named: Vec<(String, RawTensor)> = Vec::new();
    for part in parts {
        for (name, t) in part.vs.variables() {
            named.push((format!("{}/w/{name}", part.role), to_bytes(&t)));
        }
        for (key, t) in part.optimizer {
            named.push((format!("{}/opt/{key}", part.role), to_bytes(t)));
        }
    }
    let views = named
        .iter()
        .map(|(n, (shape, bytes))| {
            TensorView::new(Dtype::F32, shape.clone(), bytes).map(|v| (n.clone(), v))
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| invalid(path, e.to_string()))?;
    let metadata = HashMap::from([
        (
            STATE_KEY.to_string(),
            serde_json::to_string(state).expect("state serialises"),
        ),
        (FORMAT_KEY.to_string(), FORMAT.to_string()),
    ]);
    let bytes =
        safetensors::serialize(views, Some(metadata)).map_err(|e| invalid(path, e.to_string()))?;
    rtf_core::write_bytes_atomic(path, &bytes).map_err(|e| CheckpointError::Io {
        path: path.into(),
        source: std::io::Error::other(e.to_string()),
    })
}

/// Reads only the training state of a checkpoint (where a run stands).
pub fn read_state(path: &Path) -> Result<TrainState, CheckpointError> {
    let bytes = std::fs::read(path).map_err(|source| CheckpointError::Io {
        path: path.into(),
        source,
    })?;
    Ok(header(path, &bytes)?.0)
}

fn header(path: &Path, bytes: &[u8]) -> Result<(TrainState, bool), CheckpointError> {
    let (_, metadata) = SafeTensors::read_metadata(bytes).map_err(|e| {
        invalid(
            path,
            format!(
                "not a safetensors file, or a truncated one ({e}); delete it to start the run over"
            ),
        )
    })?;
    let meta = metadata.metadata().as_ref();
    let state: TrainState = meta
        .and_then(|m| m.get(STATE_KEY))
        .ok_or_else(|| {
            invalid(
                path,
                "no training state in metadata (not an rtf checkpoint)".into(),
            )
        })
        .and_then(|s| {
            serde_json::from_str(s).map_err(|e| invalid(path, format!("bad training state: {e}")))
        })?;
    let namespaced = meta.and_then(|m| m.get(FORMAT_KEY)).is_some();
    Ok((state, namespaced))
}

/// Each role's optimiser state: role → (state name → tensor).
pub type OptimizerStates = BTreeMap<String, BTreeMap<String, Tensor>>;

/// Restores every role's weights (every variable must be present with its shape) and returns
/// each role's optimiser state and the training state.
pub fn load(
    path: &Path,
    parts: &mut [(&str, &mut VarStore)],
) -> Result<(OptimizerStates, TrainState), CheckpointError> {
    let bytes = std::fs::read(path).map_err(|source| CheckpointError::Io {
        path: path.into(),
        source,
    })?;
    let (state, namespaced) = header(path, &bytes)?;
    let tensors = SafeTensors::deserialize(&bytes).map_err(|e| invalid(path, e.to_string()))?;
    let file = Reader {
        path,
        tensors,
        namespaced,
    };
    let mut optimizers = BTreeMap::new();
    for (role, vs) in parts.iter_mut() {
        if !namespaced && *role != "student" {
            return Err(invalid(
                path,
                format!("written by an older rtf that trained one network; it holds no `{role}`"),
            ));
        }
        file.restore_weights(role, vs)?;
        optimizers.insert(role.to_string(), file.optimizer_state(role, vs.device())?);
    }
    Ok((optimizers, state))
}

fn invalid(path: &Path, message: String) -> CheckpointError {
    CheckpointError::Invalid {
        path: path.into(),
        message,
    }
}

/// A checkpoint file's tensors, and where each role's keys live in it: `ROLE/w/NAME` and
/// `ROLE/opt/KEY` (namespaced), or `model/NAME` and bare optimiser keys (older single-network
/// files).
struct Reader<'a> {
    path: &'a Path,
    tensors: SafeTensors<'a>,
    namespaced: bool,
}

impl Reader<'_> {
    /// One F32 tensor by its key, on the CPU.
    fn tensor(&self, name: &str) -> Result<Tensor, CheckpointError> {
        let view = self
            .tensors
            .tensor(name)
            .map_err(|_| invalid(self.path, format!("missing tensor `{name}`")))?;
        if view.dtype() != Dtype::F32 {
            let dtype = view.dtype();
            return Err(invalid(
                self.path,
                format!("tensor `{name}` is {dtype:?}, expected F32"),
            ));
        }
        let values: Vec<f32> = view
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let shape: Vec<i64> = view.shape().iter().map(|&d| d as i64).collect();
        Ok(Tensor::from_slice(&values).view(shape.as_slice()))
    }

    /// Copies the role's saved weights into every variable of `vs` (each must be present with
    /// its shape).
    fn restore_weights(&self, role: &str, vs: &VarStore) -> Result<(), CheckpointError> {
        let device = vs.device();
        let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        tch::no_grad(|| {
            for (name, mut var) in vars {
                let key = match self.namespaced {
                    true => format!("{role}/w/{name}"),
                    false => format!("model/{name}"),
                };
                let saved = self.tensor(&key)?;
                if saved.size() != var.size() {
                    let message = format!(
                        "`{role}` `{name}` has shape {:?}, the network expects {:?}",
                        saved.size(),
                        var.size()
                    );
                    return Err(invalid(self.path, message));
                }
                var.copy_(&saved.to_device(device));
            }
            Ok(())
        })
    }

    /// The role's optimiser state (state name → tensor), on `device`.
    fn optimizer_state(
        &self,
        role: &str,
        device: Device,
    ) -> Result<BTreeMap<String, Tensor>, CheckpointError> {
        let mut optimizer = BTreeMap::new();
        let prefix = format!("{role}/opt/");
        for name in self.tensors.names() {
            let key = match self.namespaced {
                true => name.strip_prefix(&prefix),
                false => (!name.starts_with("model/")).then_some(name),
            };
            if let Some(key) = key {
                optimizer.insert(key.to_string(), self.tensor(name)?.to_device(device));
            }
        }
        Ok(optimizer)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::nn;

    #[test]
    fn round_trip_restores_everything() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("checkpoint.safetensors");
        let vs = VarStore::new(Device::Cpu);
        let _ = nn::linear(vs.root() / "fc", 3, 2, Default::default());
        let optimizer_state = BTreeMap::from([(
            "momentum/fc.weight".to_string(),
            Tensor::ones([2, 3], (Kind::Float, Device::Cpu)),
        )]);
        let state = TrainState {
            epochs_done: 3,
            steps_done: 42,
            best_val_miou: Some(0.5),
            partial: Some(PartialEpoch {
                batches: 2,
                loss_sum: 1.5,
                images: 12,
                seconds: 3.0,
                wait_seconds: 0.1,
                term_sums: BTreeMap::from([("ce".to_string(), 1.5)]),
            }),
            records: vec![crate::run::tests::record(0)],
        };
        let critic = VarStore::new(Device::Cpu);
        let _ = nn::linear(critic.root() / "fc", 3, 2, Default::default());
        let parts = [
            Part {
                role: "student",
                vs: &vs,
                optimizer: &optimizer_state,
            },
            Part {
                role: "critic",
                vs: &critic,
                optimizer: &BTreeMap::new(),
            },
        ];
        save(&path, &parts, &state).unwrap();

        let mut other = VarStore::new(Device::Cpu);
        let _ = nn::linear(other.root() / "fc", 3, 2, Default::default());
        let mut other_critic = VarStore::new(Device::Cpu);
        let _ = nn::linear(other_critic.root() / "fc", 3, 2, Default::default());
        let (m, s) = load(
            &path,
            &mut [("student", &mut other), ("critic", &mut other_critic)],
        )
        .unwrap();
        assert_eq!(s, state);
        assert_eq!(read_state(&path).unwrap(), state);
        assert_eq!(m["student"].len(), 1);
        assert!(m["critic"].is_empty());
        assert_eq!(m["student"]["momentum/fc.weight"].size(), vec![2, 3]);
        // Same architecture, different roles: each role gets its own weights back.
        assert!(critic.variables()["fc.weight"].equal(&other_critic.variables()["fc.weight"]));
        assert!(!vs.variables()["fc.weight"].equal(&critic.variables()["fc.weight"]));
        let a = vs.variables();
        let b = other.variables();
        assert!(a["fc.weight"].equal(&b["fc.weight"]));
        assert!(a["fc.bias"].equal(&b["fc.bias"]));
    }

    #[test]
    fn wrong_network_is_refused_with_the_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.safetensors");
        let vs = VarStore::new(Device::Cpu);
        let _ = nn::linear(vs.root() / "fc", 3, 2, Default::default());
        save(
            &path,
            &[Part {
                role: "student",
                vs: &vs,
                optimizer: &BTreeMap::new(),
            }],
            &TrainState {
                epochs_done: 1,
                steps_done: 1,
                best_val_miou: None,
                partial: None,
                records: vec![],
            },
        )
        .unwrap();
        let mut other = VarStore::new(Device::Cpu);
        let _ = nn::linear(other.root() / "fc", 4, 2, Default::default());
        let err = load(&path, &mut [("student", &mut other)])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("fc.weight") && err.contains("c.safetensors"),
            "{err}"
        );
    }

    #[test]
    fn checkpoints_of_older_builds_load_as_the_student() {
        // The layout written before roles: `model/<name>`, optimiser keys un-prefixed.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.safetensors");
        let weight: Vec<u8> = [1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let bias: Vec<u8> = [0.5f32, -0.5]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let views = vec![
            (
                "model/fc.weight",
                TensorView::new(Dtype::F32, vec![2, 3], &weight).unwrap(),
            ),
            (
                "model/fc.bias",
                TensorView::new(Dtype::F32, vec![2], &bias).unwrap(),
            ),
            (
                "momentum/fc.bias",
                TensorView::new(Dtype::F32, vec![2], &bias).unwrap(),
            ),
        ];
        let state = r#"{"epochs_done":1,"steps_done":3,"best_val_miou":null}"#;
        let metadata = HashMap::from([(STATE_KEY.to_string(), state.to_string())]);
        std::fs::write(
            &path,
            safetensors::serialize(views, Some(metadata)).unwrap(),
        )
        .unwrap();

        let mut vs = VarStore::new(Device::Cpu);
        let _ = nn::linear(vs.root() / "fc", 3, 2, Default::default());
        let (optimizers, state) = load(&path, &mut [("student", &mut vs)]).unwrap();
        assert_eq!((state.epochs_done, state.steps_done), (1, 3));
        assert_eq!(
            Vec::<f32>::try_from(vs.variables()["fc.bias"].shallow_clone()).unwrap(),
            vec![0.5, -0.5]
        );
        assert_eq!(
            optimizers["student"].keys().collect::<Vec<_>>(),
            vec!["momentum/fc.bias"]
        );
        let mut critic = VarStore::new(Device::Cpu);
        let _ = nn::linear(critic.root() / "fc", 3, 2, Default::default());
        let err = load(&path, &mut [("critic", &mut critic)]).unwrap_err();
        assert!(err.to_string().contains("critic"), "{err}");
    }
}
