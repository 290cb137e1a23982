//! The data term: pyramid levels and the eq. 7-style cost (HeatNet §IV-A) in pixel-scaled
//! parameters.
//!
//! A [`Level`] holds every frame at one resolution as tensors (back-projected RGB pixels, the
//! fixed loss support, the RGB features, the thermal source to warp and its gradients) and
//! evaluates the blurred masked feature difference, with a robust (Cauchy) or
//! cross-correlation variant; [`cost`] is its mean over the support. [`Scaling`] maps the
//! pixel-scaled θ to physical parameters ([`model::pixel_scales`]); [`pyramid_factors`],
//! [`assessment_factor`] and [`MAX_LEVEL_PIXELS`] shape the pyramid.

use crate::camera::{Calibration, RgbCamera};
use crate::frames::Frame;
use crate::model::{self, NUM_PARAMS};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::{Device, Kind, Tensor};

/// One pyramid level (or the paper's single full-resolution level) of all frames, as tensors.
pub struct Level {
    pub factor: usize,
    pub h: i64,
    pub w: i64,
    pub tw: i64,
    pub th: i64,
    /// [B, H·W, 3] back-projected RGB pixels.
    pub points: Tensor,
    /// [B, 1, H, W] fixed loss support.
    pub mask: Tensor,
    /// [B, C, H, W] RGB features (edge representation or gradients).
    pub rgb_feat: Tensor,
    /// [B, Ct, th, tw] what gets warped: thermal edge features, or the thermal image (paper).
    pub thermal_src: Tensor,
    /// [B, 2·Ct, th, tw] ∂/∂u and ∂/∂v of `thermal_src` (level pixels), for analytic Jacobians.
    pub thermal_grad: Tensor,
    pub sigma: f64,
    pub taps: i64,
    pub paper: bool,
    /// Cauchy scale c of the robust loss ρ(r) = c²·ln(1 + r²/c²) (0: plain squares).
    pub robust: f64,
    /// Cross-correlation objective on centred features (see [`Level::into_correlation`]).
    pub correlation: bool,
}

impl Level {
    pub fn build(
        rgb_cam: &RgbCamera,
        frames: &[&Frame],
        factor: usize,
        paper: bool,
        sigma: f64,
        taps: i64,
    ) -> Level {
        let mut points = Vec::new();
        let mut masks = Vec::new();
        let mut rgb_feats = Vec::new();
        let mut thermal = Vec::new();
        let (mut h, mut w, mut th, mut tw) = (0, 0, 0, 0);
        for f in frames {
            let depth = model::downsample_depth(&f.depth, factor);
            let (pts, mut mask) = model::level_points(rgb_cam, &depth, factor);
            let rgb = model::plane_tensor(&model::downsample(&f.rgb, factor), Device::Cpu);
            let t = model::plane_tensor(&model::downsample(&f.thermal, factor), Device::Cpu);
            let (rf, tf) = if paper {
                // The gradient of the warped image needs both neighbours inside the support.
                mask = -(-&mask).max_pool2d([3, 3], [1, 1], [1, 1], [1, 1], false);
                (model::gradients(&rgb), t)
            } else {
                (model::edge_features(&rgb), model::edge_features(&t))
            };
            (h, w) = (depth.height as i64, depth.width as i64);
            (th, tw) = (tf.size()[2], tf.size()[3]);
            points.push(pts);
            masks.push(mask);
            rgb_feats.push(rf);
            thermal.push(tf);
        }
        let thermal_src = Tensor::cat(&thermal, 0);
        let (b, ct) = (thermal_src.size()[0], thermal_src.size()[1]);
        let g =
            model::gradients(&thermal_src.reshape([b * ct, 1, th, tw])).reshape([b, ct, 2, th, tw]);
        let thermal_grad = Tensor::cat(&[g.select(2, 0), g.select(2, 1)], 1);
        Level {
            factor,
            h,
            w,
            tw,
            th,
            points: Tensor::cat(&points, 0),
            mask: Tensor::cat(&masks, 0),
            rgb_feat: Tensor::cat(&rgb_feats, 0),
            thermal_src,
            thermal_grad,
            sigma,
            taps,
            paper,
            robust: 0.0,
            correlation: false,
        }
    }

