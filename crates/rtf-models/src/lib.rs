//! rtf-models: the networks of MFNet, RTFNet, HeatNet and CMX on tch, with the reference
//! implementations' parameter names, and their weights in and out as safetensors ([`io`]).
//! The kernels they run on (oneDNN's fused convolutions, Winograd, the C++ op shim) are
//! rtf-kernels'.
//!
//! Every network takes `[B, 4, H, W]` = R, G, B, T already scaled by its
//! [`Network::input_convention`]; networks that use fewer channels select them inside forward.
//! Output: logits `[B, num_classes, H, W]`.

pub mod backbone;
pub mod baselines;
pub mod bn_defaults;
pub mod cmx;
pub mod error;
pub mod fast;
pub mod heatnet;
pub mod inputs;
pub mod io;
pub mod layers;
pub mod mfnet;
pub mod release;
pub mod resnet;
pub mod rtfnet;
pub mod sync_bn;
pub mod tolerance;

use serde::{Deserialize, Serialize};
use tch::nn;

pub use error::{ModelError, ShapeMismatch};
pub use inputs::{masked, Masked, Modality};
pub use layers::{BuildOptions, UnitKernels};
/// Which network to build, with its options: the schema's (rtf-config), read without libtorch.
pub use rtf_config::network::{default_num_classes, model_names, ModelConfig, NetworkConfigError};
pub use sync_bn::StatsAllReduce;

/// What every segmentation network offers beyond its forward pass.
pub trait Network: nn::ModuleT {
    /// How the input must be scaled (MFNet/RTFNet: pixel / 255).
    fn input_convention(&self) -> rtf_core::InputConvention;
    fn num_classes(&self) -> i64;
    /// Input H and W must be multiples of this.
    fn size_multiple(&self) -> i64;
    /// Canonical model name (as accepted by [`ModelConfig::from_name`]).
    fn name(&self) -> String;

    /// The network's inference form, built anew as `folder` says ([`fast`]): BatchNorm folded
    /// into the convolutions, weights laid out and cast for inference, eval forward only.
    /// `None` for networks without a folded path (their eval forward is then the plain one).
    fn folded(&self, folder: &fast::folder::Folder) -> Option<Box<dyn Network>> {
        let _ = folder;
        None
    }

    /// Checks an input shape before forward (which panics inside libtorch on bad shapes).
    fn check_input(&self, shape: &[i64]) -> Result<(), ModelError> {
        let bad = |reason: String| ModelError::InvalidInput {
            network: self.name(),
            shape: shape.to_vec(),
            reason,
        };
        if shape.len() != 4 {
            return Err(bad("expected [B, 4, H, W]".into()));
        }
        if shape[1] != 4 {
            return Err(bad(format!(
                "expected 4 channels (R, G, B, T), got {}",
                shape[1]
            )));
        }
        let m = self.size_multiple();
        if shape[0] < 1 || shape[2] < m || shape[3] < m || shape[2] % m != 0 || shape[3] % m != 0 {
            return Err(bad(format!("H and W must be positive multiples of {m}")));
        }
        Ok(())
    }
}

/// Builds the network described by `cfg` under `p` (parameter paths = reference names), with
/// the default [`BuildOptions`]: initialised variables, every Winograd form, libtorch's bf16
/// kernels, per-process BatchNorm statistics.
pub fn build(p: &nn::Path, cfg: &ModelConfig) -> Result<Box<dyn Network>, ModelError> {
    build_with(p, cfg, &BuildOptions::default())
}

/// [`build`] with `options`: how the network's plain units compute (a training run's recorded
/// kernels) and whether its variables are initialised.
pub fn build_with(
    p: &nn::Path,
    cfg: &ModelConfig,
    options: &BuildOptions,
) -> Result<Box<dyn Network>, ModelError> {
    let p = layers::Path::new(p.clone(), options);
    Ok(match cfg {
        ModelConfig::Mfnet(c) => Box::new(mfnet::MfNet::new(p, c)?) as Box<dyn Network>,
        ModelConfig::Rtfnet(c) => Box::new(rtfnet::RtfNet::new(p, c)?),
        ModelConfig::Heatnet(c) => Box::new(heatnet::HeatNet::new(p, c)?),
        ModelConfig::Baseline(c) => Box::new(baselines::Baseline::new(p, c)?),
        ModelConfig::Cmx(c) => Box::new(cmx::Cmx::new(p, c)?),
    })
}

