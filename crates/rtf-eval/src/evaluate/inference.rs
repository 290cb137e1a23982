//! How an evaluation runs the network on a frame: the whole image once (the default), or as
//! the field reports it, by sliding windows and over several scales and a horizontal flip.
//!
//! The modes follow the official CMX evaluator (`huaaaliu/RGBX_Semantic_Segmentation`,
//! `engine/evaluator.py`: `sliding_eval_rgbX`, `scale_process_rgbX`, `val_func_process_rgbX`,
//! `process_image_rgbX`; settings in `config.py`: `eval_crop_size = [480, 640]` (height,
//! width), `eval_stride_rate = 2/3`, `eval_scale_array = [1]` or `[0.75, 1, 1.25]`,
//! `eval_flip = False` or `True`):
//!
//! * **Score of one pass** ([`pass_scores`]): the network's logits, plus, with flip, the logits
//!   of the horizontally flipped input flipped back (summed as logits), then `exp` of the sum
//!   (not a softmax). Computed here in f64, where the official code's f32 would overflow
//!   above a summed logit of 88.
//! * **Scales**: the input is resized by each factor (bilinear, half-pixel centres, the size
//!   rounded as OpenCV's `cv2.resize(fx=s)` rounds it), scored, and the score map resized back
//!   to the frame's size (bilinear); the maps of all scales are summed, then the argmax taken.
//!   (The official code resizes the 8-bit image before normalising it; here the network's
//!   input, already normalised, is resized: the same up to the 8-bit rounding.)
//! * **Sliding window** ([`Inference::Sliding`]) at each scale: an image not larger than the
//!   crop in both sides (`rows <= crop_h or cols <= crop_w`) runs once, padded to at least the
//!   crop, centred ([`pad_margins`]: the odd pixel after), with the value 0 in the network's
//!   input scale (the official code pads the normalised image with 0), and the score cropped
//!   back. A larger image runs window by window: stride `ceil(crop · stride_rate)` per axis,
//!   `ceil((size − crop) / stride) + 1` windows per axis, the last moved back to end at the
//!   border ([`window_starts`]); window scores are summed into the frame's map.
//!
//! Two differences from the official code, both deliberate:
//! * its window loop pairs the x axis with the crop's *height* and stride (`s_x = grid_xidx *
//!   stride[0]`, `e_x = min(s_x + crop_size[0], pad_cols)`): with the 480×640 crop windows are
//!   640 rows high and 480 columns wide, which on a 600×800 image (MF at scale 1.25) starts
//!   them at row −40 and scores only the last 40 rows. Here each axis uses its own crop side
//!   and stride.
//! * `scale_process_rgbX` sums overlapping windows without dividing by their count (the RGB
//!   `scale_process` keeps a count, its division commented out). Here the sum is divided by
//!   the count, so that a pixel's score is the mean of its windows' and scales weigh alike. At
//!   one scale the argmax, hence every metric, is the same either way.
//!
//! Every network runs at any size: an input (scaled image, padded image or window) that is not
//! a multiple of [`rtf_models::Network::size_multiple`] is padded at the bottom and right by
//! replicating the border, and the logits are cropped back ([`crate::evaluate::logits`]).
//! Windows run one at a time (each over the whole batch).

use rtf_models::Network;
use serde::{Deserialize, Serialize};
use tch::{Kind, Tensor};

use super::{logits, predict_ids, EvalError};

/// The official CMX evaluator's crop, (height, width) (`config.py`: `eval_crop_size`).
pub const CMX_CROP: (usize, usize) = (480, 640);
/// The official CMX evaluator's stride rate (`config.py`: `eval_stride_rate`).
pub const CMX_STRIDE_RATE: f64 = 2.0 / 3.0;

/// How one scale of a frame is run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case")]
pub enum Inference {
    /// The whole (scaled) image in one pass.
    Whole,
    /// Windows of `crop` = (height, width) at stride `ceil(crop · stride_rate)` (module docs).
    Sliding {
        crop: (usize, usize),
        stride_rate: f64,
    },
}