    /// Keeps `n` pixels per frame (a seeded random subset of the loss support, padded with
    /// pixels outside it if a frame has fewer), as a 1×n "image": the cost of a level then
    /// grows with `n`, not with the resolution, while the thermal features keep their full
    /// resolution. Only for unblurred levels (the blur needs the pixel grid).
    pub fn subsample(mut self, n: usize, seed: u64) -> Level {
        assert!(
            self.taps <= 1 && !self.paper,
            "subsampling needs an unblurred level"
        );
        let hw = (self.h * self.w) as usize;
        if n >= hw {
            return self;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let b = self.points.size()[0];
        let mut picks = Vec::new();
        for f in 0..b {
            let m: Vec<f32> = Vec::try_from(self.mask.get(f).flatten(0, -1)).unwrap();
            let (mut inside, mut outside): (Vec<i64>, Vec<i64>) =
                (0..hw as i64).partition(|&i| m[i as usize] > 0.0);
            inside.shuffle(&mut rng);
            outside.shuffle(&mut rng);
            let mut pick: Vec<i64> = inside.into_iter().chain(outside).take(n).collect();
            pick.sort();
            picks.push(Tensor::from_slice(&pick));
        }
        let idx = Tensor::stack(&picks, 0); // [B, n]
        let gather = |t: &Tensor| {
            let c = t.size()[1];
            t.reshape([b, c, -1])
                .gather(2, &idx.unsqueeze(1).expand([b, c, n as i64], false), false)
                .view([b, c, 1, n as i64])
        };
        self.points =
            self.points
                .gather(1, &idx.unsqueeze(2).expand([b, n as i64, 3], false), false);
        self.mask = gather(&self.mask);
        self.rgb_feat = gather(&self.rgb_feat);
        self.h = 1;
        self.w = n as i64;
        self
    }

    /// A copy sharing the tensors' storage (read-only use from another thread).
    pub fn shallow(&self) -> Level {
        Level {
            points: self.points.shallow_clone(),
            mask: self.mask.shallow_clone(),
            rgb_feat: self.rgb_feat.shallow_clone(),
            thermal_src: self.thermal_src.shallow_clone(),
            thermal_grad: self.thermal_grad.shallow_clone(),
            ..*self
        }
    }

    /// Warps the thermal source of frames `idx` into the RGB view: [b, Ct, H, W].
    pub fn warp(&self, p: &Tensor, idx: &Tensor) -> Tensor {
        let (u, v) = model::project(&self.points.index_select(0, idx), p);
        let grid = model::sampling_grid(&u, &v, self.factor, self.tw, self.th, self.h, self.w);
        // Paper: border padding so the warped image has no artificial edge at the thermal
        // frame; default: zero padding of edge features (outside = no edges).
        let padding = if self.paper { 1 } else { 0 };
        self.thermal_src
            .index_select(0, idx)
            .grid_sampler_2d(&grid, 0, padding, true)
    }

    /// Blurred masked feature difference [b, C, H, W] (eq. 7 before squaring).
    pub fn residual(&self, p: &Tensor, idx: &Tensor) -> Tensor {
        let warped = self.warp(p, idx);
        let feat_t = if self.paper {
            model::gradients(&warped)
        } else {
            warped
        };
        let mask = self.mask.index_select(0, idx);
        let diff = (self.rgb_feat.index_select(0, idx) - feat_t) * &mask;
        model::gaussian_blur(&diff, self.sigma, self.taps)
    }

    /// Switches to the cross-correlation objective: features are centred (RGB over the loss
    /// support, thermal over the whole thermal image, so the zero padding outside it is the
    /// mean) and the per-pixel cost is a² − 2·a·t with a = G * (M·F_RGB), t = G * (M·F_T): the
    /// squared difference without its Σt² term. That term rewarded maps that sample thermal
    /// regions with little edge energy (or leave the thermal image): on real-imagery rigs,
    /// where most edges exist in one band only, it biased f by +3–4 %.
    pub fn into_correlation(mut self) -> Level {
        let dims = &[2i64, 3][..];
        let n = self
            .mask
            .sum_dim_intlist(dims, true, Kind::Float)
            .clamp_min(1.0);
        let mean_rgb = (&self.rgb_feat * &self.mask).sum_dim_intlist(dims, true, Kind::Float) / n;
        self.rgb_feat = (&self.rgb_feat - mean_rgb) * &self.mask;
        let mean_t = self.thermal_src.mean_dim(dims, true, Kind::Float);
        self.thermal_src = &self.thermal_src - mean_t;
        self.correlation = true;
        self
    }

    /// Per-pixel cost [b, C, H, W] at physical parameters `p`.
    pub fn pixel_cost(&self, p: &Tensor, idx: &Tensor) -> Tensor {
        let r = self.residual(p, idx);
        if self.correlation {
            let a = self.blurred_rgb(idx);
            let t = &a - r;
            a.square() - a * t * 2.0
        } else {
            self.rho(&r)
        }
    }

    /// G * (M·F_RGB) of frames `idx`.
    pub fn blurred_rgb(&self, idx: &Tensor) -> Tensor {
        let mask = self.mask.index_select(0, idx);
        model::gaussian_blur(
            &(self.rgb_feat.index_select(0, idx) * mask),
            self.sigma,
            self.taps,
        )
    }

    /// ρ(r) elementwise: r² or the Cauchy loss c²·ln(1 + r²/c²).
    pub fn rho(&self, r: &Tensor) -> Tensor {
        if self.robust > 0.0 {
            let c2 = self.robust * self.robust;
            (r.square() / c2).log1p() * c2
        } else {
            r.square()
        }
    }

    /// IRLS weights ρ'(r)/(2r): 1 for squares, 1/(1 + r²/c²) for Cauchy.
    pub fn irls_weight(&self, r: &Tensor) -> Tensor {
        if self.robust > 0.0 {
            (r.square() / (self.robust * self.robust) + 1.0).reciprocal()
        } else {
            r.ones_like()
        }
    }

    /// Normaliser of the loss: support pixels × channels of frames `idx` (fixed per frame).
    pub fn support(&self, idx: &Tensor) -> f64 {
        let c = self.rgb_feat.size()[1] as f64;
        self.mask
            .index_select(0, idx)
            .sum(Kind::Double)
            .double_value(&[])
            * c
    }
}

/// Parameters in pixel-scaled units θ: physical = p0 + scale ⊙ θ.
pub struct Scaling {
    pub p0: [f64; NUM_PARAMS],
    pub scale: [f64; NUM_PARAMS],
}

impl Scaling {
    pub fn new(rgb: &RgbCamera, p0: [f64; NUM_PARAMS], frames: &[&Frame]) -> Self {
        Self {
            p0,
            scale: model::pixel_scales(rgb, &p0, &depth_samples(frames)),
        }
    }

