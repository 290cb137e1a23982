//! Geometric and photometric augmentation on planar f32 images ([C, H, W], values in [0, 1])
//! and u8 label maps. Every random choice is drawn from a caller-supplied RNG, so a frame's
//! augmentation depends only on the seed the loader derives for it.

use rand::Rng;
use serde::{Deserialize, Serialize};

/// Which augmentations the loader applies: the schema's (rtf-config).
pub use rtf_config::data::{AugmentConfig, ScaleCrop};

/// A planar image: `channels` planes of `height * width` values.
#[derive(Debug, Clone, PartialEq)]
pub struct Planar {
    pub channels: usize,
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Planar {
    pub fn plane(&self, c: usize) -> &[f32] {
        let n = self.width * self.height;
        &self.data[c * n..(c + 1) * n]
    }
    pub fn plane_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.width * self.height;
        &mut self.data[c * n..(c + 1) * n]
    }
}

/// Borrowed planar data with the same accessors as [`Planar`].
struct PlanarMut<'a> {
    channels: usize,
    width: usize,
    height: usize,
    data: &'a mut [f32],
}

impl PlanarMut<'_> {
    fn plane_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.width * self.height;
        &mut self.data[c * n..(c + 1) * n]
    }
}

/// A crop window in source pixel-edge coordinates (x0, y0) .. (x1, y1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    pub x0: f32,
    pub y0: f32,
    pub x1: f32,
    pub y1: f32,
}

impl Window {
    pub fn full(width: usize, height: usize) -> Self {
        Self {
            x0: 0.0,
            y0: 0.0,
            x1: width as f32,
            y1: height as f32,
        }
    }

    /// RTFNet's crop: left/top start in [0, f·size), right/bottom end in [(1-f)·size, size],
    /// whole pixels as in the reference (integer slicing).
    pub fn random_crop(width: usize, height: usize, fraction: f32, rng: &mut impl Rng) -> Self {
        let f = fraction.clamp(0.0, 0.49);
        let pick_start = |size: usize, rng: &mut dyn rand::RngCore| {
            let max = (f * size as f32) as usize;
            if max == 0 {
                0
            } else {
                rng.random_range(0..max)
            }
        };
        let pick_end = |size: usize, rng: &mut dyn rand::RngCore| {
            let min = ((1.0 - f) * size as f32).ceil() as usize;
            rng.random_range(min.min(size)..=size)
        };
        let x0 = pick_start(width, rng);
        let x1 = pick_end(width, rng);
        let y0 = pick_start(height, rng);
        let y1 = pick_end(height, rng);
        Self {
            x0: x0 as f32,
            y0: y0 as f32,
            x1: x1 as f32,
            y1: y1 as f32,
        }
    }

