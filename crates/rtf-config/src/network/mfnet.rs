//! MFNet's options (Ha et al., IROS 2017; spec §3): the published network and the paper's
//! Tab. III variants. The network is rtf-models' `mfnet`.

use serde::{Deserialize, Serialize};

use super::NetworkConfigError;

/// Activation of every block.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum Activation {
    #[default]
    LeakyRelu,
    Relu,
}

/// What fills the conv4/conv5 stages (three blocks each).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum Inception {
    /// 3×3 ‖ 3×3 dilation 2, concatenated (the published network).
    #[default]
    Mini,
    /// One plain 3×3 convolution per block (Tab. III, noInc1).
    Conv3x3,
    /// One 3×3 dilation-2 convolution per block (noInc2).
    Dilated3x3,
}

/// A 1×1 convolution squeezing the channels before each mini-inception block (Tab. III sq*).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Squeeze {
    Quarter,
    Half,
    Same,
}

impl Squeeze {
    /// The squeezed width of a block of `c_in` channels.
    pub fn width(self, c_in: i64) -> i64 {
        match self {
            Squeeze::Quarter => (c_in / 4).max(1),
            Squeeze::Half => (c_in / 2).max(1),
            Squeeze::Same => c_in,
        }
    }
}

/// How the decoder upsamples.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum Upsampling {
    /// Nearest-neighbour ×2 (published).
    #[default]
    Nearest,
    /// Max-unpooling with the encoders' pooling indices (Tab. III idUp).
    Indices,
}

/// MFNet's options. Defaults are the published weights' (thermal conv4/conv5 = 36; the paper's
/// table says 32, see [`Config::paper`]).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub num_classes: i64,
    /// Output widths of conv1, conv2_x, conv3_x, conv4, conv5 of the RGB encoder.
    #[serde(default = "default_rgb_channels")]
    pub rgb_channels: [i64; 5],
    /// Output widths of conv1, conv2_x, conv3_x, conv4, conv5 of the thermal encoder; all
    /// zero = no thermal encoder (RGB-only, Tab. III B).
    #[serde(default = "default_thermal_channels")]
    pub thermal_channels: [i64; 5],
    /// Output width of decode2 (decode4/decode3 widths follow from the skips).
    #[serde(default = "default_decode2_channels")]
    pub decode2_channels: i64,
    #[serde(default)]
    pub activation: Activation,
    #[serde(default)]
    pub inception: Inception,
    #[serde(default)]
    pub squeeze: Option<Squeeze>,
    /// The decoder's shortcut blocks (adding the encoder skips).
    #[serde(default = "yes")]
    pub shortcuts: bool,
    #[serde(default)]
    pub upsampling: Upsampling,
    #[serde(default)]
    pub input: rtf_core::InputConvention,
}

fn default_rgb_channels() -> [i64; 5] {
    [16, 48, 48, 96, 96]
}
fn default_thermal_channels() -> [i64; 5] {
    [16, 16, 16, 36, 36]
}
fn default_decode2_channels() -> i64 {
    32
}
fn yes() -> bool {
    true
}

/// MFNet paper Tab. III letters with the configuration each names (descriptions of Sec. V;
/// see docs/src/models.md for where the paper's text letters differ from its table).
pub const VARIANT_LETTERS: [char; 13] = [
    'b', 'c', 'd', 'e', 'f', 'g', 'h', 'i', 'j', 'k', 'l', 'm', 'n',
];

impl Config {
    /// The published code and weights (736,275 parameters for 9 classes).
    pub fn reference(num_classes: i64) -> Self {
        Self {
            num_classes,
            rgb_channels: default_rgb_channels(),
            thermal_channels: default_thermal_channels(),
            decode2_channels: default_decode2_channels(),
            activation: Activation::LeakyRelu,
            inception: Inception::Mini,
            squeeze: None,
            shortcuts: true,
            upsampling: Upsampling::Nearest,
            input: rtf_core::InputConvention::UnitRange,
        }
    }

    /// The paper's Tab. I widths (thermal conv4/conv5 = 32).
    pub fn paper(num_classes: i64) -> Self {
        Self {
            thermal_channels: [16, 16, 16, 32, 32],
            ..Self::reference(num_classes)
        }
    }

    /// Every width doubled (Tab. III "2x").
    fn doubled(self) -> Self {
        Self {
            rgb_channels: self.rgb_channels.map(|c| 2 * c),
            thermal_channels: self.thermal_channels.map(|c| 2 * c),
            decode2_channels: 2 * self.decode2_channels,
            ..self
        }
    }