    pub fn physical(&self, theta: &[f64; NUM_PARAMS]) -> [f64; NUM_PARAMS] {
        std::array::from_fn(|i| self.p0[i] + self.scale[i] * theta[i])
    }

    /// The calibration at pixel-scaled parameters `theta`.
    pub fn calibration(&self, theta: &[f64; NUM_PARAMS]) -> Calibration {
        model::to_calibration(&self.physical(theta))
    }

    /// The pixel-scaled parameters of calibration `c` (inverse of [`Scaling::calibration`]).
    pub fn theta_of(&self, c: &Calibration) -> [f64; NUM_PARAMS] {
        let p = model::from_calibration(c);
        std::array::from_fn(|i| (p[i] - self.p0[i]) / self.scale[i])
    }

    pub fn tensor(&self, theta: &[f64; NUM_PARAMS]) -> Tensor {
        Tensor::from_slice(&self.physical(theta).map(|x| x as f32))
    }
}

/// The pyramid factor of the finest level at most 320 px wide (where the quality assessment
/// and the bound look at a solution).
pub fn assessment_factor(width: usize) -> usize {
    pyramid_factors(width)
        .into_iter()
        .filter(|&f| width / f <= 320)
        .min()
        .unwrap_or(1)
}

pub fn pyramid_factors(width: usize) -> Vec<usize> {
    let mut factors = vec![1];
    while width / (factors.last().unwrap() * 2) >= 40 && factors.len() < 6 {
        factors.push(factors.last().unwrap() * 2);
    }
    factors.reverse();
    factors
}

/// Pixels per frame of a level at most (half of 320×240; larger levels, from 320×240 up, use
/// a random subset, which makes a normal-equation evaluation about ten times cheaper at
/// 640×480; docs/src/calibration.md).
pub const MAX_LEVEL_PIXELS: usize = 160 * 240;

/// Mean data cost (per support pixel and channel) of frames `idx` at pixel-scaled `theta`.
pub fn cost(level: &Level, scaling: &Scaling, theta: &[f64; NUM_PARAMS], idx: &Tensor) -> f64 {
    level
        .pixel_cost(&scaling.tensor(theta), idx)
        .sum(Kind::Double)
        .double_value(&[])
        / level.support(idx)
}

/// RGB pixels with depth (u, v, z-depth), ~400 per frame.
pub(super) fn depth_samples(frames: &[&Frame]) -> Vec<(f64, f64, f64)> {
    let mut samples = Vec::new();
    for f in frames {
        let step = ((f.depth.width * f.depth.height) / 400).max(1);
        for i in (0..f.depth.data.len()).step_by(step) {
            let d = f.depth.data[i] as f64;
            if d > 0.0 {
                samples.push(((i % f.depth.width) as f64, (i / f.depth.width) as f64, d));
            }
        }
    }
    samples
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optimize::initial_params;

    #[test]
    fn subsampled_level_keeps_the_cost_of_its_pixels() {
        tch::set_num_threads(1);
        let dir = tempfile::tempdir().unwrap();
        let (synth, frames) = crate::optimize::tests::small_test_rig(dir.path());
        let used: Vec<&Frame> = frames.iter().collect();
        let scaling = Scaling::new(&synth.rig.rgb, initial_params(&synth.rig), &used);
        let theta = [0.7; NUM_PARAMS];
        let idx = Tensor::from_slice(&[0i64, 1]);
        let full = Level::build(&synth.rig.rgb, &used, 1, false, 0.0, 1);
        let n = (full.h * full.w) as usize;
        // All pixels, reordered: the same cost; a subset: its own pixels' cost.
        let same = Level::build(&synth.rig.rgb, &used, 1, false, 0.0, 1).subsample(n - 1, 3);
        assert_eq!((same.h, same.w), (1, n as i64 - 1));
        let (cf, cs) = (
            cost(&full, &scaling, &theta, &idx),
            cost(&same, &scaling, &theta, &idx),
        );
        assert!((cf - cs).abs() < 0.02 * cf, "{cf} vs {cs}");
        let half = Level::build(&synth.rig.rgb, &used, 1, false, 0.0, 1).subsample(n / 2, 3);
        let ch = cost(&half, &scaling, &theta, &idx);
        assert!(ch > 0.0 && (ch - cf).abs() < 0.25 * cf, "{ch} vs {cf}");
    }
}
