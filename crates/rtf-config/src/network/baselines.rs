//! The papers' baseline networks' options (RTFNet Tab. III, MFNet Tab. II/IV): the
//! architecture and its input channels. The networks are rtf-models' `baselines`.

use serde::{Deserialize, Serialize};

use super::NetworkConfigError;

/// The baseline architectures.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Arch {
    Segnet,
    Unet,
    Pspnet,
    Duchdc,
    Erfnet,
    Enet,
    Fusenet,
}

impl Arch {
    pub const ALL: [Arch; 7] = [
        Arch::Erfnet,
        Arch::Unet,
        Arch::Pspnet,
        Arch::Segnet,
        Arch::Duchdc,
        Arch::Fusenet,
        Arch::Enet,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Arch::Segnet => "segnet",
            Arch::Unet => "unet",
            Arch::Pspnet => "pspnet",
            Arch::Duchdc => "duchdc",
            Arch::Erfnet => "erfnet",
            Arch::Enet => "enet",
            Arch::Fusenet => "fusenet",
        }
    }

    /// Input channel counts offered (FuseNet: two streams, always RGB + thermal).
    pub fn channel_options(self) -> &'static [i64] {
        match self {
            Arch::Fusenet => &[4],
            _ => &[3, 4],
        }
    }

    /// Input sides must be multiples of this.
    pub fn size_multiple(self) -> i64 {
        match self {
            Arch::Pspnet | Arch::Duchdc => 8,
            Arch::Enet | Arch::Erfnet => 8,
            _ => 32,
        }
    }
}

#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub arch: Arch,
    /// 3: RGB only; 4: RGB-T stacked as one input.
    pub in_channels: i64,
    pub num_classes: i64,
    #[serde(default)]
    pub input: rtf_core::InputConvention,
}

impl Config {
    pub fn new(arch: Arch, in_channels: i64, num_classes: i64) -> Self {
        Self {
            arch,
            in_channels,
            num_classes,
            input: rtf_core::InputConvention::UnitRange,
        }
    }

    /// `erfnet-3c`, `unet-4c`, …, `fusenet`.
    pub fn name(&self) -> String {
        match self.arch {
            Arch::Fusenet => "fusenet".into(),
            a => format!("{}-{}c", a.as_str(), self.in_channels),
        }
    }

    pub fn validate(&self) -> Result<(), NetworkConfigError> {
        let err = |reason: String| NetworkConfigError::Invalid {
            network: self.name(),
            reason,
        };
        if !self.arch.channel_options().contains(&self.in_channels) {
            return Err(err(format!(
                "in_channels must be one of {:?}",
                self.arch.channel_options()
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
}
