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

/// Which network to build, with its options; nested in training configs as
/// `{"network": "mfnet", "num_classes": 9, ...}`.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(tag = "network", rename_all = "snake_case")]
pub enum ModelConfig {
    Mfnet(mfnet::Config),
    Rtfnet(rtfnet::Config),
    Heatnet(heatnet::Config),
    Baseline(baselines::Config),
    Cmx(cmx::Config),
}

impl ModelConfig {
    /// The configuration of a named model (see [`model_names`]).
    pub fn from_name(name: &str, num_classes: i64) -> Result<Self, ModelError> {
        let cfg = match name {
            "mfnet" => Self::Mfnet(mfnet::Config::reference(num_classes)),
            "mfnet-paper" => Self::Mfnet(mfnet::Config::paper(num_classes)),
            _ if mfnet_letter(name).is_some() => Self::Mfnet(
                mfnet::Config::variant(mfnet_letter(name).unwrap(), num_classes).unwrap(),
            ),
            _ if heatnet_inputs(name).is_some() => Self::Heatnet(heatnet::Config::new(
                heatnet_inputs(name).unwrap(),
                num_classes,
            )),
            _ if parse_baseline(name).is_some() => {
                let (arch, c) = parse_baseline(name).unwrap();
                Self::Baseline(baselines::Config::new(arch, c, num_classes))
            }
            _ if cmx::Size::from_name(name).is_some() => Self::Cmx(cmx::Config::new(
                cmx::Size::from_name(name).unwrap(),
                num_classes,
            )),
            _ if parse_rtfnet(name).is_some() => {
                let (depth, variant) = parse_rtfnet(name).unwrap();
                Self::Rtfnet(rtfnet::Config::new(depth, num_classes, variant))
            }
            _ => {
                return Err(ModelError::UnknownModel {
                    name: name.to_string(),
                    known: model_names().join(", "),
                })
            }
        };
        Ok(cfg)
    }

    /// Canonical name; `from_name(cfg.name())` gives back `cfg` for named configurations.
    pub fn name(&self) -> String {
        match self {
            Self::Mfnet(c) => c.name(),
            Self::Rtfnet(c) => c.name(),
            Self::Heatnet(c) => c.name(),
            Self::Baseline(c) => c.name(),
            Self::Cmx(c) => c.name(),
        }
    }

    pub fn num_classes(&self) -> i64 {
        match self {
            Self::Mfnet(c) => c.num_classes,
            Self::Rtfnet(c) => c.num_classes,
            Self::Heatnet(c) => c.num_classes,
            Self::Baseline(c) => c.num_classes,
            Self::Cmx(c) => c.num_classes,
        }
    }

    /// The same network with another class count (fine-tuning onto a new class set).
    pub fn with_num_classes(&self, num_classes: i64) -> Self {
        let mut cfg = self.clone();
        match &mut cfg {
            Self::Mfnet(c) => c.num_classes = num_classes,
            Self::Rtfnet(c) => c.num_classes = num_classes,
            Self::Heatnet(c) => c.num_classes = num_classes,
            Self::Baseline(c) => c.num_classes = num_classes,
            Self::Cmx(c) => c.num_classes = num_classes,
        }
        cfg
    }

    /// The unit-range input (R, G, B, T in [0, 1]) that the network's input normalisation maps
    /// to 0: what "0 after normalisation" is in rtf's unit-range data pipeline (CMX's official
    /// training pads normalised images with 0). The mean of a mean/std convention; CMX's own
    /// normalisation ([`cmx::Config::normalised_zero`]); 0 for unit-range networks.
    pub fn normalised_zero(&self) -> [f32; 4] {
        match (self, self.input_convention()) {
            (Self::Cmx(c), _) => c.normalised_zero(),
            (_, rtf_core::InputConvention::MeanStd { mean, .. }) => [mean; 4],
            (_, rtf_core::InputConvention::UnitRange) => [0.0; 4],
        }
    }

    /// The network with its decoder's BatchNorm at `eps` where it has one that the official
    /// training sets apart (CMX: `config.bn_eps` on `decode_head`); the others unchanged.
    pub fn with_decoder_bn_eps(&self, eps: f64) -> Self {
        let mut cfg = self.clone();
        if let Self::Cmx(c) = &mut cfg {
            c.decoder_bn_eps = eps;
        }
        cfg
    }

