//! Starting weights given to a run (`rtf train --init`): fine-tuning from published weights,
//! and parity runs against a reference trainer that start both sides from one file
//! (issue 27). The trainer loads them with the strict loader of `rtf_models::weights`; this
//! module checks them before a run folder is written.

use crate::config::{TrainConfig, WeightsRef};
use crate::TrainError;

/// Loads the run's `init_from` file into a fresh CPU copy of its network: every tensor must be
/// present with the network's shape, and the error names the file and each tensor that is
/// missing, unexpected or of another shape. A stage reference or no `init_from` passes.
pub fn check_init_weights(cfg: &TrainConfig) -> Result<(), TrainError> {
    let Some(WeightsRef::File(path)) = &cfg.init_from else {
        return Ok(());
    };
    let mut vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let _net = rtf_models::build(&vs.root(), &cfg.model)?;
    rtf_models::weights::load_safetensors(&mut vs, path)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtf_models::ModelConfig;

    fn mfnet_with_init(path: &std::path::Path) -> TrainConfig {
        let mut cfg = TrainConfig::mfnet_paper(std::path::PathBuf::new());
        cfg.model = ModelConfig::from_name("mfnet", 9).unwrap();
        cfg.init_from = Some(WeightsRef::File(path.to_path_buf()));
        cfg
    }

    #[test]
    fn matching_weights_pass_and_another_class_count_names_the_head_tensors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mfnet.safetensors");
        let model = ModelConfig::from_name("mfnet", 9).unwrap();
        let vs = tch::nn::VarStore::new(tch::Device::Cpu);
        let _net = rtf_models::build(&vs.root(), &model).unwrap();
        rtf_models::weights::save_safetensors(&vs, &model, Default::default(), &path).unwrap();
        check_init_weights(&mfnet_with_init(&path)).unwrap();

        let mut other = mfnet_with_init(&path);
        other.model = ModelConfig::from_name("mfnet", 5).unwrap();
        let err = check_init_weights(&other).unwrap_err().to_string();
        assert!(err.contains("mfnet.safetensors"), "{err}");
        assert!(err.contains("decode1.conv.weight"), "{err}");
    }
}