impl Inference {
    /// Sliding windows with the official CMX settings (480×640, 2/3).
    pub fn cmx_sliding() -> Self {
        Self::Sliding {
            crop: CMX_CROP,
            stride_rate: CMX_STRIDE_RATE,
        }
    }
}

/// Mode, scales and flip of an evaluation (default: whole image, scale 1, no flip).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InferenceOptions {
    #[serde(flatten)]
    pub mode: Inference,
    /// Factors the input is resized by; the score maps of all are summed.
    pub scales: Vec<f64>,
    /// Also score the horizontally flipped input (its logits flipped back and added).
    pub flip: bool,
}

impl Default for InferenceOptions {
    fn default() -> Self {
        Self {
            mode: Inference::Whole,
            scales: vec![1.0],
            flip: false,
        }
    }
}

impl InferenceOptions {
    /// Whole image, scale 1, no flip: the argmax of the logits, as before the modes existed.
    pub fn is_plain(&self) -> bool {
        self.mode == Inference::Whole && self.scales == [1.0] && !self.flip
    }

    /// Refuses options that cannot run: no scale, a scale not positive and finite, an empty
    /// crop, a stride rate outside (0, 1] (above 1 the windows would leave gaps).
    pub fn validate(&self) -> Result<(), EvalError> {
        let bad = |m: String| Err(EvalError::Inference(m));
        if self.scales.is_empty() {
            return bad("no scale given".into());
        }
        if let Some(s) = self.scales.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
            return bad(format!("scale {s} is not a positive number"));
        }
        if let Inference::Sliding { crop, stride_rate } = self.mode {
            if crop.0 == 0 || crop.1 == 0 {
                return bad(format!("crop {}x{} is empty", crop.0, crop.1));
            }
            if !(stride_rate > 0.0 && stride_rate <= 1.0) {
                return bad(format!("stride rate {stride_rate} is not in (0, 1]"));
            }
        }
        Ok(())
    }

    /// One line for a report: "sliding 480x640 (HxW), stride rate 0.667, scales 0.75,1,1.25,
    /// flip" or "whole image, scale 1".
    pub fn describe(&self) -> String {
        let scales: Vec<String> = self.scales.iter().map(|s| s.to_string()).collect();
        let mode = match self.mode {
            Inference::Whole => "whole image".to_string(),
            Inference::Sliding { crop, stride_rate } => format!(
                "sliding {}x{} (HxW), stride rate {stride_rate:.3}",
                crop.0, crop.1
            ),
        };
        let plural = if scales.len() > 1 { "scales" } else { "scale" };
        let flip = if self.flip { ", flip" } else { "" };
        format!("{mode}, {plural} {}{flip}", scales.join(","))
    }

    /// The largest (height, width) one forward pass sees on a `height`×`width` frame (for the
    /// memory check before a run).
    pub fn largest_pass(&self, height: usize, width: usize) -> (usize, usize) {
        let top = self.scales.iter().copied().fold(0.0f64, f64::max);
        let (h, w) = scaled_size(height as i64, width as i64, top);
        let (h, w) = (h as usize, w as usize);
        match self.mode {
            Inference::Whole => (h, w),
            Inference::Sliding { crop, .. } if h > crop.0 && w > crop.1 => crop,
            Inference::Sliding { crop, .. } => (h.max(crop.0), w.max(crop.1)),
        }
    }
}

/// Class ids [B, H, W] of `input` [B, C, H, W] (the network's input scale) by `options`: the
/// plain path ([`predict_ids`]) when they are plain, else the argmax of [`scores`].
pub fn predict(
    network: &dyn Network,
    input: &Tensor,
    options: &InferenceOptions,
) -> Result<Tensor, EvalError> {
    if options.is_plain() {
        return predict_ids(network, input);
    }
    Ok(scores(network, input, options)?.f_argmax(1, false)?)
}