    pub fn input_convention(&self) -> rtf_core::InputConvention {
        match self {
            Self::Mfnet(c) => c.input,
            Self::Rtfnet(c) => c.input,
            Self::Heatnet(c) => c.input,
            Self::Baseline(c) => c.input,
            Self::Cmx(c) => c.input(),
        }
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

/// The class count a named model is usually built with: Freiburg's 13 for HeatNet, MF's 9
/// otherwise.
pub fn default_num_classes(name: &str) -> i64 {
    if name.starts_with("heatnet") {
        rtf_core::ClassSet::freiburg().len() as i64
    } else {
        rtf_core::ClassSet::mf().len() as i64
    }
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

/// Every name [`ModelConfig::from_name`] accepts.
pub fn model_names() -> Vec<String> {
    let mut names = vec!["mfnet".to_string(), "mfnet-paper".to_string()];
    names.extend(mfnet::VARIANT_LETTERS.iter().map(|l| format!("mfnet-{l}")));
    for depth in resnet::DEPTHS {
        for variant in rtfnet::Variant::ALL {
            names.push(format!("rtfnet{depth}{}", variant.suffix()));
        }
    }
    for inputs in heatnet::Inputs::ALL {
        names.push(format!("heatnet{}", inputs.suffix()));
    }
    for arch in baselines::Arch::ALL {
        for &c in arch.channel_options() {
            names.push(baselines::Config::new(arch, c, 9).name());
        }
    }
    names.extend(cmx::Size::ALL.map(|size| cmx::Config::new(size, 9).name()));
    names
}

/// `erfnet-3c` -> (Erfnet, 3); `fusenet` -> (Fusenet, 4).
fn parse_baseline(name: &str) -> Option<(baselines::Arch, i64)> {
    baselines::Arch::ALL.into_iter().find_map(|arch| {
        let c = *arch
            .channel_options()
            .iter()
            .find(|&&c| baselines::Config::new(arch, c, 1).name() == name)?;
        Some((arch, c))
    })
}

/// `heatnet-early` -> Early.
fn heatnet_inputs(name: &str) -> Option<heatnet::Inputs> {
    let suffix = name.strip_prefix("heatnet")?;
    heatnet::Inputs::ALL
        .into_iter()
        .find(|i| i.suffix() == suffix)
}

/// `mfnet-e` -> 'e' for the MFNet Tab. III letters.
fn mfnet_letter(name: &str) -> Option<char> {
    let mut rest = name.strip_prefix("mfnet-")?.chars();
    let letter = rest.next()?;
    (rest.next().is_none() && mfnet::VARIANT_LETTERS.contains(&letter)).then_some(letter)
}

/// `rtfnet50-nre` -> (50, Nre).
fn parse_rtfnet(name: &str) -> Option<(i64, rtfnet::Variant)> {
    let rest = name.strip_prefix("rtfnet")?;
    let (depth, suffix) = match rest.find('-') {
        Some(i) => rest.split_at(i),
        None => (rest, ""),
    };
    let depth: i64 = depth.parse().ok()?;
    resnet::layout(depth)?;
    let variant = rtfnet::Variant::ALL
        .into_iter()
        .find(|v| v.suffix() == suffix)?;
    Some((depth, variant))
}

#[cfg(test)]
mod test_util;

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{nn::VarStore, Device};

    #[test]
    fn every_name_builds_and_round_trips() {
        for name in model_names() {
            let cfg = ModelConfig::from_name(&name, 9).unwrap();
            assert_eq!(cfg.name(), name);
            assert_eq!(cfg.num_classes(), 9);
            let json = serde_json::to_string(&cfg).unwrap();
            assert_eq!(
                serde_json::from_str::<ModelConfig>(&json).unwrap(),
                cfg,
                "{json}"
            );
        }
    }

    #[test]
    fn config_json_is_tagged_by_network() {
        let cfg: ModelConfig =
            serde_json::from_str(r#"{"network": "mfnet", "num_classes": 4}"#).unwrap();
        assert_eq!(cfg, ModelConfig::from_name("mfnet", 4).unwrap());
        let cfg: ModelConfig =
            serde_json::from_str(r#"{"network": "cmx", "size": "b2", "num_classes": 4}"#).unwrap();
        assert_eq!(cfg, ModelConfig::from_name("cmx-mit-b2", 4).unwrap());
    }

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

    /// "0 after normalisation" per network family, and the decoder eps only where a network
    /// has that BatchNorm.
    #[test]
    fn normalised_zero_and_decoder_eps_follow_the_network() {
        let named = |n: &str| ModelConfig::from_name(n, 9).unwrap();
        assert_eq!(named("mfnet").normalised_zero(), [0.0; 4]);
        assert_eq!(named("heatnet").normalised_zero(), [0.5; 4]);
        let cmx = named("cmx-mit-b0").normalised_zero();
        assert_eq!(&cmx[..3], &[0.406, 0.456, 0.485]);
        assert!((cmx[3] - 0.4486).abs() < 1e-3, "{cmx:?}");
        assert_eq!(named("mfnet").with_decoder_bn_eps(1e-3), named("mfnet"));
        let ModelConfig::Cmx(c) = named("cmx-mit-b0").with_decoder_bn_eps(1e-3) else {
            panic!("a CMX config")
        };
        assert_eq!(c.decoder_bn_eps, 1e-3);
    }

    #[test]
    fn unknown_name_lists_known_ones() {
        let err = ModelConfig::from_name("mfnett", 9).unwrap_err().to_string();
        assert!(
            err.contains("mfnett") && err.contains("mfnet-paper"),
            "{err}"
        );
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
