//! Starting weights given to a run (`rtf train --init`): fine-tuning from published weights,
//! and parity runs against a reference trainer that start both sides from one file
//! (issue 27). The trainer loads them with the strict loader of `rtf_models::io::weights`; this
//! module checks them before a run folder is written.

use std::collections::BTreeSet;
use std::path::Path;

use tch::nn::VarStore;

use crate::config::{NetworkConfig, TrainConfig, WeightsRef};
use crate::TrainError;

/// Which tensors of the network came from the `init_from` file and which kept their fresh
/// initial values (`init_reset_head`).
#[derive(Debug, Clone, PartialEq)]
pub struct InitReport {
    pub file: std::path::PathBuf,
    pub loaded: Vec<String>,
    pub fresh: Vec<String>,
}

impl std::fmt::Display for InitReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "init: {} of {} tensors loaded from {}",
            self.loaded.len(),
            self.loaded.len() + self.fresh.len(),
            self.file.display()
        )?;
        if !self.fresh.is_empty() {
            write!(f, "; start fresh (--reset-head): {}", self.fresh.join(", "))?;
        }
        Ok(())
    }
}

/// Loads the network's `init_from` file into `vs` (built from `network.model`): strictly, or
/// with the class-dependent tensors left fresh under `init_reset_head` (then the file may come
/// from a network of another class count; any other difference is still an error naming the
/// tensors). None without a file to load.
pub fn load_init(
    vs: &mut VarStore,
    network: &NetworkConfig,
) -> Result<Option<InitReport>, TrainError> {
    let path = match &network.init_from {
        None => return Ok(None),
        Some(WeightsRef::File(path)) => path,
        Some(WeightsRef::Stage(name)) => {
            return Err(TrainError::Config(format!(
                "init_from stage `{name}` was not resolved (stage references only work inside a multi-stage run)"
            )))
        }
    };
    let fresh = if network.init_reset_head {
        rtf_models::io::weights::class_dependent_names(&network.model)?
    } else {
        BTreeSet::new()
    };
    let tensors = rtf_models::io::weights::read_safetensors(path)?;
    rtf_models::io::weights::load_named_except(vs, tensors, path, &fresh)?;
    Ok(Some(report(vs, path, &fresh)))
}

fn report(vs: &VarStore, path: &Path, fresh: &BTreeSet<String>) -> InitReport {
    let (fresh, loaded): (Vec<String>, Vec<String>) = vs
        .variables()
        .into_keys()
        .partition(|name| fresh.contains(name));
    let sorted = |mut v: Vec<String>| {
        v.sort();
        v
    };
    InitReport {
        file: path.to_path_buf(),
        loaded: sorted(loaded),
        fresh: sorted(fresh),
    }
}

/// Loads the run's `init_from` file into a fresh CPU copy of its network, as the run will
/// ([`load_init`]), so that weights that do not fit are refused before a run folder is
/// written: the error names the file and each tensor that is missing, unexpected or of
/// another shape. A stage reference or no `init_from` passes.
pub fn check_init_weights(cfg: &TrainConfig) -> Result<Option<InitReport>, TrainError> {
    if !matches!(cfg.network.init_from, Some(WeightsRef::File(_))) {
        return Ok(None);
    }
    let mut vs = VarStore::new(tch::Device::Cpu);
    let uninitialised = rtf_models::BuildOptions::uninitialised();
    let _net = rtf_models::build_with(&vs.root(), &cfg.network.model, &uninitialised)?;
    load_init(&mut vs, &cfg.network)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtf_models::ModelConfig;

    fn mfnet_with_init(path: &std::path::Path) -> TrainConfig {
        let mut cfg = TrainConfig::mfnet_paper(std::path::PathBuf::new());
        cfg.network.model = ModelConfig::from_name("mfnet", 9).unwrap();
        cfg.network.init_from = Some(WeightsRef::File(path.to_path_buf()));
        cfg
    }

    #[test]
    fn matching_weights_pass_and_another_class_count_names_the_head_tensors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mfnet.safetensors");
        let model = ModelConfig::from_name("mfnet", 9).unwrap();
        let vs = tch::nn::VarStore::new(tch::Device::Cpu);
        let _net = rtf_models::build(&vs.root(), &model).unwrap();
        rtf_models::io::weights::save_safetensors(&vs, &model, Default::default(), &path).unwrap();
        check_init_weights(&mfnet_with_init(&path)).unwrap();

        let mut other = mfnet_with_init(&path);
        other.network.model = ModelConfig::from_name("mfnet", 5).unwrap();
        let err = check_init_weights(&other).unwrap_err().to_string();
        assert!(err.contains("mfnet.safetensors"), "{err}");
        assert!(err.contains("decode1.conv.weight"), "{err}");

        other.network.init_reset_head = true;
        let report = check_init_weights(&other).unwrap().unwrap();
        assert_eq!(report.fresh.len(), 6, "{report}");
        assert!(report.fresh.contains(&"decode1.conv.weight".to_string()));
        assert_eq!(report.loaded.len(), 228 - 6, "{report}");
        assert!(
            report.to_string().contains("222 of 228 tensors loaded"),
            "{report}"
        );
    }

    #[test]
    fn reset_head_still_refuses_a_mismatch_outside_the_head() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("other.safetensors");
        let vs = tch::nn::VarStore::new(tch::Device::Cpu);
        let _net = rtf_models::build(&vs.root(), &ModelConfig::from_name("mfnet", 9).unwrap());
        let named: Vec<_> = rtf_models::io::weights::state_dict(&vs)
            .into_iter()
            .map(|(name, t)| match name.as_str() {
                "conv1_rgb.conv.weight" => (name, tch::Tensor::zeros([1], tch::kind::FLOAT_CPU)),
                _ => (name, t),
            })
            .collect();
        rtf_models::io::weights::save_named(&named, &path).unwrap();
        let mut cfg = mfnet_with_init(&path);
        cfg.network.model = ModelConfig::from_name("mfnet", 5).unwrap();
        cfg.network.init_reset_head = true;
        let err = check_init_weights(&cfg).unwrap_err().to_string();
        assert!(err.contains("other.safetensors"), "{err}");
        assert!(err.contains("conv1_rgb"), "{err}");
    }
}
