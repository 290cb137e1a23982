//! CMX's options (Zhang et al., IEEE T-ITS 2023; the official code's `config.py`): the MiT size
//! of both encoders, the colour order and the decoder's BatchNorm eps. The network is
//! rtf-models' `cmx`.

use serde::{Deserialize, Serialize};

use super::NetworkConfigError;

/// The ImageNet normalisation of the official pipeline, per colour channel.
pub const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
pub const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

/// SegFormer's Mix Transformer sizes.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Size {
    B0,
    B1,
    B2,
    B3,
    B4,
    B5,
}

/// Embed dims and blocks per stage of one MiT encoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    pub dims: [i64; 4],
    pub depths: [i64; 4],
}

impl Size {
    pub const ALL: [Size; 6] = [Size::B0, Size::B1, Size::B2, Size::B3, Size::B4, Size::B5];

    /// `b0` … `b5`.
    pub fn suffix(self) -> &'static str {
        match self {
            Size::B0 => "b0",
            Size::B1 => "b1",
            Size::B2 => "b2",
            Size::B3 => "b3",
            Size::B4 => "b4",
            Size::B5 => "b5",
        }
    }

    pub fn layout(self) -> Layout {
        let wide = [64, 128, 320, 512];
        let (dims, depths) = match self {
            Size::B0 => ([32, 64, 160, 256], [2, 2, 2, 2]),
            Size::B1 => (wide, [2, 2, 2, 2]),
            Size::B2 => (wide, [3, 4, 6, 3]),
            Size::B3 => (wide, [3, 4, 18, 3]),
            Size::B4 => (wide, [3, 8, 27, 3]),
            Size::B5 => (wide, [3, 6, 40, 3]),
        };
        Layout { dims, depths }
    }

    /// `cmx-mit-b2` -> B2.
    pub fn from_name(name: &str) -> Option<Size> {
        let suffix = name.strip_prefix("cmx-mit-")?;
        Size::ALL.into_iter().find(|s| s.suffix() == suffix)
    }
}

/// Order of the colour planes the encoder sees.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum ColorOrder {
    /// B, G, R: what the official code trains and evaluates on (OpenCV's order), so what its
    /// checkpoints expect.
    #[default]
    Bgr,
    /// R, G, B (SegFormer's ImageNet pretraining order).
    Rgb,
}

/// CMX's options; `{"network": "cmx", "size": "b2", "num_classes": 9}` in a model config.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// The MiT size of both encoders.
    pub size: Size,
    /// Width of the classifier (`decode_head.linear_pred`).
    pub num_classes: i64,
    /// Default B, G, R: the official checkpoints' order.
    #[serde(default)]
    pub color_order: ColorOrder,
    /// eps of the decoder's BatchNorm (`decode_head.linear_fuse.1`): PyTorch's 1e-5 by default
    /// (the official evaluation), 1e-3 as the official training sets it. Written only when
    /// not the default.
    #[serde(default = "default_bn_eps", skip_serializing_if = "is_default_bn_eps")]
    pub decoder_bn_eps: f64,
}

fn default_bn_eps() -> f64 {
    super::BN_EPS
}

fn is_default_bn_eps(eps: &f64) -> bool {
    *eps == super::BN_EPS
}

impl Config {
    pub fn new(size: Size, num_classes: i64) -> Self {
        Self {
            size,
            num_classes,
            color_order: ColorOrder::Bgr,
            decoder_bn_eps: default_bn_eps(),
        }
    }

    /// The unit-range input (R, G, B, T) that the network's normalisation maps to 0: the ImageNet
    /// mean of each colour plane's channel (in the encoder's colour order), and for the thermal
    /// plane, which is replicated to three channels normalised with three means, the value
    /// closest to 0 in all three (the mean weighted by 1/std², ≈ 0.449; it normalises to about
    /// −0.16, −0.03, +0.19).
    pub fn normalised_zero(&self) -> [f32; 4] {
        let [m0, m1, m2] = IMAGENET_MEAN;
        // Encoder channel c is normalised with mean c: in B, G, R order the R plane is channel 2.
        let colour = match self.color_order {
            ColorOrder::Bgr => [m2, m1, m0],
            ColorOrder::Rgb => [m0, m1, m2],
        };
        let weights = IMAGENET_STD.map(|s| 1.0 / (s * s));
        let thermal = (0..3).map(|c| IMAGENET_MEAN[c] * weights[c]).sum::<f32>()
            / weights.iter().sum::<f32>();
        [colour[0], colour[1], colour[2], thermal]
    }

    /// `cmx-mit-b0` … `cmx-mit-b5`.
    pub fn name(&self) -> String {
        format!("cmx-mit-{}", self.size.suffix())
    }

    /// Always unit range: the ImageNet normalisation is the network's own first step.
    pub fn input(&self) -> rtf_core::InputConvention {
        rtf_core::InputConvention::UnitRange
    }

    pub fn validate(&self) -> Result<(), NetworkConfigError> {
        if self.num_classes < 1 {
            return Err(NetworkConfigError::Invalid {
                network: self.name(),
                reason: format!("num_classes must be ≥ 1, got {}", self.num_classes),
            });
        }
        if !(self.decoder_bn_eps.is_finite() && self.decoder_bn_eps > 0.0) {
            return Err(NetworkConfigError::Invalid {
                network: self.name(),
                reason: format!("decoder_bn_eps must be > 0, got {}", self.decoder_bn_eps),
            });
        }
        Ok(())
    }
}
