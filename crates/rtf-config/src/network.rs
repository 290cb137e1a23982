//! Which network a run builds, with its options ([`ModelConfig`], tagged by `network` in a
//! configuration), and which input channels it sees ([`Modality`]). The options of each
//! network family are in its module; the networks themselves are rtf-models', which builds
//! them from these values.

use serde::{Deserialize, Serialize};

pub mod baselines;
pub mod cmx;
pub mod heatnet;
pub mod mfnet;
pub mod rtfnet;

/// The ResNet depths torchvision builds (RTFNet's encoders).
pub const RESNET_DEPTHS: [i64; 5] = [18, 34, 50, 101, 152];

/// BatchNorm epsilon of every reference network (PyTorch's `nn.BatchNorm2d` default).
pub const BN_EPS: f64 = 1e-5;

/// A network configuration that names no network or cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NetworkConfigError {
    #[error("unknown model {name:?}; known models: {known}")]
    Unknown { name: String, known: String },
    #[error("invalid {network} configuration: {reason}")]
    Invalid { network: String, reason: String },
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
    pub fn from_name(name: &str, num_classes: i64) -> Result<Self, NetworkConfigError> {
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
                return Err(NetworkConfigError::Unknown {
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

/// The class count a named model is usually built with: Freiburg's 13 for HeatNet, MF's 9
/// otherwise.
pub fn default_num_classes(name: &str) -> i64 {
    if name.starts_with("heatnet") {
        rtf_core::ClassSet::freiburg().len() as i64
    } else {
        rtf_core::ClassSet::mf().len() as i64
    }
}

/// Every name [`ModelConfig::from_name`] accepts.
pub fn model_names() -> Vec<String> {
    let mut names = vec!["mfnet".to_string(), "mfnet-paper".to_string()];
    names.extend(mfnet::VARIANT_LETTERS.iter().map(|l| format!("mfnet-{l}")));
    for depth in RESNET_DEPTHS {
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
    RESNET_DEPTHS.contains(&depth).then_some(())?;
    let variant = rtfnet::Variant::ALL
        .into_iter()
        .find(|v| v.suffix() == suffix)?;
    Some((depth, variant))
}

/// The modalities of the 4-channel input (R, G, B, T) a network sees.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Modality {
    #[default]
    RgbT,
    Rgb,
    Thermal,
}

impl Modality {
    pub fn name(self) -> &'static str {
        match self {
            Modality::RgbT => "rgb_t",
            Modality::Rgb => "rgb",
            Modality::Thermal => "thermal",
        }
    }

    pub fn parse(text: &str) -> Result<Self, String> {
        match text {
            "rgb_t" | "rgbt" | "rgb-t" => Ok(Modality::RgbT),
            "rgb" => Ok(Modality::Rgb),
            "thermal" | "ir" => Ok(Modality::Thermal),
            other => Err(format!(
                "unknown inputs `{other}` (expected rgb_t, rgb or thermal)"
            )),
        }
    }

    /// (first channel, channel count) of this modality in the network input.
    pub fn channels(self) -> (usize, usize) {
        match self {
            Modality::RgbT => (0, 4),
            Modality::Rgb => (0, 3),
            Modality::Thermal => (3, 1),
        }
    }
}

impl std::fmt::Display for Modality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_name_round_trips() {
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
    fn names_parse_back() {
        for m in [Modality::RgbT, Modality::Rgb, Modality::Thermal] {
            assert_eq!(Modality::parse(m.name()), Ok(m));
        }
        assert!(Modality::parse("depth").unwrap_err().contains("depth"));
    }
}