/// Trainable parameter count of a configuration, without initialising any weights.
pub fn count_parameters(cfg: &ModelConfig) -> Result<i64, ModelError> {
    let vs = nn::VarStore::new(tch::Device::Cpu);
    build_with(&vs.root(), cfg, &BuildOptions::uninitialised())?;
    Ok(io::weights::count_trainable(&vs))
}

/// One row of `rtf models`.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct ModelInfo {
    pub name: String,
    /// Trainable parameters with [`default_num_classes`] classes.
    pub params: i64,
    /// float32 parameter bytes / 2^20.
    pub megabytes: f64,
}

/// Every named model with its parameter count and size, then HeatNet's critic (a training
/// module, not a segmentation network: `heatnet-critic`, reading Freiburg's 13 classes).
pub fn model_infos() -> Result<Vec<ModelInfo>, ModelError> {
    let info = |name: String, params: i64| ModelInfo {
        name,
        params,
        megabytes: params as f64 * 4.0 / (1u64 << 20) as f64,
    };
    let mut infos = model_names()
        .into_iter()
        .map(|name| {
            let cfg = ModelConfig::from_name(&name, default_num_classes(&name))?;
            Ok(info(name, count_parameters(&cfg)?))
        })
        .collect::<Result<Vec<_>, ModelError>>()?;
    let vs = nn::VarStore::new(tch::Device::Cpu);
    let cfg = heatnet::CriticConfig {
        in_channels: rtf_core::ClassSet::freiburg().len() as i64,
    };
    heatnet::Critic::new(
        layers::Path::new(vs.root(), &BuildOptions::uninitialised()),
        &cfg,
    )?;
    let critic = io::weights::count_trainable(&vs);
    infos.push(info("heatnet-critic".into(), critic));
    Ok(infos)
}

#[cfg(test)]
mod test_util;

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{nn::VarStore, Device};

    #[test]
    fn counting_without_init_matches_a_real_build() {
        for name in ["mfnet", "rtfnet18-nub", "heatnet", "cmx-mit-b0"] {
            let cfg = ModelConfig::from_name(name, default_num_classes(name)).unwrap();
            let vs = VarStore::new(Device::Cpu);
            build(&vs.root(), &cfg).unwrap();
            assert_eq!(
                count_parameters(&cfg).unwrap(),
                io::weights::count_trainable(&vs),
                "{name}"
            );
        }
    }

    #[test]
    fn model_infos_cover_every_name_with_reference_counts() {
        let infos = model_infos().unwrap();
        assert_eq!(infos.len(), model_names().len() + 1);
        let params = |name: &str| infos.iter().find(|i| i.name == name).unwrap().params;
        // Reference counts (spec §3–5).
        assert_eq!(params("mfnet"), 736_275);
        assert_eq!(params("rtfnet152"), 254_510_053);
        assert_eq!(params("heatnet"), 54_361_040);
        assert_eq!(params("heatnet-critic"), 2_774_977);
        // The official CMX network (cmx.rs tests).
        assert_eq!(params("cmx-mit-b2"), 66_565_521);
        assert_eq!(params("cmx-mit-b5"), 181_058_961);
        let mf = infos.iter().find(|i| i.name == "mfnet").unwrap();
        assert!((mf.megabytes - 736_275.0 * 4.0 / 1048576.0).abs() < 1e-9);
        // Counting does not leave zero-initialised builds behind.
        let vs = VarStore::new(Device::Cpu);
        build(&vs.root(), &ModelConfig::from_name("mfnet", 9).unwrap()).unwrap();
        let w = &vs.variables()["decode1.conv.weight"];
        assert!(w.abs().sum(tch::Kind::Float).double_value(&[]) > 0.0);
    }

    #[test]
    fn check_input_rejects_bad_shapes() {
        let vs = VarStore::new(Device::Cpu);
        let net = build(&vs.root(), &ModelConfig::from_name("mfnet", 9).unwrap()).unwrap();
        assert!(net.check_input(&[1, 4, 480, 640]).is_ok());
        for bad in [
            &[1, 3, 64, 64][..],
            &[1, 4, 60, 64],
            &[4, 64, 64],
            &[1, 4, 0, 64],
        ] {
            let err = net.check_input(bad).unwrap_err().to_string();
            assert!(err.contains("mfnet"), "{err}");
        }
    }
}