/// Score map [B, classes, H, W] (f64) of `input` [B, C, H, W]: the sum over `options.scales`
/// of each scale's map resized back to H×W (module docs).
pub fn scores(
    network: &dyn Network,
    input: &Tensor,
    options: &InferenceOptions,
) -> Result<Tensor, EvalError> {
    options.validate()?;
    let (h, w) = height_width(input)?;
    let mut total: Option<Tensor> = None;
    for &s in &options.scales {
        let (sh, sw) = scaled_size(h, w, s);
        let scaled = if (sh, sw) == (h, w) {
            input.shallow_clone()
        } else {
            input
                .f_to_kind(Kind::Float)?
                .f_upsample_bilinear2d([sh, sw], false, s, s)?
        };
        let map = match options.mode {
            Inference::Whole => pass_scores(network, &scaled, options.flip)?,
            Inference::Sliding { crop, stride_rate } => {
                sliding_scores(network, &scaled, crop, stride_rate, options.flip)?
            }
        };
        let map = if (sh, sw) == (h, w) {
            map
        } else {
            map.f_upsample_bilinear2d([h, w], false, None, None)?
        };
        total = Some(match total {
            None => map,
            Some(t) => t.f_add(&map)?,
        });
    }
    total.ok_or_else(|| EvalError::Inference("no scale given".into()))
}

/// Size of a `h`×`w` image resized by `s`, rounded as OpenCV rounds `cv2.resize(fx=s, fy=s)`
/// (to nearest, ties to even), at least 1.
pub fn scaled_size(h: i64, w: i64, s: f64) -> (i64, i64) {
    let side = |v: i64| ((v as f64 * s).round_ties_even() as i64).max(1);
    (side(h), side(w))
}

fn height_width(input: &Tensor) -> Result<(i64, i64), EvalError> {
    match input.size().as_slice() {
        [_, _, h, w] => Ok((*h, *w)),
        other => Err(EvalError::Shape(format!(
            "expected input [B, C, H, W], got {other:?}"
        ))),
    }
}

/// One pass's scores (f64): `exp(logits)`, with flip `exp(logits + flip(logits(flip(x))))`
/// (`val_func_process_rgbX`).
pub fn pass_scores(network: &dyn Network, input: &Tensor, flip: bool) -> Result<Tensor, EvalError> {
    let mut sum = logits(network, input)?.f_to_kind(Kind::Double)?;
    if flip {
        let mirrored = logits(network, &input.f_flip([3])?)?.f_flip([3])?;
        sum = sum.f_add(&mirrored.f_to_kind(Kind::Double)?)?;
    }
    Ok(sum.f_exp()?)
}

/// Padding (before, after) that brings `size` to at least `crop`, centred with the odd pixel
/// after (`utils/transforms.py`, `pad_image_to_shape`); (0, 0) when `size >= crop`.
pub fn pad_margins(size: usize, crop: usize) -> (usize, usize) {
    let pad = crop.saturating_sub(size);
    (pad / 2, pad - pad / 2)
}

/// Window stride of a crop side: `ceil(crop · rate)`, at least 1 (`scale_process_rgbX`).
pub fn window_stride(crop: usize, rate: f64) -> usize {
    ((crop as f64 * rate).ceil() as usize).max(1)
}

/// Starts of the windows along a side of `size` > `crop` pixels: `ceil((size − crop) /
/// stride) + 1` windows at `i · stride`, each moved back to end by the border
/// (`scale_process_rgbX`); `[0]` when `size <= crop`.
pub fn window_starts(size: usize, crop: usize, stride: usize) -> Vec<usize> {
    if size <= crop {
        return vec![0];
    }
    let n = (size - crop).div_ceil(stride) + 1;
    (0..n)
        .map(|i| (i * stride + crop).min(size) - crop)
        .collect()
}

