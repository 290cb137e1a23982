//! Weights in and out as safetensors state_dicts with the reference parameter names.
//!
//! Loading is strict: every network variable must be present with the same shape and the file
//! may hold nothing else (PyTorch's `num_batches_tracked` counters carry no weights and are
//! skipped). On any difference the error lists all missing, unexpected and misshaped names.

use std::collections::BTreeMap;
use std::path::Path;

use tch::nn::VarStore;
use tch::Tensor;

use crate::error::{ModelError, ShapeMismatch};

/// PyTorch BatchNorm counters; present in reference state_dicts, absent from tch's VarStore.
pub fn is_ignored_name(name: &str) -> bool {
    name.ends_with("num_batches_tracked")
}

/// Reads every tensor of a safetensors file, in file order.
pub fn read_safetensors(path: &Path) -> Result<Vec<(String, Tensor)>, ModelError> {
    if !path.is_file() {
        return Err(ModelError::Read {
            path: path.to_path_buf(),
            message: "no such file".into(),
        });
    }
    Tensor::read_safetensors(path).map_err(|e| ModelError::Read {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Loads a safetensors state_dict into `vs` (strict; see the module docs). Nothing is copied
/// unless the whole file matches, so a refused file leaves the network untouched.
pub fn load_safetensors(vs: &mut VarStore, path: &Path) -> Result<(), ModelError> {
    let tensors = read_safetensors(path)?;
    load_named(vs, tensors, path)
}

/// Strict load from already-read named tensors; `source` names where they came from.
pub fn load_named(
    vs: &mut VarStore,
    tensors: Vec<(String, Tensor)>,
    source: &Path,
) -> Result<(), ModelError> {
    let vars: BTreeMap<String, Tensor> = vs.variables().into_iter().collect();
    let file: BTreeMap<String, Tensor> = tensors
        .into_iter()
        .filter(|(name, _)| !is_ignored_name(name))
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
    if !missing.is_empty() || !unexpected.is_empty() || !mismatched.is_empty() {
        return Err(ModelError::Mismatch {
            path: source.to_path_buf(),
            missing,
            unexpected,
            mismatched,
        });
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

/// Writes the variables of `vs` as a safetensors state_dict with the reference names, through
/// a temporary file renamed into place.
pub fn save_safetensors(vs: &VarStore, path: &Path) -> Result<(), ModelError> {
    save_named(&state_dict(vs), path)
}

/// Writes named tensors as safetensors, atomically.
pub fn save_named(named: &[(String, Tensor)], path: &Path) -> Result<(), ModelError> {
    rtf_core::write_atomic(path, |tmp| Tensor::write_safetensors(named, tmp)).map_err(|e| {
        ModelError::Write {
            path: path.to_path_buf(),
            message: e.to_string(),
        }
    })
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
        save_safetensors(&vs_a, &file).unwrap();
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
}