    fn is_full(&self, width: usize, height: usize) -> bool {
        *self == Self::full(width, height)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Filter {
    /// Triangle filter, widened when shrinking (antialiased, like PIL's BILINEAR).
    Bilinear,
    /// Keys cubic a = -0.5, widened when shrinking (like PIL's BICUBIC).
    Bicubic,
    /// Triangle filter never widened: plain bilinear interpolation between the two nearest
    /// pixel centres, no antialiasing when shrinking (OpenCV's `INTER_LINEAR`).
    Linear,
}

impl Filter {
    fn support(self) -> f32 {
        match self {
            Self::Bilinear | Self::Linear => 1.0,
            Self::Bicubic => 2.0,
        }
    }
    fn weight(self, x: f32) -> f32 {
        let x = x.abs();
        match self {
            Self::Bilinear | Self::Linear => (1.0 - x).max(0.0),
            Self::Bicubic => {
                const A: f32 = -0.5;
                if x < 1.0 {
                    ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0
                } else if x < 2.0 {
                    (((x - 5.0) * x + 8.0) * x - 4.0) * A
                } else {
                    0.0
                }
            }
        }
    }
}

/// Per output coordinate: first source index and normalised weights.
struct Taps {
    start: Vec<usize>,
    len: usize,
    weights: Vec<f32>,
}

fn taps(src: usize, lo: f32, hi: f32, out: usize, filter: Filter) -> Taps {
    let scale = (hi - lo) / out as f32;
    let fscale = match filter {
        Filter::Linear => 1.0,
        _ => scale.max(1.0),
    };
    let support = filter.support() * fscale;
    let len = (2.0 * support).ceil() as usize + 1;
    let mut start = Vec::with_capacity(out);
    let mut weights = vec![0.0; out * len];
    for i in 0..out {
        let center = lo + (i as f32 + 0.5) * scale;
        let first = ((center - support).floor().max(0.0) as usize).min(src - 1);
        let last = ((center + support).ceil() as usize).min(src);
        let w = &mut weights[i * len..(i + 1) * len];
        let mut total = 0.0;
        for (k, j) in (first..last.max(first + 1)).take(len).enumerate() {
            let v = filter.weight((j as f32 + 0.5 - center) / fscale);
            w[k] = v;
            total += v;
        }
        if total.abs() < 1e-8 {
            // Window narrower than a tap: fall back to the nearest source pixel.
            w.iter_mut().for_each(|v| *v = 0.0);
            w[0] = 1.0;
            start.push(((center.floor().max(0.0)) as usize).min(src - 1));
        } else {
            w.iter_mut().for_each(|v| *v /= total);
            // Keep every tap inside the source (the tail weights are zero), so the passes
            // can read `len` values without bounds arithmetic.
            let shift = (first + len).saturating_sub(src).min(first);
            if shift > 0 {
                w.rotate_right(shift);
            }
            start.push(first - shift);
        }
    }
    Taps {
        start,
        len,
        weights,
    }
}

/// Resamples the window of `src` to `out_w × out_h` with a separable filter.
pub fn resample(src: &Planar, win: Window, out_w: usize, out_h: usize, filter: Filter) -> Planar {
    if win.is_full(src.width, src.height) && out_w == src.width && out_h == src.height {
        return src.clone();
    }
    let mut out = Planar {
        channels: src.channels,
        width: out_w,
        height: out_h,
        data: vec![0.0; src.channels * out_w * out_h],
    };
    resample_into(src, win, out_w, out_h, filter, &mut out.data);
    out
}

/// [`resample`] writing into `dst` (`channels * out_w * out_h` values, any prior content).
pub fn resample_into(
    src: &Planar,
    win: Window,
    out_w: usize,
    out_h: usize,
    filter: Filter,
    dst_all: &mut [f32],
) {
    assert_eq!(
        dst_all.len(),
        src.channels * out_w * out_h,
        "resample_into: destination size"
    );
    if win.is_full(src.width, src.height) && out_w == src.width && out_h == src.height {
        dst_all.copy_from_slice(&src.data);
        return;
    }
    let (sw, sh) = (src.width, src.height);
    let tx = taps(sw, win.x0, win.x1, out_w, filter);
    let ty = taps(sh, win.y0, win.y1, out_h, filter);
    // Source rows the vertical pass will read.
    let row_lo = ty.start.iter().copied().min().unwrap_or(0);
    let row_hi = ty
        .start
        .iter()
        .map(|&s| (s + ty.len).min(sh))
        .max()
        .unwrap_or(0);
    let rows = row_hi - row_lo;
    let mut tmp = take_scratch(rows * out_w);
    for c in 0..src.channels {
        let plane = src.plane(c);
        // Horizontal pass: [rows, sw] -> [rows, out_w].
        for r in 0..rows {
            let src_row = &plane[(row_lo + r) * sw..(row_lo + r + 1) * sw];
            let dst = &mut tmp[r * out_w..(r + 1) * out_w];
            if sw >= tx.len {
                match tx.len {
                    3 => horizontal::<3>(src_row, dst, &tx),
                    5 => horizontal::<5>(src_row, dst, &tx),
                    _ => horizontal_any(src_row, dst, &tx),
                }
                continue;
            }
            for (i, d) in dst.iter_mut().enumerate() {
                let s = tx.start[i];
                let w = &tx.weights[i * tx.len..(i + 1) * tx.len];
                let n = tx.len.min(sw - s);
                *d = src_row[s..s + n]
                    .iter()
                    .zip(&w[..n])
                    .map(|(a, b)| a * b)
                    .sum();
            }
        }
        // Vertical pass: [rows, out_w] -> [out_h, out_w].
        let dst_plane = &mut dst_all[c * out_w * out_h..(c + 1) * out_w * out_h];
        dst_plane.fill(0.0);
        for j in 0..out_h {
            let s = ty.start[j];
            let w = &ty.weights[j * ty.len..(j + 1) * ty.len];
            let n = ty.len.min(sh - s);
            let dst = &mut dst_plane[j * out_w..(j + 1) * out_w];
            for (k, &wk) in w[..n].iter().enumerate() {
                if wk == 0.0 {
                    continue;
                }
                let row = &tmp[(s + k - row_lo) * out_w..(s + k - row_lo + 1) * out_w];
                for (d, v) in dst.iter_mut().zip(row) {
                    *d += wk * v;
                }
            }
        }
    }
    put_scratch(tmp);
    // Cubic overshoot must not leave the unit range.
    if filter == Filter::Bicubic {
        dst_all.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
    }
}

/// Horizontal pass with a compile-time tap count (3: bilinear, 5: bicubic, when enlarging).
fn horizontal<const L: usize>(src_row: &[f32], dst: &mut [f32], tx: &Taps) {
    for ((d, &s), w) in dst
        .iter_mut()
        .zip(&tx.start)
        .zip(tx.weights.chunks_exact(L))
    {
        let x: &[f32; L] = src_row[s..s + L].try_into().expect("taps inside the row");
        let w: &[f32; L] = w.try_into().expect("L weights");
        let mut acc = 0.0;
        for k in 0..L {
            acc += x[k] * w[k];
        }
        *d = acc;
    }
}

fn horizontal_any(src_row: &[f32], dst: &mut [f32], tx: &Taps) {
    for ((d, &s), w) in dst
        .iter_mut()
        .zip(&tx.start)
        .zip(tx.weights.chunks_exact(tx.len))
    {
        *d = src_row[s..s + tx.len]
            .iter()
            .zip(w)
            .map(|(a, b)| a * b)
            .sum();
    }
}

thread_local! {
    /// Per-thread scratch memory: re-touching the same pages is much cheaper than faulting in
    /// fresh ones for every frame.
    static SCRATCH: std::cell::RefCell<Vec<Vec<f32>>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// A zeroed buffer of `len` values from this thread's scratch pool.
pub(crate) fn take_scratch(len: usize) -> Vec<f32> {
    let mut v = SCRATCH.with(|s| s.borrow_mut().pop()).unwrap_or_default();
    v.clear();
    v.resize(len, 0.0);
    v
}

/// Returns a buffer to this thread's scratch pool (at most a few are kept).
pub(crate) fn put_scratch(v: Vec<f32>) {
    SCRATCH.with(|s| {
        let mut s = s.borrow_mut();
        if s.len() < 4 {
            s.push(v);
        }
    });
}

/// Nearest-neighbour resampling of a label window (labels are never interpolated).
pub fn resample_nearest(
    ids: &[u8],
    width: usize,
    height: usize,
    win: Window,
    out_w: usize,
    out_h: usize,
) -> Vec<u8> {
    if win.is_full(width, height) && out_w == width && out_h == height {
        return ids.to_vec();
    }
    let sx = (win.x1 - win.x0) / out_w as f32;
    let sy = (win.y1 - win.y0) / out_h as f32;
    let cols: Vec<usize> = (0..out_w)
        .map(|i| ((win.x0 + (i as f32 + 0.5) * sx).floor().max(0.0) as usize).min(width - 1))
        .collect();
    let mut out = Vec::with_capacity(out_w * out_h);
    for j in 0..out_h {
        let y = ((win.y0 + (j as f32 + 0.5) * sy).floor().max(0.0) as usize).min(height - 1);
        let row = &ids[y * width..(y + 1) * width];
        out.extend(cols.iter().map(|&x| row[x]));
    }
    out
}

/// Mirrors every plane left-right in place.
pub fn hflip_planar(img: &mut Planar) {
    let w = img.width;
    for row in img.data.chunks_exact_mut(w) {
        row.reverse();
    }
}

pub fn hflip_label(ids: &mut [u8], width: usize) {
    for row in ids.chunks_exact_mut(width) {
        row.reverse();
    }
}

/// Rotates image (bilinear) and label (nearest) by `deg` about the centre; uncovered pixels
/// become 0 in the image and `fill` in the label.
pub fn rotate(img: &Planar, label: Option<&[u8]>, deg: f32, fill: u8) -> (Planar, Option<Vec<u8>>) {
    let (w, h) = (img.width, img.height);
    let (s, c) = deg.to_radians().sin_cos();
    let (cx, cy) = ((w as f32 - 1.0) / 2.0, (h as f32 - 1.0) / 2.0);
    let mut out = Planar {
        channels: img.channels,
        width: w,
        height: h,
        data: vec![0.0; img.data.len()],
    };
    let mut out_label = label.map(|_| vec![fill; w * h]);
    for y in 0..h {
        for x in 0..w {
            // Inverse map: output pixel -> source position.
            let (dx, dy) = (x as f32 - cx, y as f32 - cy);
            let sx = c * dx + s * dy + cx;
            let sy = -s * dx + c * dy + cy;
            if sx < -0.5 || sy < -0.5 || sx > w as f32 - 0.5 || sy > h as f32 - 0.5 {
                continue;
            }
            if let (Some(src), Some(dst)) = (label, out_label.as_mut()) {
                let (nx, ny) = (
                    (sx.round() as usize).min(w - 1),
                    (sy.round() as usize).min(h - 1),
                );
                dst[y * w + x] = src[ny * w + nx];
            }
            let (x0, y0) = (sx.floor().max(0.0), sy.floor().max(0.0));
            let (fx, fy) = ((sx - x0).clamp(0.0, 1.0), (sy - y0).clamp(0.0, 1.0));
            let (x0, y0) = (x0 as usize, y0 as usize);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            for ch in 0..img.channels {
                let p = img.plane(ch);
                let v = p[y0 * w + x0] * (1.0 - fx) * (1.0 - fy)
                    + p[y0 * w + x1] * fx * (1.0 - fy)
                    + p[y1 * w + x0] * (1.0 - fx) * fy
                    + p[y1 * w + x1] * fx * fy;
                out.data[ch * w * h + y * w + x] = v;
            }
        }
    }
    (out, out_label)
}

/// Photometric augmentations after the geometry (channels 0..3 RGB, 3 thermal).
pub fn photometric(img: &mut Planar, cfg: &AugmentConfig, rng: &mut impl Rng) {
    let (c, w, h) = (img.channels, img.width, img.height);
    photometric_data(&mut img.data, c, w, h, cfg, rng);
}

/// [`photometric`] on raw planar data (`channels` planes of `width * height`).
pub fn photometric_data(
    data: &mut [f32],
    channels: usize,
    width: usize,
    height: usize,
    cfg: &AugmentConfig,
    rng: &mut impl Rng,
) {
    let mut img = PlanarMut {
        channels,
        width,
        height,
        data,
    };
    let img = &mut img;
    let n = img.width * img.height;
    if let Some(b) = cfg.brightness {
        let f = 1.0 + rng.random_range(-b.abs()..=b.abs());
        img.data[..3 * n]
            .iter_mut()
            .for_each(|v| *v = (*v * f).clamp(0.0, 1.0));
    }
    if let Some((lo, hi)) = cfg.ir_scale {
        let f = if hi > lo {
            rng.random_range(lo..=hi)
        } else {
            lo
        };
        if img.channels > 3 {
            img.plane_mut(3).iter_mut().for_each(|v| *v *= f);
        }
    }
    if let Some(p) = cfg.modality_dropout {
        if rng.random::<f32>() < p {
            let (w, h) = (img.width, img.height);
            let rw = rng.random_range(1..=(w / 2).max(1));
            let rh = rng.random_range(1..=(h / 2).max(1));
            let x0 = rng.random_range(0..=w - rw);
            let y0 = rng.random_range(0..=h - rh);
            let channels: Vec<usize> = if rng.random::<bool>() {
                vec![0, 1, 2]
            } else {
                vec![3]
            };
            let n_channels = img.channels;
            for c in channels.into_iter().filter(|&c| c < n_channels) {
                let plane = img.plane_mut(c);
                for y in y0..y0 + rh {
                    plane[y * w + x0..y * w + x0 + rw]
                        .iter_mut()
                        .for_each(|v| *v = 0.0);
                }
            }
        }
    }
    if let Some(std) = cfg.noise_std {
        if std > 0.0 {
            img.data
                .iter_mut()
                .for_each(|v| *v = (*v + std * gaussian(rng)).clamp(0.0, 1.0));
        }
    }
}

/// Standard normal sample (Box-Muller), so no extra distribution crate is needed.
pub fn gaussian(rng: &mut impl Rng) -> f32 {
    let u1: f32 = rng.random::<f32>().max(1e-7);
    let u2: f32 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

/// Resizes a decoded frame: RGB and thermal bilinear (antialiased when shrinking), label
/// nearest neighbour. Used where whole frames are shown or evaluated at another size.
pub fn resize_frame(frame: &crate::Frame, width: usize, height: usize) -> crate::Frame {
    let (w, h) = (frame.width, frame.height);
    if (w, h) == (width, height) || w == 0 || h == 0 || width == 0 || height == 0 {
        return frame.clone();
    }
    let n = w * h;
    let mut data = vec![0.0f32; 4 * n];
    for (i, px) in frame.rgb.chunks_exact(3).take(n).enumerate() {
        for c in 0..3 {
            data[c * n + i] = px[c] as f32 / 255.0;
        }
    }
    data[3 * n..3 * n + frame.thermal.len().min(n)]
        .copy_from_slice(&frame.thermal[..frame.thermal.len().min(n)]);
    let img = Planar {
        channels: 4,
        width: w,
        height: h,
        data,
    };
    let out = resample(&img, Window::full(w, h), width, height, Filter::Bilinear);
    let m = width * height;
    let mut rgb = Vec::with_capacity(3 * m);
    for i in 0..m {
        for c in 0..3 {
            rgb.push((out.data[c * m + i].clamp(0.0, 1.0) * 255.0).round() as u8);
        }
    }
    crate::Frame {
        name: frame.name.clone(),
        daytime: frame.daytime,
        width,
        height,
        rgb,
        thermal: out.data[3 * m..].to_vec(),
        label: frame
            .label
            .as_ref()
            .map(|l| resample_nearest(l, w, h, Window::full(w, h), width, height)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn ramp(w: usize, h: usize) -> Planar {
        let data = (0..2 * w * h)
            .map(|i| (i % (w * h)) as f32 / (w * h) as f32)
            .collect();
        Planar {
            channels: 2,
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn identity_resample_is_exact_and_constant_stays_constant() {
        let img = ramp(8, 6);
        assert_eq!(
            resample(&img, Window::full(8, 6), 8, 6, Filter::Bicubic),
            img
        );
        let flat = Planar {
            channels: 1,
            width: 10,
            height: 7,
            data: vec![0.25; 70],
        };
        for f in [Filter::Bilinear, Filter::Bicubic] {
            let out = resample(
                &flat,
                Window {
                    x0: 1.0,
                    y0: 2.0,
                    x1: 9.0,
                    y1: 7.0,
                },
                13,
                4,
                f,
            );
            assert!(out.data.iter().all(|v| (v - 0.25).abs() < 1e-5), "{f:?}");
            let down = resample(&flat, Window::full(10, 7), 3, 2, f);
            assert!(down.data.iter().all(|v| (v - 0.25).abs() < 1e-5));
        }
    }

    #[test]
    fn nearest_halving_picks_source_pixels() {
        let ids: Vec<u8> = (0..16).collect();
        let out = resample_nearest(&ids, 4, 4, Window::full(4, 4), 2, 2);
        assert_eq!(out, vec![5, 7, 13, 15]);
    }

    #[test]
    fn crop_window_trims_at_most_the_fraction() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for _ in 0..200 {
            let w = Window::random_crop(640, 480, 0.1, &mut rng);
            assert!(
                w.x0 >= 0.0 && w.x0 < 64.0 && w.x1 >= 576.0 && w.x1 <= 640.0,
                "{w:?}"
            );
            assert!(
                w.y0 >= 0.0 && w.y0 < 48.0 && w.y1 >= 432.0 && w.y1 <= 480.0,
                "{w:?}"
            );
        }
    }

    #[test]
    fn rotation_by_zero_is_identity_and_fills_corners_otherwise() {
        let img = ramp(9, 7);
        let ids: Vec<u8> = (0..63).map(|i| (i % 5) as u8).collect();
        let (same, same_ids) = rotate(&img, Some(&ids), 0.0, 9);
        assert!(same
            .data
            .iter()
            .zip(&img.data)
            .all(|(a, b)| (a - b).abs() < 1e-6));
        assert_eq!(same_ids.unwrap(), ids);
        let (_, rot_ids) = rotate(&img, Some(&ids), 20.0, 9);
        assert_eq!(rot_ids.unwrap()[0], 9, "corner uncovered after rotation");
    }
}
