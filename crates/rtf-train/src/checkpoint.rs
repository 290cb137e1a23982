//! Checkpoints: one safetensors file holding the weights (`model/<name>`), the optimiser's
//! state under its own keys (`momentum/<name>`, `square_avg/<name>`) and, in its metadata, the
//! training state. One file, written
//! atomically, so a checkpoint is never half old and half new.

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
}

const STATE_KEY: &str = "rtf_train_state";

/// A tensor as safetensors wants it: shape and little-endian f32 bytes.
type RawTensor = (Vec<usize>, Vec<u8>);

fn to_bytes(t: &Tensor) -> RawTensor {
    let t = t.to_device(Device::Cpu).to_kind(Kind::Float).contiguous();
    let shape = t.size().iter().map(|&d| d as usize).collect();
    let values = Vec::<f32>::try_from(t.flatten(0, -1)).expect("float tensor");
    (shape, values.iter().flat_map(|v| v.to_le_bytes()).collect())
}

/// Writes weights, the optimiser's state (keys as [`crate::Optimizer::state`] names them)
/// and the training state to `path` (temp file + rename).
pub fn save(
    path: &Path,
    vs: &VarStore,
    optimizer_state: &BTreeMap<String, Tensor>,
    state: &TrainState,
) -> Result<(), CheckpointError> {
    let mut named: Vec<(String, RawTensor)> = Vec::new();
    for (name, t) in vs.variables() {
        named.push((format!("model/{name}"), to_bytes(&t)));
    }
    for (key, t) in optimizer_state {
        debug_assert!(!key.starts_with("model/"), "optimizer key {key}");
        named.push((key.clone(), to_bytes(t)));
    }
    let views = named
        .iter()
        .map(|(n, (shape, bytes))| {
            TensorView::new(Dtype::F32, shape.clone(), bytes).map(|v| (n.clone(), v))
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| CheckpointError::Invalid {
            path: path.into(),
            message: e.to_string(),
        })?;
    let metadata = HashMap::from([(
        STATE_KEY.to_string(),
        serde_json::to_string(state).expect("state serialises"),
    )]);
    let bytes =
        safetensors::serialize(views, Some(metadata)).map_err(|e| CheckpointError::Invalid {
            path: path.into(),
            message: e.to_string(),
        })?;
    rtf_core::write_bytes_atomic(path, &bytes).map_err(|e| CheckpointError::Io {
        path: path.into(),
        source: std::io::Error::other(e.to_string()),
    })
}

/// Restores weights into `vs` (every variable must be present with its shape) and returns the
/// optimiser's state and the training state.
pub fn load(
    path: &Path,
    vs: &mut VarStore,
) -> Result<(BTreeMap<String, Tensor>, TrainState), CheckpointError> {
    let invalid = |message: String| CheckpointError::Invalid {
        path: path.into(),
        message,
    };
    let bytes = std::fs::read(path).map_err(|source| CheckpointError::Io {
        path: path.into(),
        source,
    })?;
    let (_, metadata) = SafeTensors::read_metadata(&bytes)
        .map_err(|e| invalid(format!("not a safetensors file: {e}")))?;
    let state: TrainState = metadata
        .metadata()
        .as_ref()
        .and_then(|m| m.get(STATE_KEY))
        .ok_or_else(|| invalid("no training state in metadata (not an rtf checkpoint)".into()))
        .and_then(|s| {
            serde_json::from_str(s).map_err(|e| invalid(format!("bad training state: {e}")))
        })?;
    let tensors = SafeTensors::deserialize(&bytes).map_err(|e| invalid(e.to_string()))?;
    let read = |name: &str| -> Result<Tensor, CheckpointError> {
        let view = tensors
            .tensor(name)
            .map_err(|_| invalid(format!("missing tensor `{name}`")))?;
        if view.dtype() != Dtype::F32 {
            return Err(invalid(format!(
                "tensor `{name}` is {:?}, expected F32",
                view.dtype()
            )));
        }
        let values: Vec<f32> = view
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let shape: Vec<i64> = view.shape().iter().map(|&d| d as i64).collect();
        Ok(Tensor::from_slice(&values).view(shape.as_slice()))
    };
    let device = vs.device();
    let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    vars.sort_by(|a, b| a.0.cmp(&b.0));
    tch::no_grad(|| -> Result<(), CheckpointError> {
        for (name, mut var) in vars {
            let saved = read(&format!("model/{name}"))?;
            if saved.size() != var.size() {
                return Err(invalid(format!(
                    "`{name}` has shape {:?}, the network expects {:?}",
                    saved.size(),
                    var.size()
                )));
            }
            var.copy_(&saved.to_device(device));
        }
        Ok(())
    })?;
    let mut optimizer_state = BTreeMap::new();
    for name in tensors.names() {
        if !name.starts_with("model/") {
            optimizer_state.insert(name.to_string(), read(name)?.to_device(device));
        }
    }
    Ok((optimizer_state, state))
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
            }),
        };
        save(&path, &vs, &optimizer_state, &state).unwrap();

        let mut other = VarStore::new(Device::Cpu);
        let _ = nn::linear(other.root() / "fc", 3, 2, Default::default());
        let (m, s) = load(&path, &mut other).unwrap();
        assert_eq!(s, state);
        assert_eq!(m.len(), 1);
        assert_eq!(m["momentum/fc.weight"].size(), vec![2, 3]);
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
            &vs,
            &BTreeMap::new(),
            &TrainState {
                epochs_done: 1,
                steps_done: 1,
                best_val_miou: None,
                partial: None,
            },
        )
        .unwrap();
        let mut other = VarStore::new(Device::Cpu);
        let _ = nn::linear(other.root() / "fc", 4, 2, Default::default());
        let err = load(&path, &mut other).unwrap_err().to_string();
        assert!(
            err.contains("fc.weight") && err.contains("c.safetensors"),
            "{err}"
        );
    }
}