    /// MFNet paper Tab. III model `letter` (b–n), built on the published widths.
    pub fn variant(letter: char, num_classes: i64) -> Option<Self> {
        let base = Self::reference(num_classes);
        Some(match letter {
            // MFNet_RGB: no IR encoder, no fusion; the RGB skips are kept.
            'b' => Self {
                thermal_channels: [0; 5],
                ..base
            },
            // MFNet_noInc1 / noInc2: mini-inception replaced by 3×3 / 3×3 dilation-2 convs.
            'c' => Self {
                inception: Inception::Conv3x3,
                ..base
            },
            'd' => Self {
                inception: Inception::Dilated3x3,
                ..base
            },
            // MFNet_2x, MFNet_relu, MFNet_relu_2x.
            'e' => base.doubled(),
            'f' => Self {
                activation: Activation::Relu,
                ..base
            },
            'g' => Self {
                activation: Activation::Relu,
                ..base
            }
            .doubled(),
            // MFNet_idUp(_2x): no shortcuts, max-unpooling with the pooling indices.
            'h' => Self {
                shortcuts: false,
                upsampling: Upsampling::Indices,
                ..base
            },
            'i' => Self {
                shortcuts: false,
                upsampling: Upsampling::Indices,
                ..base
            }
            .doubled(),
            // MFNet_noSc: no shortcut blocks.
            'j' => Self {
                shortcuts: false,
                ..base
            },
            // MFNet_sqQuart, sqHalf, sqHalf_noSc, sqSame: 1×1 squeeze before each block.
            'k' => Self {
                squeeze: Some(Squeeze::Quarter),
                ..base
            },
            'l' => Self {
                squeeze: Some(Squeeze::Half),
                ..base
            },
            'm' => Self {
                squeeze: Some(Squeeze::Half),
                shortcuts: false,
                ..base
            },
            'n' => Self {
                squeeze: Some(Squeeze::Same),
                ..base
            },
            _ => return None,
        })
    }

    /// `mfnet`, `mfnet-paper`, `mfnet-b` … `mfnet-n`, or `mfnet-custom`.
    pub fn name(&self) -> String {
        if *self == Self::reference(self.num_classes) {
            return "mfnet".into();
        }
        if *self == Self::paper(self.num_classes) {
            return "mfnet-paper".into();
        }
        VARIANT_LETTERS
            .iter()
            .find(|&&l| Self::variant(l, self.num_classes).as_ref() == Some(self))
            .map_or_else(|| "mfnet-custom".into(), |l| format!("mfnet-{l}"))
    }

    /// Whether the network has a thermal encoder (Tab. III B has none).
    pub fn has_thermal(&self) -> bool {
        self.thermal_channels.iter().any(|&c| c > 0)
    }

    /// Checks that the skips' widths line up with the decoder (they are added, not concatenated).
    pub fn validate(&self) -> Result<(), NetworkConfigError> {
        let err = |reason: String| NetworkConfigError::Invalid {
            network: "mfnet".into(),
            reason,
        };
        let (r, t) = (self.rgb_channels, self.thermal_channels);
        if self.num_classes < 1 {
            return Err(err(format!(
                "num_classes must be ≥ 1, got {}",
                self.num_classes
            )));
        }
        let thermal_ok = t.iter().all(|&c| c >= 1) || t.iter().all(|&c| c == 0);
        if r.iter().chain([&self.decode2_channels]).any(|&c| c < 1) || !thermal_ok {
            return Err(err(
                "channel widths must be ≥ 1 (thermal: all ≥ 1, or all 0 for none)".into(),
            ));
        }
        if self.inception == Inception::Mini && [r[3], r[4], t[3], t[4]].iter().any(|c| c % 2 != 0)
        {
            return Err(err(
                "mini-inception widths (conv4, conv5) must be even".into()
            ));
        }
        if (self.shortcuts || self.upsampling == Upsampling::Indices) && r[3] + t[3] != r[4] + t[4]
        {
            return Err(err(format!(
                "conv4 skip width {} must equal the fused conv5 width {}",
                r[3] + t[3],
                r[4] + t[4]
            )));
        }
        if self.upsampling == Upsampling::Indices && r[0] + t[0] != self.decode2_channels {
            return Err(err(format!(
                "unpooling with conv1's indices needs decode2 width {} = conv1 widths {}",
                self.decode2_channels,
                r[0] + t[0]
            )));
        }
        Ok(())
    }
}
