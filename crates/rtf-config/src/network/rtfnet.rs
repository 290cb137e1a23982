//! RTFNet's options (Sun et al., RA-L 2019; spec §4): the ResNet depth and the paper's
//! ablations (IV-D). The network is rtf-models' `rtfnet`.

use serde::{Deserialize, Serialize};

use super::NetworkConfigError;

/// The paper's ablations of Fig. 3 / Tab. IV–V.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum Variant {
    /// RTFNet as published.
    #[default]
    Full,
    /// No RGB encoder: thermal encoder → decoder.
    Nre,
    /// No thermal encoder: RGB encoder → decoder.
    Nte,
    /// No Upception blocks: each decoder stage is ConvTranspose 2×2 s2 → BN → ReLU.
    Nub,
    /// Only the last fusion (after layer4); no fusion after the stem and layer1..3.
    Olf,
    /// Fusion at the channel input: one encoder on the 4-channel RGB-T image.
    Fci,
}

impl Variant {
    pub const ALL: [Variant; 6] = [
        Variant::Full,
        Variant::Nre,
        Variant::Nte,
        Variant::Nub,
        Variant::Olf,
        Variant::Fci,
    ];

    /// Name suffix (`rtfnet50-nre`), empty for the full network.
    pub fn suffix(self) -> &'static str {
        match self {
            Variant::Full => "",
            Variant::Nre => "-nre",
            Variant::Nte => "-nte",
            Variant::Nub => "-nub",
            Variant::Olf => "-olf",
            Variant::Fci => "-fci",
        }
    }
}

/// How the thermal stem is initialised when ImageNet backbone weights are loaded.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum ThermalInit {
    /// The reference code: mean over the input channels of the pretrained RGB conv1.
    #[default]
    MeanOfRgb,
    /// The paper's text: Xavier-uniform.
    Xavier,
}

#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// ResNet depth: 18, 34, 50, 101 or 152.
    pub depth: i64,
    pub num_classes: i64,
    #[serde(default)]
    pub variant: Variant,
    #[serde(default)]
    pub thermal_init: ThermalInit,
    #[serde(default)]
    pub input: rtf_core::InputConvention,
}

impl Config {
    pub fn new(depth: i64, num_classes: i64, variant: Variant) -> Self {
        Self {
            depth,
            num_classes,
            variant,
            thermal_init: ThermalInit::MeanOfRgb,
            input: rtf_core::InputConvention::UnitRange,
        }
    }

    /// `rtfnet50`, `rtfnet152-fci`, …
    pub fn name(&self) -> String {
        format!("rtfnet{}{}", self.depth, self.variant.suffix())
    }

    pub fn validate(&self) -> Result<(), NetworkConfigError> {
        let err = |reason: String| NetworkConfigError::Invalid {
            network: self.name(),
            reason,
        };
        if !super::RESNET_DEPTHS.contains(&self.depth) {
            return Err(err(format!(
                "depth must be one of {:?}",
                super::RESNET_DEPTHS
            )));
        }
        if self.num_classes < 1 {
            return Err(err(format!(
                "num_classes must be ≥ 1, got {}",
                self.num_classes
            )));
        }
        Ok(())
    }

    /// Whether the network has an RGB / a thermal encoder (FCI has one 4-channel encoder).
    pub fn encoders(&self) -> (bool, bool) {
        match self.variant {
            Variant::Nre => (false, true),
            Variant::Nte => (true, false),
            Variant::Fci => (false, false),
            _ => (true, true),
        }
    }
}