/// One scale's scores by sliding windows of `crop` (height, width) over `input`.
fn sliding_scores(
    network: &dyn Network,
    input: &Tensor,
    crop: (usize, usize),
    rate: f64,
    flip: bool,
) -> Result<Tensor, EvalError> {
    let (h, w) = height_width(input)?;
    let (rows, cols) = (h as usize, w as usize);
    if rows <= crop.0 || cols <= crop.1 {
        return padded_scores(network, input, crop, flip);
    }
    let starts_y = window_starts(rows, crop.0, window_stride(crop.0, rate));
    let starts_x = window_starts(cols, crop.1, window_stride(crop.1, rate));
    let (ch, cw) = (crop.0 as i64, crop.1 as i64);
    let batch = input.size()[0];
    let options = (Kind::Double, input.device());
    let sum = Tensor::f_zeros([batch, network.num_classes(), h, w], options)?;
    let count = Tensor::f_zeros([1, 1, h, w], options)?;
    for &y in &starts_y {
        for &x in &starts_x {
            let (y, x) = (y as i64, x as i64);
            let window = input.f_narrow(2, y, ch)?.f_narrow(3, x, cw)?;
            let score = pass_scores(network, &window, flip)?;
            let _ = sum.f_narrow(2, y, ch)?.f_narrow(3, x, cw)?.f_add_(&score)?;
            let _ = count
                .f_narrow(2, y, ch)?
                .f_narrow(3, x, cw)?
                .f_add_scalar_(1.0)?;
        }
    }
    Ok(sum.f_div(&count)?)
}

