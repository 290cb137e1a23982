//! Which augmentations a training run's loader applies ([`AugmentConfig`]); rtf-data's
//! `augment` applies them.

use serde::{Deserialize, Serialize};

/// Which augmentations the loader applies; everything is off by default.
#[derive(Serialize, Deserialize, Clone, Debug, Default, PartialEq)]
#[serde(default)]
pub struct AugmentConfig {
    /// Horizontal flip of image and label with probability 0.5 (MFNet, RTFNet, HeatNet).
    pub hflip: bool,
    /// RTFNet's random crop: each edge trimmed independently by up to this fraction of the
    /// size (reference 0.1), then resized back (bicubic image, nearest label).
    pub crop: Option<f32>,
    /// HeatNet's random window: a (width, height) region at a uniformly random whole-pixel
    /// position (reference (640, 320) after the 150..850 column crop); the batch is that size
    /// unless a resize is set. An alternative to `crop`.
    pub window: Option<(usize, usize)>,
    /// HeatNet's rotation by U(-deg, +deg) (reference 20°), bilinear image, nearest label;
    /// uncovered pixels are 0 in the image and the ignore id (0 when the set has none) in the label.
    pub rotation_deg: Option<f32>,
    /// HeatNet's modality drop-out: with this probability a random rectangle (up to half of
    /// each side) is zeroed in either RGB or thermal (chosen 50/50).
    pub modality_dropout: Option<f32>,
    /// HeatNet's IR scaling: thermal multiplied by U(lo, hi) (reference (0.1, 1.0)).
    pub ir_scale: Option<(f32, f32)>,
    /// RGB brightness multiplied by U(1 - b, 1 + b).
    pub brightness: Option<f32>,
    /// Gaussian noise of this standard deviation (in [0, 1] units) added to all channels.
    pub noise_std: Option<f32>,
    /// CMX's random scale from a set, then a random crop padded where the scaled frame is
    /// smaller ([`ScaleCrop`]); the batch is the crop's size. An alternative to `crop` and
    /// `window`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale_crop: Option<ScaleCrop>,
}

/// CMX's training geometry (huaaaliu/RGBX_Semantic_Segmentation, `dataloader/dataloader.py`
/// `TrainPre` with `random_scale`, `utils/transforms.py` `generate_random_crop_pos` and
/// `random_crop_pad_to_shape`): the frame scaled by a factor drawn uniformly from `scales`
/// (image bilinear without antialiasing, OpenCV's `INTER_LINEAR`; label `INTER_NEAREST`), then
/// a crop of `size` at a random position, padded around (centred) where the scaled frame is
/// smaller: image planes with `fill`, label with the ignore id. The geometry is in
/// rtf-data's `scale_crop`.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ScaleCrop {
    /// The scale factors, one drawn per frame (official `train_scale_array`: 0.5, 0.75, 1,
    /// 1.25, 1.5, 1.75).
    pub scales: Vec<f32>,
    /// (width, height) of the crop; None = the frame's size before scaling (the resize if
    /// one is set, else the frame's own; the official 640×480 is MF's frame size).
    #[serde(default)]
    pub size: Option<(usize, usize)>,
    /// Value of padded image pixels per plane R, G, B, T in [0, 1]: the official pads the
    /// normalised image with 0, which is the network's normalisation mean here (see
    /// `rtf_models::ModelConfig::normalised_zero`).
    pub fill: [f32; 4],
}

impl ScaleCrop {
    /// CMX's scale set with the crop at the frame's size, padding with `fill`.
    pub fn cmx(fill: [f32; 4]) -> Self {
        Self {
            scales: vec![0.5, 0.75, 1.0, 1.25, 1.5, 1.75],
            size: None,
            fill,
        }
    }

    /// (width, height) of the crop for a frame whose size before scaling is `base`.
    pub fn crop_size(&self, base: (usize, usize)) -> (usize, usize) {
        self.size.unwrap_or(base)
    }
}
