//! The optimisers. Both minimise eq. 7-style losses over K_T, distortion and ξ ∈ se(3), in
//! parameters scaled so that one unit moves the RGB→thermal map by ~1 px (see
//! [`model::pixel_scales`]).
//!
//! - `paper`: HeatNet §IV-A as published: full resolution, ∇ of the warped thermal image vs ∇
//!   of the RGB image, Gaussian σ = 3 / 51 px, Adam, batches of 10 from up to 600 random
//!   pairs, 8000 iterations, step halved every 500.
//! - `default` (ours): coarse-to-fine pyramid (coarsest ≥ 40 px wide), a polarity-blind edge
//!   representation ([`model::edge_features`]) warped from thermal space with zero padding
//!   (no artificial border edges), a fixed loss support (RGB pixels with depth), an exhaustive
//!   shift search at the coarsest level (the rough landscape's basin), then damped
//!   Gauss-Newton (Levenberg-Marquardt with finite-difference Jacobians and a step limit) per
//!   level, which also handles the strongly correlated parameters (cx vs. ω_y vs. t_x).

use crate::camera::{Calibration, RgbCamera};
use crate::error::{CalibError, Result};
use crate::frames::Frame;
use crate::model::{self, NUM_PARAMS};
use crate::rig::{OptimizerOverrides, Rig};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::{Device, Kind, Tensor};

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Recipe {
    Default,
    Paper,
}

/// Resolved optimiser settings (flags > rig.yaml `optimizer:` > recipe).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    pub recipe: Recipe,
    /// paper: Adam iterations; default: Levenberg-Marquardt iterations per pyramid level.
    pub iterations: usize,
    /// paper: pairs per Adam step; default: frames used per level (a seeded random subset).
    pub batch_size: usize,
    /// paper: initial Adam step (pixel-scaled units); default: sets the first
    /// Levenberg-Marquardt damping λ₀ = 10⁻⁵ / learning_rate (λ adapts afterwards, so any
    /// sensible value works, including a rig.yaml written for Adam).
    pub learning_rate: f64,
    pub seed: u64,
}

impl Settings {
    pub fn recipe_defaults(recipe: Recipe) -> OptimizerOverrides {
        match recipe {
            Recipe::Paper => OptimizerOverrides {
                iterations: Some(8000),
                batch_size: Some(10),
                learning_rate: Some(0.1),
            },
            Recipe::Default => OptimizerOverrides {
                iterations: Some(20),
                batch_size: Some(20),
                learning_rate: Some(0.01),
            },
        }
    }

    pub fn resolve(
        recipe: Recipe,
        flags: OptimizerOverrides,
        file: Option<OptimizerOverrides>,
        seed: u64,
    ) -> Result<Self> {
        let s = flags
            .or(file.unwrap_or_default())
            .or(Self::recipe_defaults(recipe));
        let settings = Settings {
            recipe,
            iterations: s.iterations.unwrap_or(1),
            batch_size: s.batch_size.unwrap_or(1),
            learning_rate: s.learning_rate.unwrap_or(1.0),
            seed,
        };
        if settings.iterations == 0 || settings.batch_size == 0 {
            return Err(CalibError::Setting(
                "iterations and batch size must be at least 1".into(),
            ));
        }
        if !(settings.learning_rate.is_finite() && settings.learning_rate > 0.0) {
            return Err(CalibError::Setting(format!(
                "learning rate must be positive, got {}",
                settings.learning_rate
            )));
        }
        Ok(settings)
    }
}

/// Progress report after each optimiser iteration.
#[derive(Debug, Clone)]
pub struct Progress {
    pub stage: String,
    pub step: usize,
    pub total: usize,
    pub loss: f64,
}

#[derive(Debug, Clone)]
/// What an optimiser run found, before its assessment ([`crate::solve::Outcome`]).
pub struct Solution {
    pub initial: Calibration,
    pub calibration: Calibration,
    /// Final loss of the finest stage (mean squared blurred residual).
    pub loss: f64,
    pub frames_used: usize,
    pub iterations: usize,
    /// Why the optimiser stopped early (NaN, divergence), if it did; the best parameters are kept.
    pub stopped: Option<String>,
    /// Indices (into the frames given) of the frames the optimiser used.
    pub used: Vec<usize>,
    /// The wrong-basin check of the default recipe ([`Pipeline::restart`]).
    pub restarts: Option<Restarts>,
}

/// The wrong-basin check of the default recipe ([`Pipeline::restart`]): the
/// solution perturbed and refined again from several starts.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Restarts {
    /// Solutions compared (the continued main solution and the perturbed restarts).
    pub count: usize,
    /// Rounds of restarts run (a second round runs around a clearly better solution).
    pub rounds: usize,
    /// Perturbation of the starts (full-resolution thermal px).
    pub perturbation_px: f64,
    /// Mean distance (px) between the main run's map and the chosen one (0: it stood).
    pub improved_px: f64,
    /// Relative cost drop from the main run's solution to the best restart.
    pub cost_drop: f64,
    /// Largest distance (px) from the best solution to any solution of about the same cost.
    pub spread_px: f64,
    /// False if the last round still found a clearly better, distinct solution.
    pub settled: bool,
}

/// Eq. 8 initial parameters: K_T from f_m / l and the image centre (or the prior's principal
/// point), the extrinsic at the prior's rotation and camera centre where rig.yaml gives them,
/// everything else 1e-4.
pub fn initial_params(rig: &Rig) -> [f64; NUM_PARAMS] {
    let k = rig.nominal_thermal();
    let mut p = [1e-4; NUM_PARAMS];
    p[0] = k.fx;
    p[1] = k.fy;
    p[2] = k.cx;
    p[3] = k.cy;
    let Some(prior) = &rig.prior else {
        return p;
    };
    if let Some(c) = &prior.principal_point_px {
        (p[2], p[3]) = (c[0], c[1]);
    }
    let w: [f64; 3] = match &prior.rotation_deg {
        Some(r) => std::array::from_fn(|i| r[i].to_radians()),
        None => [1e-4; 3],
    };
    let rotation = crate::se3::Rigid::exp([0.0, 0.0, 0.0, w[0], w[1], w[2]]);
    let t = match &prior.translation_m {
        // X_T = R·X_RGB + t and the centre C maps to 0: t = −R·C.
        Some(c) => crate::se3::mat_vec(&rotation.rotation, [c[0], c[1], c[2]]).map(|x| -x),
        None => [1e-4; 3],
    };
    let xi = crate::se3::Rigid {
        translation: t,
        ..rotation
    }
    .log();
    p[8..14].copy_from_slice(&xi);
    p
}

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