/// The single pass of an image not larger than the crop in both sides: padded (centred, 0)
/// to at least the crop, scored, cropped back.
fn padded_scores(
    network: &dyn Network,
    input: &Tensor,
    crop: (usize, usize),
    flip: bool,
) -> Result<Tensor, EvalError> {
    let (h, w) = height_width(input)?;
    let (top, bottom) = pad_margins(h as usize, crop.0);
    let (left, right) = pad_margins(w as usize, crop.1);
    if top + bottom + left + right == 0 {
        return pass_scores(network, input, flip);
    }
    let pads = [left, right, top, bottom].map(|p| p as i64);
    let padded = input.f_pad(pads, "constant", 0.0)?;
    let score = pass_scores(network, &padded, flip)?;
    Ok(score
        .f_narrow(2, top as i64, h)?
        .f_narrow(3, left as i64, w)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::nn::ModuleT;
    use tch::Device;

    /// Logits = a fixed 1×1 convolution of the input: a pixel's output depends on that pixel
    /// only (hence the same in any window and under a flip). Refuses (panics on) inputs whose
    /// sides are not multiples of `multiple`, as the real networks' shapes would.
    #[derive(Debug)]
    struct PixelWise {
        weight: Tensor,
        bias: Tensor,
        multiple: i64,
    }

    impl PixelWise {
        fn new(classes: i64, multiple: i64) -> Self {
            let _rng = crate::seeded_rng_lock();
            tch::manual_seed(7);
            let weight = Tensor::randn([classes, 4, 1, 1], (Kind::Float, Device::Cpu));
            let bias = Tensor::randn([classes], (Kind::Float, Device::Cpu));
            Self {
                weight,
                bias,
                multiple,
            }
        }
    }

    impl ModuleT for PixelWise {
        fn forward_t(&self, xs: &Tensor, _train: bool) -> Tensor {
            let size = xs.size();
            assert!(
                size[2] % self.multiple == 0 && size[3] % self.multiple == 0,
                "{size:?} not a multiple of {}",
                self.multiple
            );
            xs.conv2d(&self.weight, Some(&self.bias), [1, 1], [0, 0], [1, 1], 1)
        }
    }

    impl Network for PixelWise {
        fn input_convention(&self) -> rtf_core::InputConvention {
            rtf_core::InputConvention::UnitRange
        }
        fn num_classes(&self) -> i64 {
            3
        }
        fn size_multiple(&self) -> i64 {
            self.multiple
        }
        fn name(&self) -> String {
            "pixel-wise".into()
        }
    }

    fn input(h: i64, w: i64) -> Tensor {
        let _rng = crate::seeded_rng_lock();
        tch::manual_seed(11);
        Tensor::rand([2, 4, h, w], (Kind::Float, Device::Cpu))
    }

    fn sliding(crop: (usize, usize), scales: &[f64], flip: bool) -> InferenceOptions {
        InferenceOptions {
            mode: Inference::Sliding {
                crop,
                stride_rate: CMX_STRIDE_RATE,
            },
            scales: scales.to_vec(),
            flip,
        }
    }

    fn whole(scales: &[f64], flip: bool) -> InferenceOptions {
        InferenceOptions {
            mode: Inference::Whole,
            scales: scales.to_vec(),
            flip,
        }
    }

    fn max_relative_difference(a: &Tensor, b: &Tensor) -> f64 {
        ((a - b).abs() / b.abs().clamp_min(1e-30))
            .max()
            .double_value(&[])
    }

    #[test]
    fn one_window_covering_the_image_is_the_whole_image_exactly() {
        let _rng = crate::seeded_rng_lock();
        tch::manual_seed(0);
        let vs = tch::nn::VarStore::new(Device::Cpu);
        let config = rtf_models::ModelConfig::from_name("mfnet", 9).unwrap();
        let net = rtf_models::build(&vs.root(), &config).unwrap();
        drop(_rng);
        let x = input(48, 64);
        for flip in [false, true] {
            let reference = scores(net.as_ref(), &x, &whole(&[1.0], flip)).unwrap();
            let windowed = scores(net.as_ref(), &x, &sliding((48, 64), &[1.0], flip)).unwrap();
            assert!(windowed.equal(&reference), "flip {flip}");
        }
        // And the argmax of the plain path (logits) is the argmax of these scores.
        let plain = predict(net.as_ref(), &x, &InferenceOptions::default()).unwrap();
        let one_window = predict(net.as_ref(), &x, &sliding((48, 64), &[1.0], false)).unwrap();
        assert!(plain.equal(&one_window));
    }

    #[test]
    fn overlapping_windows_of_a_pixel_wise_network_give_the_whole_image() {
        // Multiple 8: the 45×61 image and the 20×28 windows run padded to multiples of 8.
        let net = PixelWise::new(3, 8);
        let x = input(45, 61);
        let reference = scores(&net, &x, &whole(&[1.0], false)).unwrap();
        for crop in [(20, 28), (16, 16), (45, 30), (32, 61)] {
            let windowed = scores(&net, &x, &sliding(crop, &[1.0], false)).unwrap();
            let d = max_relative_difference(&windowed, &reference);
            assert!(d < 1e-6, "crop {crop:?}: {d}");
        }
        // A flip-equivariant network: the flipped pass adds the same logits again.
        let flipped = scores(&net, &x, &sliding((20, 28), &[1.0], true)).unwrap();
        let doubled = (logits(&net, &x).unwrap().to_kind(Kind::Double) * 2.0).exp();
        assert!(max_relative_difference(&flipped, &doubled) < 1e-6);
        let ids = predict(&net, &x, &sliding((20, 28), &[1.0], true)).unwrap();
        assert!(ids.equal(&predict_ids(&net, &x).unwrap()));
    }

    #[test]
    fn the_single_scale_one_is_single_scale_and_scales_sum() {
        let net = PixelWise::new(3, 8);
        let x = input(40, 56);
        for options in [whole(&[1.0], true), sliding((24, 24), &[1.0], false)] {
            let one = scores(&net, &x, &options).unwrap();
            let twice = scores(
                &net,
                &x,
                &InferenceOptions {
                    scales: vec![1.0, 1.0],
                    ..options.clone()
                },
            )
            .unwrap();
            assert!(max_relative_difference(&twice, &(&one * 2.0)) < 1e-12);
        }
        // Several scales: the map is at the frame's size, and a scale that is not a multiple of
        // the network's (0.75 of 40×56 is 30×42) runs padded.
        let multi = scores(&net, &x, &sliding((24, 24), &[0.75, 1.0, 1.25], true)).unwrap();
        assert_eq!(multi.size(), [2, 3, 40, 56]);
        assert_eq!(multi.isfinite().all().int64_value(&[]), 1);
    }

    #[test]
    fn windows_are_placed_as_the_official_evaluator_places_them() {
        // engine/evaluator.py, scale_process_rgbX: stride = ceil(crop * stride_rate);
        // grid = ceil((size - crop) / stride) + 1; start = min(i * stride + crop, size) - crop.
        // Rows: 77 rows, crop 32: stride ceil(21.33) = 22, grid ceil(45 / 22) + 1 = 4,
        // starts 0, 22, 44, min(66 + 32, 77) - 32 = 45.
        assert_eq!(window_stride(32, CMX_STRIDE_RATE), 22);
        assert_eq!(window_starts(77, 32, 22), [0, 22, 44, 45]);
        // Columns: 101 columns, crop 48: stride ceil(32.0) = 32, grid ceil(53 / 32) + 1 = 3,
        // starts 0, 32, min(64 + 48, 101) - 48 = 53.
        assert_eq!(window_stride(48, CMX_STRIDE_RATE), 32);
        assert_eq!(window_starts(101, 48, 32), [0, 32, 53]);
        // The official 480×640 crop: strides 320 and 427; MF at scale 1.25 (600×800).
        assert_eq!(window_stride(480, CMX_STRIDE_RATE), 320);
        assert_eq!(window_stride(640, CMX_STRIDE_RATE), 427);
        assert_eq!(window_starts(600, 480, 320), [0, 120]);
        assert_eq!(window_starts(800, 640, 427), [0, 160]);
        // pad_image_to_shape: the odd pixel after.
        assert_eq!(pad_margins(21, 32), (5, 6));
        assert_eq!(pad_margins(20, 32), (6, 6));
        assert_eq!(pad_margins(40, 32), (0, 0));
        // Counts per row of the 77-row case, by hand: windows [0,32) [22,54) [44,76) [45,77).
        let rows: Vec<usize> = (0..77)
            .map(|r| {
                [0, 22, 44, 45]
                    .iter()
                    .filter(|&&s| s <= r && r < s + 32)
                    .count()
            })
            .collect();
        let expected: Vec<usize> = (0..77)
            .map(|r| match r {
                0..=21 => 1,
                22..=31 => 2,
                32..=43 => 1,
                44 => 2,
                45..=53 => 3,
                54..=75 => 2,
                _ => 1,
            })
            .collect();
        assert_eq!(rows, expected);
    }

    #[test]
    fn window_counts_divide_the_sum() {
        // A network whose logits are 0 everywhere: every pass scores exp(0) = 1, so the mean
        // over windows is 1 at every pixel whatever the count (a sum would show the counts).
        let mut net = PixelWise::new(3, 1);
        net.weight = net.weight.zeros_like();
        net.bias = net.bias.zeros_like();
        let x = input(77, 101);
        let map = scores(&net, &x, &sliding((32, 48), &[1.0], false)).unwrap();
        assert!(map.equal(&map.ones_like()));
    }

    #[test]
    fn sizes_options_and_their_description() {
        assert_eq!(scaled_size(480, 640, 0.75), (360, 480));
        assert_eq!(scaled_size(480, 640, 1.25), (600, 800));
        assert_eq!(scaled_size(5, 3, 0.5), (2, 2)); // 2.5 → 2, 1.5 → 2: ties to even
        let cmx = InferenceOptions {
            mode: Inference::cmx_sliding(),
            scales: vec![0.75, 1.0, 1.25],
            flip: true,
        };
        assert_eq!(
            cmx.describe(),
            "sliding 480x640 (HxW), stride rate 0.667, scales 0.75,1,1.25, flip"
        );
        assert_eq!(
            InferenceOptions::default().describe(),
            "whole image, scale 1"
        );
        assert_eq!(cmx.largest_pass(480, 640), (480, 640));
        assert_eq!(whole(&[0.5, 2.0], false).largest_pass(48, 64), (96, 128));
        assert_eq!(
            sliding((32, 32), &[1.0], false).largest_pass(20, 64),
            (32, 64)
        );
        let json = serde_json::to_value(&cmx).unwrap();
        assert_eq!(json["mode"], "sliding");
        assert_eq!(json["crop"], serde_json::json!([480, 640]));
        assert_eq!(json["flip"], true);
        let back: InferenceOptions = serde_json::from_value(json).unwrap();
        assert_eq!(back, cmx);
        for bad in [
            whole(&[], false),
            whole(&[0.0], false),
            sliding((0, 32), &[1.0], false),
            InferenceOptions {
                mode: Inference::Sliding {
                    crop: (32, 32),
                    stride_rate: 1.5,
                },
                ..Default::default()
            },
        ] {
            assert!(
                matches!(bad.validate(), Err(EvalError::Inference(_))),
                "{bad:?}"
            );
        }
    }
}