/// Runs the recipe's optimiser on loaded frames (no assessment: see [`crate::solve`]).
pub fn solve(
    rig: &Rig,
    frames: &[Frame],
    settings: &Settings,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Solution> {
    let _guard = tch::no_grad_guard();
    let p0 = initial_params(rig);
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    match settings.recipe {
        Recipe::Default => calibrate_default(rig, frames, settings, p0, &mut rng, progress),
        Recipe::Paper => calibrate_paper(rig, frames, settings, p0, &mut rng, progress),
    }
}

pub fn cost(level: &Level, scaling: &Scaling, theta: &[f64; NUM_PARAMS], idx: &Tensor) -> f64 {
    level
        .pixel_cost(&scaling.tensor(theta), idx)
        .sum(Kind::Double)
        .double_value(&[])
        / level.support(idx)
}

/// Half-width of the principal point's free zone around the image centre, in thermal widths:
/// inside it the prior costs nothing, outside it grows with σ = 5 % of the width. A centred
/// Gaussian (no free zone) pulled the synthetic rigs' principal points (truth within 1.5 % of
/// the width from the centre) 1.3–3.6 px inwards and the rotation 0.3–0.5° off along the flat
/// principal-point / pan valley at 640×480 (docs/src/calibration.md, round 7).
const PRINCIPAL_POINT_FREE: f64 = 0.05;

/// The priors, as residuals in physical units: built in (issue 12), the principal point near
/// the image centre (free within [`PRINCIPAL_POINT_FREE`]) and bounded distortion; from
/// rig.yaml's `prior:` (issue 28), the thermal camera centre, the rotation vector and the
/// principal point the user gives (then replacing the built-in one). The square-pixel
/// constraint (fx = fy) is exact instead (a tied search direction, see [`directions`]).
#[derive(Debug, Clone)]
pub struct Priors {
    /// (parameter index, mean, standard deviation, free half-width): the residual is
    /// (|p − μ| − w)₊/σ, so a bound (w > 0) costs nothing inside it.
    pub terms: Vec<(usize, f64, f64, f64)>,
    /// The thermal camera centre −Rᵀt in the RGB frame (metres) and its σ, if given.
    pub centre: Option<([f64; 3], f64)>,
    /// Weight in cost units: the data cost of ~1 px of misalignment (set per level).
    pub weight: f64,
}

/// The thermal camera centre in the RGB frame (−Rᵀt) of physical parameters `p`.
pub fn camera_centre(p: &[f64; NUM_PARAMS]) -> [f64; 3] {
    let e = crate::se3::Rigid::exp([p[8], p[9], p[10], p[11], p[12], p[13]]);
    e.inverse().translation
}

impl Priors {
    pub fn new(rig: &Rig) -> Self {
        let (w, h) = (rig.thermal.width as f64, rig.thermal.height as f64);
        let pp_free = PRINCIPAL_POINT_FREE * w;
        let user = rig.prior.clone().unwrap_or_default();
        let mut terms = match user.principal_point_sigma_px {
            Some(sd) => {
                let c = user
                    .principal_point_px
                    .clone()
                    .unwrap_or(vec![w / 2.0, h / 2.0]);
                vec![(2, c[0], sd, 0.0), (3, c[1], sd, 0.0)]
            }
            None => vec![
                (2, w / 2.0, 0.05 * w, pp_free),
                (3, h / 2.0, 0.05 * w, pp_free),
            ],
        };
        terms.extend([
            (4, 0.0, 0.05, 0.5),
            (5, 0.0, 0.05, 0.3),
            (6, 0.0, 0.002, 0.01),
            (7, 0.0, 0.002, 0.01),
        ]);
        if let (Some(r), Some(sd)) = (&user.rotation_deg, user.rotation_sigma_deg) {
            for (i, mu) in r.iter().enumerate() {
                terms.push((11 + i, mu.to_radians(), sd.to_radians(), 0.0));
            }
        }
        let centre = match (&user.translation_m, user.translation_sigma_m) {
            (Some(t), Some(sd)) => Some(([t[0], t[1], t[2]], sd)),
            _ => None,
        };
        Self {
            terms,
            centre,
            weight: 0.0,
        }
    }

    fn residual(p: f64, mu: f64, sd: f64, free: f64) -> f64 {
        let e = p - mu;
        e.signum() * (e.abs() - free).max(0.0) / sd
    }

    /// Every prior residual at physical parameters `p` (terms first, then the centre's axes).
    pub fn residuals(&self, p: &[f64; NUM_PARAMS]) -> Vec<f64> {
        let mut r: Vec<f64> = self
            .terms
            .iter()
            .map(|&(i, mu, sd, free)| Self::residual(p[i], mu, sd, free))
            .collect();
        if let Some((mu, sd)) = self.centre {
            let c = camera_centre(p);
            r.extend((0..3).map(|k| (c[k] - mu[k]) / sd));
        }
        r
    }

    pub fn cost(&self, scaling: &Scaling, theta: &[f64; NUM_PARAMS]) -> f64 {
        let r = self.residuals(&scaling.physical(theta));
        self.weight * r.iter().map(|x| x * x).sum::<f64>()
    }
}

/// Search directions of a stage in θ space. With square pixels fx and fy move together (one
/// focal direction moving both by the same physical amount), otherwise each is free.
pub fn directions(params: &[usize], scaling: &Scaling, square: bool) -> Vec<[f64; NUM_PARAMS]> {
    let mut dirs = Vec::new();
    for &i in params {
        let mut d = [0.0; NUM_PARAMS];
        if square && i == 1 {
            continue;
        }
        d[i] = 1.0;
        if square && i == 0 {
            d[1] = scaling.scale[0] / scaling.scale[1];
        }
        dirs.push(d);
    }
    dirs
}

/// Solves the symmetric positive definite system `a x = b` (Cholesky); `None` if not SPD.
pub fn solve_spd(a: &[Vec<f64>], b: &[f64]) -> Option<Vec<f64>> {
    let n = b.len();
    let mut l = vec![vec![0.0; n]; n];
    for i in 0..n {
        for j in 0..=i {
            let s = a[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            if i == j {
                if s <= 0.0 || !s.is_finite() {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = vec![0.0; n];
    for i in 0..n {
        y[i] = (b[i] - (0..i).map(|k| l[i][k] * y[k]).sum::<f64>()) / l[i][i];
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        x[i] = (y[i] - (i + 1..n).map(|k| l[k][i] * x[k]).sum::<f64>()) / l[i][i];
    }
    Some(x)
}

/// JᵀJ, Jᵀr (normalised by the support) and the data cost at θ, along `dirs` (Gauss-Newton,
/// Lucas-Kanade style): ∂r/∂d = −G * (M · (∂F_T/∂u · ∂u/∂d + ∂F_T/∂v · ∂v/∂d)), with the
/// feature gradients warped alongside the features and ∂(u, v)/∂d from finite differences of
/// the (smooth) projection.
pub fn normal_equations(
    level: &Level,
    scaling: &Scaling,
    theta: &[f64; NUM_PARAMS],
    dirs: &[[f64; NUM_PARAMS]],
    frames: &[i64],
) -> (Vec<Vec<f64>>, Vec<f64>, f64) {
    let n = dirs.len();
    let mut jtj = vec![vec![0.0; n]; n];
    let mut jtr = vec![0.0; n];
    let mut sq = 0.0;
    let mut support = 0.0;
    let hstep = 0.05;
    let inv_f = 1.0 / level.factor as f64;
    let ct = level.thermal_src.size()[1];
    for &f in frames {
        let idx = Tensor::from_slice(&[f]);
        support += level.support(&idx);
        let pts = level.points.index_select(0, &idx);
        let (u0, v0) = model::project(&pts, &scaling.tensor(theta));
        let grid =
            model::sampling_grid(&u0, &v0, level.factor, level.tw, level.th, level.h, level.w);
        let src = Tensor::cat(
            &[
                level.thermal_src.index_select(0, &idx),
                level.thermal_grad.index_select(0, &idx),
            ],
            1,
        );
        let sampled = src.grid_sampler_2d(&grid, 0, 0, true); // [1, 3·Ct, H, W]
        let feat = sampled.narrow(1, 0, ct);
        let (du_feat, dv_feat) = (sampled.narrow(1, ct, ct), sampled.narrow(1, 2 * ct, ct));
        let mask = level.mask.index_select(0, &idx);
        let blur = |x: &Tensor| model::gaussian_blur(x, level.sigma, level.taps);
        let r0 = blur(&((level.rgb_feat.index_select(0, &idx) - &feat) * &mask))
            .flatten(0, -1)
            .to_kind(Kind::Double);
        let (sw, r0) = if level.correlation {
            // Gradient of Σ(a² − 2a·t) is 2·Jᵀa (J = ∂r/∂θ = −∂t/∂θ); JᵀJ stays the metric.
            let a = level.blurred_rgb(&idx).flatten(0, -1).to_kind(Kind::Double);
            sq += (a.square() - &a * (&a - &r0) * 2.0)
                .sum(Kind::Double)
                .double_value(&[]);
            (r0.ones_like(), a)
        } else {
            sq += level.rho(&r0).sum(Kind::Double).double_value(&[]);
            let sw = level.irls_weight(&r0).sqrt();
            let r = &r0 * &sw;
            (sw, r)
        };
        let hw = [1, 1, level.h, level.w];
        if level.taps <= 1 && !level.correlation && level.robust == 0.0 {
            // Unblurred squares (the finer levels of the default recipe): J = −M·(F_u·du +
            // F_v·dv) per channel, so JᵀJ and Jᵀr reduce over the channels first — a 2×2
            // structure tensor and a 2-vector per pixel — and only the 2·n motion columns
            // (du, dv per direction) enter the products (3–4× fewer operations than forming
            // the [C·N, n] Jacobian).
            let (mut dus, mut dvs) = (Vec::new(), Vec::new());
            for d in dirs {
                let t: [f64; NUM_PARAMS] = std::array::from_fn(|i| theta[i] + hstep * d[i]);
                let (u1, v1) = model::project(&pts, &scaling.tensor(&t));
                dus.push(((u1 - &u0) * (inv_f / hstep)).flatten(0, -1));
                dvs.push(((v1 - &v0) * (inv_f / hstep)).flatten(0, -1));
            }
            let du = Tensor::stack(&dus, 1).to_kind(Kind::Double); // [N, n]
            let dv = Tensor::stack(&dvs, 1).to_kind(Kind::Double);
            let m = mask.flatten(0, -1).to_kind(Kind::Double); // M² = M (0/1)
            let chan = |x: Tensor| x.sum_dim_intlist(1, false, Kind::Double).flatten(0, -1);
            let suu = chan(du_feat.square()) * &m;
            let suv = chan(&du_feat * &dv_feat) * &m;
            let svv = chan(dv_feat.square()) * &m;
            let r = r0.view_as(&feat).to_kind(Kind::Float);
            let gu = chan(&du_feat * &r) * &m;
            let gv = chan(&dv_feat * &r) * &m;
            let cross = du.tr().matmul(&(&dv * suv.unsqueeze(1)));
            let a = du.tr().matmul(&(&du * suu.unsqueeze(1)))
                + &cross
                + cross.tr()
                + dv.tr().matmul(&(&dv * svv.unsqueeze(1)));
            let b = -(du.tr().matmul(&gu) + dv.tr().matmul(&gv));
            let jtj_t: Vec<f64> = Vec::try_from(a.flatten(0, -1)).unwrap();
            let jtr_t: Vec<f64> = Vec::try_from(b).unwrap();
            for (a, row) in jtj.iter_mut().enumerate() {
                jtr[a] += jtr_t[a];
                for (b, x) in row.iter_mut().enumerate() {
                    *x += jtj_t[a * n + b];
                }
            }
            continue;
        }
        let cols: Vec<Tensor> = dirs
            .iter()
            .map(|d| {
                let t: [f64; NUM_PARAMS] = std::array::from_fn(|i| theta[i] + hstep * d[i]);
                let (u1, v1) = model::project(&pts, &scaling.tensor(&t));
                let du = ((u1 - &u0) * (inv_f / hstep)).view(hw);
                let dv = ((v1 - &v0) * (inv_f / hstep)).view(hw);
                (-blur(&((&du_feat * du + &dv_feat * dv) * &mask)))
                    .flatten(0, -1)
                    .to_kind(Kind::Double)
            })
            .collect();
        let j = Tensor::stack(&cols, 1) * sw.unsqueeze(1); // [N, n]
        let jtj_t: Vec<f64> = Vec::try_from(j.tr().matmul(&j).flatten(0, -1)).unwrap();
        let jtr_t: Vec<f64> = Vec::try_from(j.tr().matmul(&r0)).unwrap();
        for (a, row) in jtj.iter_mut().enumerate() {
            jtr[a] += jtr_t[a];
            for (b, x) in row.iter_mut().enumerate() {
                *x += jtj_t[a * n + b];
            }
        }
    }
    let support = support.max(1.0);
    jtr.iter_mut().for_each(|x| *x /= support);
    jtj.iter_mut().flatten().for_each(|x| *x /= support);
    (jtj, jtr, sq / support)
}

/// Adds the priors' Gauss-Newton terms (along `dirs`) to a normalised system; the residuals'
/// slopes by forward differences (a free zone's edge is a kink, the centre is nonlinear).
pub fn add_priors(
    priors: &Priors,
    scaling: &Scaling,
    theta: &[f64; NUM_PARAMS],
    dirs: &[[f64; NUM_PARAMS]],
    jtj: &mut [Vec<f64>],
    jtr: &mut [f64],
) {
    let h = 1e-4;
    let r = priors.residuals(&scaling.physical(theta));
    let slopes: Vec<Vec<f64>> = dirs
        .iter()
        .map(|d| {
            let t: [f64; NUM_PARAMS] = std::array::from_fn(|i| theta[i] + h * d[i]);
            let rt = priors.residuals(&scaling.physical(&t));
            rt.iter().zip(&r).map(|(b, a)| (b - a) / h).collect()
        })
        .collect();
    for k in 0..r.len() {
        for a in 0..dirs.len() {
            jtr[a] += priors.weight * slopes[a][k] * r[k];
            for b in 0..dirs.len() {
                jtj[a][b] += priors.weight * slopes[a][k] * slopes[b][k];
            }
        }
    }
}

/// Result of [`lm_level`].
pub struct LmRun {
    pub theta: [f64; NUM_PARAMS],
    pub cost: f64,
    pub iterations: usize,
    pub non_finite: bool,
}

/// Levenberg-Marquardt on one pyramid level along `dirs` from `theta`, over frames `frames`,
/// with the priors (their weight is set here: one σ costs as much as ~1 px of misalignment,
/// the data's mean curvature per pixel-scaled unit at the first iteration), Levenberg damping
/// λ·mean(diag)·I from `lambda0` and a step limit of 2 px × the level's factor.
#[allow(clippy::too_many_arguments)]
pub fn lm_level(
    level: &Level,
    scaling: &Scaling,
    priors: &mut Priors,
    mut theta: [f64; NUM_PARAMS],
    dirs: &[[f64; NUM_PARAMS]],
    frames: &[i64],
    max_iterations: usize,
    lambda0: f64,
    on_iteration: &mut dyn FnMut(f64),
) -> LmRun {
    let idx = Tensor::from_slice(frames);
    // Trust region: at most 2 full-resolution pixels per iteration and level factor.
    let max_step = 2.0 * level.factor as f64;
    let mut lambda = lambda0;
    let mut current = f64::NAN;
    let mut iterations = 0;
    let mut non_finite = false;
    priors.weight = f64::NAN;
    for _ in 0..max_iterations {
        let (mut jtj, mut jtr, c) = normal_equations(level, scaling, &theta, dirs, frames);
        iterations += 1;
        if !c.is_finite() {
            non_finite = true;
            break;
        }
        let n = dirs.len();
        let mean_diag = (0..n).map(|i| jtj[i][i]).sum::<f64>() / n as f64;
        if priors.weight.is_nan() {
            priors.weight = mean_diag.max(1e-12);
        }
        add_priors(priors, scaling, &theta, dirs, &mut jtj, &mut jtr);
        current = c + priors.cost(scaling, &theta);
        let mut accepted = false;
        let mut small = false;
        while lambda < 1e8 {
            let mut a = jtj.clone();
            // Levenberg damping λ·mean(diag)·I: the units are commensurate (pixels), and
            // unlike Marquardt's diag scaling it resists drift along flat valleys.
            for (i, row) in a.iter_mut().enumerate() {
                row[i] += lambda * mean_diag.max(1e-12) + 1e-12;
            }
            let rhs: Vec<f64> = jtr.iter().map(|x| -x).collect();
            let Some(coef) = solve_spd(&a, &rhs) else {
                lambda *= 10.0;
                continue;
            };
            let mut delta = [0.0; NUM_PARAMS];
            for (c, d) in coef.iter().zip(dirs) {
                for i in 0..NUM_PARAMS {
                    delta[i] += c * d[i];
                }
            }
            let biggest = delta.iter().fold(0.0f64, |m, d| m.max(d.abs()));
            if biggest > max_step {
                delta = delta.map(|d| d * max_step / biggest);
            }
            small = biggest < 1e-3 * level.factor as f64;
            let trial: [f64; NUM_PARAMS] = std::array::from_fn(|i| theta[i] + delta[i]);
            let tc = cost(level, scaling, &trial, &idx) + priors.cost(scaling, &trial);
            if tc.is_finite() && tc < current {
                theta = trial;
                current = tc;
                lambda = (lambda / 3.0).max(1e-7);
                accepted = true;
                break;
            }
            lambda *= 4.0;
        }
        on_iteration(current);
        if !accepted || small {
            break;
        }
    }
    LmRun {
        theta,
        cost: current,
        iterations,
        non_finite,
    }
}

/// The default recipe's coarse-to-fine pipeline over a fixed set of frames: the pyramid
/// levels (built once), the parameter scaling and the staging, so that the main run and the
/// restarts of the wrong-basin check ([`crate::quality`]) share them.
pub struct Pipeline<'a> {
    pub rig: &'a Rig,
    pub used: Vec<&'a Frame>,
    pub scaling: Scaling,
    pub square: bool,
    pub factors: Vec<usize>,
    pub levels: Vec<Level>,
    pub iterations: usize,
    pub lambda0: f64,
    /// RGB pixels with depth (u, v, metres), ~400 per frame, for map distances.
    pub samples: Vec<(f64, f64, f64)>,
    pub staging: Staging,
}

/// How [`Pipeline::params`] frees the parameters over the coarse levels. Both fit the
/// image-plane model (f, c, roll) at the coarsest levels, add rotation, translation and k1 at
/// the level before the finest and free everything at the finest; they differ in when the
/// translation is freed. On the 640×480 real-imagery trials neither is right for every rig:
/// a rig whose thermal camera sits 10–17 cm to the side ends 3–4 px off when the translation
/// stays fixed down to the 320-px level (the principal point absorbs the parallax), while on
/// night rigs with little shared structure a translation freed at 80 px wanders off. So
/// [`calibrate_default`] runs both up to the check level and goes on with the early one only
/// where it costs clearly less there (by more than [`RESTART_TIE`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Staging {
    /// Rotation, translation and k1 from the first level at least 80 px wide.
    Early,
    /// Rotation, translation and k1 only from the level before the finest.
    Late,
}

/// The parameters [`Staging`] frees at a level `above_finest` levels above the finest one
/// and `width` px wide: the image-plane model (f, c, roll), that plus rotation, translation
/// and k1, or everything.
pub fn staged_params(staging: Staging, above_finest: usize, width: usize) -> Vec<usize> {
    let image_plane = vec![0, 1, 2, 3, 13];
    let middle = vec![0, 1, 2, 3, 4, 8, 9, 10, 11, 12, 13];
    match (above_finest, staging) {
        (0, _) => (0..NUM_PARAMS).collect(),
        (1, _) => middle,
        (_, Staging::Early) if width >= 80 => middle,
        _ => image_plane,
    }
}

/// Result of [`Pipeline::refine`].
pub struct Refined {
    pub theta: [f64; NUM_PARAMS],
    /// Final cost (data + priors) at the last level run.
    pub cost: f64,
    pub iterations: usize,
    /// The level factor where the loss became non-finite, if it did.
    pub non_finite: Option<usize>,
}

impl<'a> Pipeline<'a> {
    pub fn new(
        rig: &'a Rig,
        used: Vec<&'a Frame>,
        p0: [f64; NUM_PARAMS],
        settings: &Settings,
    ) -> Self {
        let samples = depth_samples(&used);
        let scaling = Scaling {
            p0,
            scale: model::pixel_scales(&rig.rgb, &p0, &samples),
        };
        let factors = pyramid_factors(rig.rgb.width);
        let levels = factors
            .iter()
            .enumerate()
            .map(|(li, &factor)| {
                // A wide blur only where the basin must be wide (the coarsest level, after the
                // shift search); finer levels use the features unblurred, since blur lets edges
                // present in one band only pull on shared edges (σ = 1 / 0.6 / 0 at full and
                // half resolution: 0.32 / 0.22 / 0.18 px mean map error on a 160×120 rig).
                let (sigma, taps) = if li == 0 { (2.0, 13) } else { (0.0, 1) };
                let level = Level::build(&rig.rgb, &used, factor, false, sigma, taps);
                // Levels larger than MAX_LEVEL_PIXELS use a random subset of that many pixels
                // per frame, at full feature resolution.
                if li > 0 && (level.h * level.w) as usize > MAX_LEVEL_PIXELS {
                    level.subsample(MAX_LEVEL_PIXELS, settings.seed ^ factor as u64)
                } else {
                    level
                }
            })
            .collect();
        Self {
            rig,
            used,
            scaling,
            square: rig.thermal.square_pixels.unwrap_or(true),
            factors,
            levels,
            iterations: settings.iterations,
            lambda0: 1e-5 / settings.learning_rate,
            samples,
            staging: Staging::Late,
        }
    }

    /// Mean distance (full-resolution thermal px) between the RGB→thermal maps of θ `a` and
    /// `b` over the sample pixels that `a` maps into the thermal image.
    pub fn distance(&self, a: &[f64; NUM_PARAMS], b: &[f64; NUM_PARAMS]) -> f64 {
        let (ca, cb) = (self.scaling.calibration(a), self.scaling.calibration(b));
        let (tw, th) = (
            self.rig.thermal.width as f64,
            self.rig.thermal.height as f64,
        );
        let (mut sum, mut n) = (0.0, 0usize);
        for &(u, v, d) in &self.samples {
            let Some((au, av)) = ca.map_pixel(&self.rig.rgb, u, v, d) else {
                continue;
            };
            if au < -0.5 || av < -0.5 || au > tw - 0.5 || av > th - 0.5 {
                continue;
            }
            sum += match cb.map_pixel(&self.rig.rgb, u, v, d) {
                Some((bu, bv)) => ((au - bu).powi(2) + (av - bv).powi(2)).sqrt(),
                None => tw,
            };
            n += 1;
        }
        if n == 0 {
            f64::INFINITY
        } else {
            sum / n as f64
        }
    }

    /// Index of the finest level at most `RESTART_MAX_WIDTH` px wide (where restarts run;
    /// the quality assessment uses the level ≤ 320 px wide).
    pub fn check_level(&self) -> usize {
        (0..self.levels.len())
            .filter(|&li| self.rig.rgb.width / self.factors[li] <= RESTART_MAX_WIDTH)
            .max()
            .unwrap_or(0)
    }

    /// Cost at level `li` (data + priors at a fixed weight), comparable between solutions.
    fn total_cost(&self, li: usize, theta: &[f64; NUM_PARAMS], priors: &Priors) -> f64 {
        let idx = Tensor::from_slice(&self.all());
        cost(&self.levels[li], &self.scaling, theta, &idx) + priors.cost(&self.scaling, theta)
    }

    /// The wrong-basin check (issue 12). On real imagery most edges exist in one band only and
    /// the objective has several optima a few pixels apart; the main run can stop in one that
    /// is not the best (on the 160×120 real-imagery trials, seeds 3 and 12 ended 2–3 px off
    /// with every other quality figure as good as a success). So the solution is perturbed by
    /// ±`RESTART_FRACTION` of the thermal width in cx, cy and f and each start refined again
    /// at the two levels up to [`Pipeline::check_level`] (plus one restart from the solution
    /// itself); the best-scoring solution wins (never the truth: the objective decides) and,
    /// if it is not the main run's, a second round restarts around it, then it is refined at
    /// the finer levels. Returns the chosen θ and the figures the verdict reads: how far the
    /// restarts moved the solution and how far apart solutions of about the same cost lie.
    pub fn restart(
        &self,
        main: [f64; NUM_PARAMS],
        on_iteration: &mut dyn FnMut(usize, f64),
    ) -> ([f64; NUM_PARAMS], Restarts) {
        let q = self.check_level();
        let from = q.saturating_sub(1);
        let delta = RESTART_FRACTION * self.rig.thermal.width as f64;
        let mut priors = Priors::new(self.rig);
        let all_dirs = directions(
            &(0..NUM_PARAMS).collect::<Vec<_>>(),
            &self.scaling,
            self.square,
        );
        let (jtj, _, _) = normal_equations(
            &self.levels[q],
            &self.scaling,
            &main,
            &all_dirs,
            &self.all(),
        );
        priors.weight =
            ((0..jtj.len()).map(|i| jtj[i][i]).sum::<f64>() / jtj.len() as f64).max(1e-12);
        let focal = directions(&[0, 1], &self.scaling, self.square)[0];
        let axis =
            |i: usize| -> [f64; NUM_PARAMS] { std::array::from_fn(|k| (k == i) as u8 as f64) };
        let perturbations = [axis(2), axis(3), focal];
        let main_cost = self.total_cost(q, &main, &priors);
        // (θ, cost at level q, refined at level q?)
        let mut solutions: Vec<([f64; NUM_PARAMS], f64)> = Vec::new();
        let continued = self.refine_between(main, q, q, on_iteration);
        let continued_cost = self.total_cost(q, &continued, &priors);
        solutions.push((continued, continued_cost));
        let mut best = (continued, continued_cost);
        let mut centre = continued;
        let mut rounds = 0;
        let mut settled = false;
        for _round in 0..RESTART_ROUNDS {
            rounds += 1;
            let before = best.1;
            let starts: Vec<[f64; NUM_PARAMS]> = perturbations
                .iter()
                .flat_map(|d| {
                    [-1.0, 1.0].map(|sign| -> [f64; NUM_PARAMS] {
                        std::array::from_fn(|i| centre[i] + sign * delta * d[i])
                    })
                })
                .collect();
            for (t, c) in self.refine_all(&starts, from, q, &priors, on_iteration) {
                solutions.push((t, c));
                if c < best.1 {
                    best = (t, c);
                }
            }
            // Another round only around a clearly better, distinct solution.
            if !(best.1 < before * (1.0 - RESTART_TIE)
                && self.distance(&best.0, &centre) > delta / 4.0)
            {
                settled = true;
                break;
            }
            centre = best.0;
        }
        let mut chosen = if best.0 == continued && q + 1 == self.levels.len() {
            continued
        } else if best.0 == continued {
            main
        } else {
            best.0
        };
        if chosen != main && q + 1 < self.levels.len() {
            chosen = self.refine_between(chosen, q + 1, self.levels.len() - 1, on_iteration);
        }
        let spread_px = solutions
            .iter()
            .filter(|(_, c)| *c <= best.1 * (1.0 + RESTART_TIE))
            .map(|(t, _)| self.distance(&best.0, t))
            .fold(0.0, f64::max);
        let summary = Restarts {
            count: solutions.len(),
            rounds,
            perturbation_px: delta,
            improved_px: self.distance(&main, &chosen),
            cost_drop: (main_cost - best.1) / main_cost.abs().max(1e-12),
            spread_px,
            settled,
        };
        (chosen, summary)
    }

    /// Refines each start over levels `from..=to` and scores it at level `to`, on up to
    /// `available_parallelism` OS threads (each with shallow copies of the levels, libtorch
    /// single-threaded in each; the restarts are independent, so the result does not depend
    /// on the thread count).
    fn refine_all(
        &self,
        starts: &[[f64; NUM_PARAMS]],
        from: usize,
        to: usize,
        priors: &Priors,
        on_iteration: &mut dyn FnMut(usize, f64),
    ) -> Vec<([f64; NUM_PARAMS], f64)> {
        let workers = std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .min(starts.len());
        if workers <= 1 {
            return starts
                .iter()
                .map(|s| {
                    let t = self.refine_between(*s, from, to, on_iteration);
                    (t, self.total_cost(to, &t, priors))
                })
                .collect();
        }
        let chunk = starts.len().div_ceil(workers);
        let copies: Vec<Pipeline> = (0..workers).map(|_| self.shallow()).collect();
        let mut out = std::thread::scope(|scope| {
            let handles: Vec<_> = copies
                .into_iter()
                .zip(starts.chunks(chunk))
                .map(|(pipe, part)| {
                    let priors = priors.clone();
                    scope.spawn(move || {
                        let _guard = tch::no_grad_guard();
                        part.iter()
                            .map(|s| {
                                let t = pipe.refine_between(*s, from, to, &mut |_, _| {});
                                (t, pipe.total_cost(to, &t, &priors))
                            })
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            handles
                .into_iter()
                .flat_map(|h| h.join().expect("restart thread panicked"))
                .collect::<Vec<_>>()
        });
        if let Some((_, c)) = out.last() {
            on_iteration(self.levels[to].factor, *c);
        }
        out.truncate(starts.len());
        out
    }

    /// A copy sharing the level tensors (for other threads).
    pub fn shallow(&self) -> Pipeline<'a> {
        Pipeline {
            rig: self.rig,
            used: self.used.clone(),
            scaling: Scaling {
                p0: self.scaling.p0,
                scale: self.scaling.scale,
            },
            square: self.square,
            factors: self.factors.clone(),
            levels: self.levels.iter().map(Level::shallow).collect(),
            iterations: self.iterations,
            lambda0: self.lambda0,
            samples: self.samples.clone(),
            staging: self.staging,
        }
    }

    /// [`Pipeline::refine`] over levels `from..=to` only.
    pub fn refine_between(
        &self,
        theta: [f64; NUM_PARAMS],
        from: usize,
        to: usize,
        on_iteration: &mut dyn FnMut(usize, f64),
    ) -> [f64; NUM_PARAMS] {
        self.refine_levels(theta, from, to + 1, on_iteration).theta
    }

    fn all(&self) -> Vec<i64> {
        (0..self.used.len() as i64).collect()
    }

    /// Exhaustive search at the coarsest level over an image shift (cx, cy) around `theta`:
    /// the largest, most non-convex part of the initial misalignment (rotation and
    /// principal-point offsets). Returns the `k` best shifts that are local minima of the
    /// search grid, best first, with their costs.
    pub fn search(&self, theta: [f64; NUM_PARAMS], k: usize) -> Vec<(f64, [f64; NUM_PARAMS])> {
        let level = &self.levels[0];
        let factor = level.factor;
        let idx = Tensor::from_slice(&self.all());
        let range = (0.1 * self.rig.thermal.width as f64 / factor as f64).ceil() as i64;
        let n = (2 * range + 1) as usize;
        let mut grid = vec![f64::INFINITY; n * n];
        for dy in -range..=range {
            for dx in -range..=range {
                let mut t = theta;
                t[2] += (dx * factor as i64) as f64;
                t[3] += (dy * factor as i64) as f64;
                grid[(dy + range) as usize * n + (dx + range) as usize] =
                    cost(level, &self.scaling, &t, &idx);
            }
        }
        let mut minima: Vec<(f64, [f64; NUM_PARAMS])> = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let c = grid[y * n + x];
                let is_min = (-1i64..=1).all(|ey| {
                    (-1i64..=1).all(|ex| {
                        let (yy, xx) = (y as i64 + ey, x as i64 + ex);
                        (ey == 0 && ex == 0)
                            || yy < 0
                            || xx < 0
                            || yy >= n as i64
                            || xx >= n as i64
                            || grid[yy as usize * n + xx as usize] >= c
                    })
                });
                if is_min && c.is_finite() {
                    let mut t = theta;
                    t[2] += ((x as i64 - range) * factor as i64) as f64;
                    t[3] += ((y as i64 - range) * factor as i64) as f64;
                    minima.push((c, t));
                }
            }
        }
        minima.sort_by(|a, b| a.0.total_cmp(&b.0));
        if minima.is_empty() {
            minima.push((cost(level, &self.scaling, &theta, &idx), theta));
        }
        minima.truncate(k.max(1));
        minima
    }

    /// Staged parameters of level `li` ([`Staging`]): at coarse levels pan/tilt are
    /// indistinguishable from the principal point and translation from both, and letting
    /// them drift along that valley leads to wrong minima; so the coarsest levels fit an
    /// image-plane model (f, c, roll), then rotation, translation and k1 are added, and the
    /// finest level frees everything.
    pub fn params(&self, li: usize) -> Vec<usize> {
        let (above_finest, width) = self.level_place(li);
        staged_params(self.staging, above_finest, width)
    }

    /// Level `li`'s place for [`staged_params`]: levels above the finest, width in px.
    fn level_place(&self, li: usize) -> (usize, usize) {
        (
            self.factors.len() - 1 - li,
            self.rig.rgb.width / self.factors[li],
        )
    }

    /// Whether the two stagings free the same parameters at every level up to `to`.
    fn stagings_agree(&self, to: usize) -> bool {
        (0..=to).all(|li| {
            let (above_finest, width) = self.level_place(li);
            staged_params(Staging::Early, above_finest, width)
                == staged_params(Staging::Late, above_finest, width)
        })
    }

    /// Levenberg-Marquardt from `theta` at levels `from..` (coarse to fine).
    pub fn refine(
        &self,
        theta: [f64; NUM_PARAMS],
        from: usize,
        on_iteration: &mut dyn FnMut(usize, f64),
    ) -> Refined {
        self.refine_levels(theta, from, self.levels.len(), on_iteration)
    }

    fn refine_levels(
        &self,
        mut theta: [f64; NUM_PARAMS],
        from: usize,
        to: usize,
        on_iteration: &mut dyn FnMut(usize, f64),
    ) -> Refined {
        let all = self.all();
        let mut out = Refined {
            theta,
            cost: f64::NAN,
            iterations: 0,
            non_finite: None,
        };
        for li in from..to {
            let level = &self.levels[li];
            let dirs = directions(&self.params(li), &self.scaling, self.square);
            let mut priors = Priors::new(self.rig);
            let run = lm_level(
                level,
                &self.scaling,
                &mut priors,
                theta,
                &dirs,
                &all,
                self.iterations,
                self.lambda0,
                &mut |loss| on_iteration(level.factor, loss),
            );
            theta = run.theta;
            out.theta = theta;
            out.cost = run.cost;
            out.iterations += run.iterations;
            if run.non_finite {
                out.non_finite = Some(level.factor);
                break;
            }
        }
        out
    }
}

/// Pixels per frame of a level at most (half of 320×240; larger levels, from 320×240 up, use
/// a random subset: at 640×480 one normal-equation evaluation of 20 frames took 28.5 s at
/// full resolution and 3.0 s on a 76800-pixel subset, load ≈ 5 on 2 cores).
pub const MAX_LEVEL_PIXELS: usize = 160 * 240;
/// Restarts run at the finest level at most this wide (and the level before it), then the
/// chosen solution is refined at the finer levels: at 640×480 restarts at the 320-wide level
/// would cost several times the main run.
pub const RESTART_MAX_WIDTH: usize = 160;
/// Restart perturbation, as a fraction of the thermal width (3.2 px at 160 px wide).
pub const RESTART_FRACTION: f64 = 0.02;
/// Restart rounds at most (a round: 6 perturbed starts around the best solution so far).
pub const RESTART_ROUNDS: usize = 2;
/// Relative cost difference below which two solutions score "about the same".
pub const RESTART_TIE: f64 = 0.002;

/// RGB pixels with depth (u, v, z-depth), ~400 per frame.
fn depth_samples(frames: &[&Frame]) -> Vec<(f64, f64, f64)> {
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

fn calibrate_default(
    rig: &Rig,
    frames: &[Frame],
    settings: &Settings,
    p0: [f64; NUM_PARAMS],
    rng: &mut ChaCha8Rng,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Solution> {
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.shuffle(rng);
    order.truncate(settings.batch_size.min(frames.len()));
    order.sort();
    let used: Vec<&Frame> = order.iter().map(|&i| &frames[i]).collect();
    let mut pipe = Pipeline::new(rig, used, p0, settings);
    // Both stagings up to the check level where they differ ([`Staging`]).
    let q = pipe.check_level();
    let both = !pipe.stagings_agree(q);
    let total = (pipe.factors.len() + if both { q + 1 } else { 0 }) * settings.iterations + 1;
    let mut step = 0;
    let (best, start) = pipe.search([0.0; NUM_PARAMS], 1)[0];
    step += 1;
    progress(&Progress {
        stage: format!("search 1/{}", pipe.factors[0]),
        step,
        total,
        loss: best,
    });
    let mut on_level = |factor: usize, loss: f64| {
        step += 1;
        progress(&Progress {
            stage: format!("level 1/{factor}"),
            step,
            total,
            loss,
        });
    };
    let mut coarse = pipe.refine_levels(start, 0, q + 1, &mut on_level);
    if coarse.non_finite.is_none() && both {
        pipe.staging = Staging::Early;
        let early = pipe.refine_levels(start, 0, q + 1, &mut on_level);
        let all = Tensor::from_slice(&pipe.all());
        let cost_at_q = |t: &[f64; NUM_PARAMS]| cost(&pipe.levels[q], &pipe.scaling, t, &all);
        // Early only where the data clearly favour it; on a tie, the more constrained
        // schedule.
        if early.non_finite.is_none()
            && cost_at_q(&early.theta) < cost_at_q(&coarse.theta) * (1.0 - RESTART_TIE)
        {
            coarse = early;
        } else {
            pipe.staging = Staging::Late;
        }
    }
    let run = if coarse.non_finite.is_some() || q + 1 == pipe.levels.len() {
        coarse
    } else {
        let fine = pipe.refine(coarse.theta, q + 1, &mut on_level);
        Refined {
            iterations: coarse.iterations + fine.iterations,
            ..fine
        }
    };
    let stopped = run
        .non_finite
        .map(|factor| format!("non-finite loss at level 1/{factor}; keeping the best parameters"));
    let (theta, restarts) = if stopped.is_none() {
        let (t, r) = pipe.restart(run.theta, &mut |factor, loss| {
            progress(&Progress {
                stage: format!("restarts 1/{factor}"),
                step,
                total,
                loss,
            });
        });
        (t, Some(r))
    } else {
        (run.theta, None)
    };
    let idx = Tensor::from_slice(&pipe.all());
    let loss = cost(pipe.levels.last().unwrap(), &pipe.scaling, &theta, &idx);
    progress(&Progress {
        stage: "done".into(),
        step: total,
        total,
        loss,
    });
    Ok(Solution {
        initial: model::to_calibration(&p0),
        calibration: pipe.scaling.calibration(&theta),
        restarts,
        loss,
        frames_used: pipe.used.len(),
        iterations: run.iterations,
        stopped,
        used: order,
    })
}

fn calibrate_paper(
    rig: &Rig,
    frames: &[Frame],
    settings: &Settings,
    p0: [f64; NUM_PARAMS],
    rng: &mut ChaCha8Rng,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Solution> {
    // 600 random pairs (all of them if fewer).
    let mut pool: Vec<usize> = (0..frames.len()).collect();
    pool.shuffle(rng);
    pool.truncate(600);
    let used: Vec<&Frame> = pool.iter().map(|&i| &frames[i]).collect();
    let scaling = Scaling::new(&rig.rgb, p0, &used);
    // Tensors are built per batch: 600 full-resolution frames would not fit in memory.
    let build = |frames: &[&Frame]| Level::build(&rig.rgb, frames, 1, true, 3.0, 51);
    let mut theta =
        Tensor::zeros([NUM_PARAMS as i64], (Kind::Float, Device::Cpu)).set_requires_grad(true);
    let p0_t = Tensor::from_slice(&p0.map(|x| x as f32));
    let scale_t = Tensor::from_slice(&scaling.scale.map(|x| x as f32));
    let (beta1, beta2, eps) = (0.9f64, 0.999f64, 1e-8f64);
    let mut m = Tensor::zeros([NUM_PARAMS as i64], (Kind::Float, Device::Cpu));
    let mut v = m.zeros_like();
    let mut best: (f64, Vec<f32>) = (f64::INFINITY, vec![0.0; NUM_PARAMS]);
    let mut stopped = None;
    let mut smoothed = f64::NAN;
    let mut iterations = 0;
    let batch = settings.batch_size.min(used.len());
    for it in 0..settings.iterations {
        let lr = settings.learning_rate * 0.5f64.powi((it / 500) as i32);
        let mut pick: Vec<i64> = (0..used.len() as i64).collect();
        pick.shuffle(rng);
        pick.truncate(batch);
        let batch_frames: Vec<&Frame> = pick.iter().map(|&i| used[i as usize]).collect();
        let level = build(&batch_frames);
        let idx = Tensor::arange(batch_frames.len() as i64, (Kind::Int64, Device::Cpu));
        let loss = tch::with_grad(|| {
            let p = &p0_t + &scale_t * &theta;
            let r = level.residual(&p, &idx);
            let loss = r.square().sum(Kind::Float) / level.support(&idx);
            loss.backward();
            loss.double_value(&[])
        });
        iterations += 1;
        let grad = theta.grad();
        let grad_ok = grad.isfinite().all().int64_value(&[]) == 1;
        if !loss.is_finite() || !grad_ok {
            stopped = Some(format!(
                "non-finite loss or gradient at iteration {it}; keeping the best parameters"
            ));
            break;
        }
        smoothed = if smoothed.is_nan() {
            loss
        } else {
            0.95 * smoothed + 0.05 * loss
        };
        // Divergence: parameters far beyond any plausible misalignment (θ is in pixels), or a
        // smoothed loss well above the best seen (a diverged warp often plateaus instead, so
        // the parameter test is the one that usually fires).
        let runaway = theta.abs().max().double_value(&[]) > 10.0 * rig.thermal.width as f64;
        if runaway || (it > 50 && smoothed > 3.0 * best.0.max(1e-12)) {
            stopped = Some(format!(
                "diverged at iteration {it}; keeping the best parameters"
            ));
            break;
        }
        if smoothed < best.0 {
            best = (smoothed, Vec::try_from(&theta.detach()).unwrap());
        }
        let t = (it + 1) as i32;
        m = &m * beta1 + &grad * (1.0 - beta1);
        v = &v * beta2 + grad.square() * (1.0 - beta2);
        let m_hat = &m / (1.0 - beta1.powi(t));
        let v_hat = &v / (1.0 - beta2.powi(t));
        let update = m_hat / (v_hat.sqrt() + eps) * lr;
        tch::no_grad(|| {
            let _ = theta.f_sub_(&update);
        });
        let _ = theta.grad().zero_();
        progress(&Progress {
            stage: "paper".into(),
            step: it + 1,
            total: settings.iterations,
            loss,
        });
    }
    let final_theta: [f64; NUM_PARAMS] = if stopped.is_some() {
        std::array::from_fn(|i| best.1[i] as f64)
    } else {
        let t: Vec<f32> = Vec::try_from(&theta.detach()).unwrap();
        std::array::from_fn(|i| t[i] as f64)
    };
    // Final loss over (up to) the first 20 pairs, frame by frame.
    let (mut sq, mut support) = (0.0, 0.0);
    for frame in used.iter().take(20) {
        let level = build(&[*frame]);
        let idx = Tensor::from_slice(&[0i64]);
        let n = level.support(&idx);
        sq += cost(&level, &scaling, &final_theta, &idx) * n;
        support += n;
    }
    let final_loss = sq / support.max(1.0);
    Ok(Solution {
        initial: model::to_calibration(&p0),
        calibration: scaling.calibration(&final_theta),
        loss: final_loss,
        frames_used: used.len(),
        used: pool.clone(),
        restarts: None,
        iterations,
        stopped,
    })
}

/// Mean RGB→thermal pixel-map error (thermal px) of `estimate` vs `truth` over `frames`' depth.
pub fn mean_map_error(
    rig: &Rig,
    frames: &[Frame],
    estimate: &Calibration,
    truth: &Calibration,
) -> f64 {
    let (mut sum, mut n) = (0.0, 0);
    for f in frames {
        let (s, c) = crate::camera::pixel_map_error(
            &rig.rgb,
            &f.depth.data,
            (rig.thermal.width, rig.thermal.height),
            estimate,
            truth,
        );
        sum += s;
        n += c;
    }
    sum / n.max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::load_frames;
    use crate::synth_rig::{write_rig, DepthSource, RigSynthConfig};

    #[test]
    fn stagings_differ_only_where_a_level_of_80_px_lies_above_the_last_two() {
        let widths = |w: usize| -> Vec<(usize, usize)> {
            let f = pyramid_factors(w);
            (0..f.len())
                .map(|li| (f.len() - 1 - li, w / f[li]))
                .collect()
        };
        let plan = |s: Staging, w: usize| -> Vec<usize> {
            widths(w)
                .into_iter()
                .map(|(above, width)| staged_params(s, above, width).len())
                .collect()
        };
        // 160 px wide (40, 80, 160): one schedule, so calibrate_default runs it once.
        assert_eq!(plan(Staging::Late, 160), plan(Staging::Early, 160));
        assert_eq!(plan(Staging::Late, 160), vec![5, 11, NUM_PARAMS]);
        // 640 px wide (40, 80, 160, 320, 640): the early staging frees the translation and
        // k1 at 80 and 160 px, the late one only at 320.
        assert_eq!(plan(Staging::Late, 640), vec![5, 5, 5, 11, NUM_PARAMS]);
        assert_eq!(plan(Staging::Early, 640), vec![5, 11, 11, 11, NUM_PARAMS]);
        for (above, width) in widths(640) {
            let (early, late) = (
                staged_params(Staging::Early, above, width),
                staged_params(Staging::Late, above, width),
            );
            // Focal length, principal point and roll are free everywhere; translation
            // (8..=10) never in the image-plane model.
            assert!([0, 1, 2, 3, 13]
                .iter()
                .all(|p| early.contains(p) && late.contains(p)));
            assert_eq!(late.contains(&8), above <= 1);
        }
    }

    #[test]
    fn structure_tensor_normal_equations_match_the_full_jacobian() {
        tch::set_num_threads(1);
        let dir = tempfile::tempdir().unwrap();
        let cfg = RigSynthConfig {
            width: 64,
            height: 48,
            frames: 2,
            depth: DepthSource::Given,
            seed: 5,
            ..Default::default()
        };
        let synth = write_rig(dir.path(), &cfg).unwrap();
        let frames = load_frames(&synth.rig, &mut |_| {}).unwrap();
        let used: Vec<&Frame> = frames.iter().collect();
        let scaling = Scaling::new(&synth.rig.rgb, initial_params(&synth.rig), &used);
        let dirs = directions(&(0..NUM_PARAMS).collect::<Vec<_>>(), &scaling, false);
        let theta: [f64; NUM_PARAMS] = std::array::from_fn(|i| 0.3 * (i as f64 - 6.0));
        let fast = Level::build(&synth.rig.rgb, &used, 1, false, 0.0, 1);
        // A robust scale far above any residual: the general path, the same squares.
        let mut general = Level::build(&synth.rig.rgb, &used, 1, false, 0.0, 1);
        general.robust = 1e6;
        let (a1, b1, c1) = normal_equations(&fast, &scaling, &theta, &dirs, &[0, 1]);
        let (a2, b2, c2) = normal_equations(&general, &scaling, &theta, &dirs, &[0, 1]);
        assert!((c1 - c2).abs() <= 1e-6 * c2.abs(), "{c1} vs {c2}");
        let scale = a2.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
        for (r1, r2) in a1.iter().zip(&a2) {
            for (x, y) in r1.iter().zip(r2) {
                assert!((x - y).abs() <= 1e-4 * scale, "JᵀJ {x} vs {y}");
            }
        }
        let scale = b2.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        for (x, y) in b1.iter().zip(&b2) {
            assert!((x - y).abs() <= 1e-4 * scale, "Jᵀr {x} vs {y}");
        }
    }

    #[test]
    fn subsampled_level_keeps_the_cost_of_its_pixels() {
        tch::set_num_threads(1);
        let dir = tempfile::tempdir().unwrap();
        let cfg = RigSynthConfig {
            width: 64,
            height: 48,
            frames: 2,
            depth: DepthSource::Given,
            seed: 5,
            ..Default::default()
        };
        let synth = write_rig(dir.path(), &cfg).unwrap();
        let frames = load_frames(&synth.rig, &mut |_| {}).unwrap();
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

    #[test]
    fn paper_recipe_runs_and_runaway_steps_stop_with_best_parameters() {
        tch::set_num_threads(1);
        let dir = tempfile::tempdir().unwrap();
        let synth = write_rig(
            dir.path(),
            &RigSynthConfig {
                width: 64,
                height: 48,
                frames: 3,
                depth: DepthSource::Given,
                seed: 3,
                ..Default::default()
            },
        )
        .unwrap();
        let frames = load_frames(&synth.rig, &mut |_| {}).unwrap();
        let sane = Settings::resolve(
            Recipe::Paper,
            OptimizerOverrides {
                iterations: Some(20),
                batch_size: Some(2),
                learning_rate: Some(0.05),
            },
            None,
            0,
        )
        .unwrap();
        let mut losses = Vec::new();
        let out = solve(&synth.rig, &frames, &sane, &mut |p| losses.push(p.loss)).unwrap();
        assert_eq!((out.iterations, losses.len()), (20, 20));
        assert!(out.loss.is_finite() && out.stopped.is_none());
        // Absurd steps: the loss runs away; the optimiser must stop and keep finite, best params.
        let wild = Settings {
            learning_rate: 1e4,
            iterations: 300,
            ..sane
        };
        let out = solve(&synth.rig, &frames, &wild, &mut |_| {}).unwrap();
        assert!(out.stopped.is_some(), "runaway not detected");
        let p = model::from_calibration(&out.calibration);
        assert!(p.iter().all(|x| x.is_finite()), "{p:?}");
    }

    #[test]
    fn settings_follow_flags_then_file_then_recipe() {
        let file = OptimizerOverrides {
            iterations: Some(5),
            batch_size: Some(3),
            learning_rate: None,
        };
        let flags = OptimizerOverrides {
            batch_size: Some(7),
            ..Default::default()
        };
        let s = Settings::resolve(Recipe::Paper, flags, Some(file), 9).unwrap();
        assert_eq!(
            (s.iterations, s.batch_size, s.learning_rate, s.seed),
            (5, 7, 0.1, 9)
        );
        assert!(Settings::resolve(
            Recipe::Default,
            OptimizerOverrides {
                learning_rate: Some(-1.0),
                ..Default::default()
            },
            None,
            0
        )
        .is_err());
    }
}
