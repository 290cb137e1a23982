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
pub struct Outcome {
    pub initial: Calibration,
    pub calibration: Calibration,
    /// Final loss of the finest stage (mean squared blurred residual).
    pub loss: f64,
    pub frames_used: usize,
    pub iterations: usize,
    /// Why the optimiser stopped early (NaN, divergence), if it did; the best parameters are kept.
    pub stopped: Option<String>,
}

/// Eq. 8 initial parameters: K_T from f_m / l and the image centre, everything else 1e-4.
pub fn initial_params(rig: &Rig) -> [f64; NUM_PARAMS] {
    let k = rig.nominal_thermal();
    let mut p = [1e-4; NUM_PARAMS];
    p[0] = k.fx;
    p[1] = k.fy;
    p[2] = k.cx;
    p[3] = k.cy;
    p
}

/// One pyramid level (or the paper's single full-resolution level) of all frames, as tensors.
pub(crate) struct Level {
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
pub(crate) struct Scaling {
    pub p0: [f64; NUM_PARAMS],
    pub scale: [f64; NUM_PARAMS],
}

impl Scaling {
    pub fn new(rgb: &RgbCamera, p0: [f64; NUM_PARAMS], frames: &[&Frame]) -> Self {
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
        Self {
            p0,
            scale: model::pixel_scales(rgb, &p0, &samples),
        }
    }

    pub fn physical(&self, theta: &[f64; NUM_PARAMS]) -> [f64; NUM_PARAMS] {
        std::array::from_fn(|i| self.p0[i] + self.scale[i] * theta[i])
    }

    pub fn tensor(&self, theta: &[f64; NUM_PARAMS]) -> Tensor {
        Tensor::from_slice(&self.physical(theta).map(|x| x as f32))
    }
}

fn pyramid_factors(width: usize) -> Vec<usize> {
    let mut factors = vec![1];
    while width / (factors.last().unwrap() * 2) >= 40 && factors.len() < 6 {
        factors.push(factors.last().unwrap() * 2);
    }
    factors.reverse();
    factors
}

/// Calibrates from loaded frames.
pub fn calibrate(
    rig: &Rig,
    frames: &[Frame],
    settings: &Settings,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Outcome> {
    let _guard = tch::no_grad_guard();
    let p0 = initial_params(rig);
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    match settings.recipe {
        Recipe::Default => calibrate_default(rig, frames, settings, p0, &mut rng, progress),
        Recipe::Paper => calibrate_paper(rig, frames, settings, p0, &mut rng, progress),
    }
}

fn cost(level: &Level, scaling: &Scaling, theta: &[f64; NUM_PARAMS], idx: &Tensor) -> f64 {
    let r = level.residual(&scaling.tensor(theta), idx);
    r.square().sum(Kind::Double).double_value(&[]) / level.support(idx)
}

fn solve(
    a: &[[f64; NUM_PARAMS]; NUM_PARAMS],
    b: &[f64; NUM_PARAMS],
    active: &[usize],
) -> Option<[f64; NUM_PARAMS]> {
    // Cholesky on the active sub-system.
    let n = active.len();
    let mut l = vec![vec![0.0; n]; n];
    for i in 0..n {
        for j in 0..=i {
            let mut s = a[active[i]][active[j]];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
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
        y[i] = (b[active[i]] - (0..i).map(|k| l[i][k] * y[k]).sum::<f64>()) / l[i][i];
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        x[i] = (y[i] - (i + 1..n).map(|k| l[k][i] * x[k]).sum::<f64>()) / l[i][i];
    }
    let mut out = [0.0; NUM_PARAMS];
    for (i, &p) in active.iter().enumerate() {
        out[p] = x[i];
    }
    Some(out)
}

/// JᵀJ, Jᵀr and the cost at θ (Gauss-Newton, Lucas-Kanade style): ∂r/∂θ_i =
/// −G * (M · (∂F_T/∂u · ∂u/∂θ_i + ∂F_T/∂v · ∂v/∂θ_i)), with the feature gradients warped
/// alongside the features and ∂(u, v)/∂θ from finite differences of the (smooth) projection.
fn normal_equations(
    level: &Level,
    scaling: &Scaling,
    theta: &[f64; NUM_PARAMS],
    active: &[usize],
    frames: &[i64],
) -> ([[f64; NUM_PARAMS]; NUM_PARAMS], [f64; NUM_PARAMS], f64) {
    let mut jtj = [[0.0; NUM_PARAMS]; NUM_PARAMS];
    let mut jtr = [0.0; NUM_PARAMS];
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
        sq += r0.square().sum(Kind::Double).double_value(&[]);
        let hw = [1, 1, level.h, level.w];
        let cols: Vec<Tensor> = active
            .iter()
            .map(|&i| {
                let mut t = *theta;
                t[i] += hstep;
                let (u1, v1) = model::project(&pts, &scaling.tensor(&t));
                let du = ((u1 - &u0) * (inv_f / hstep)).view(hw);
                let dv = ((v1 - &v0) * (inv_f / hstep)).view(hw);
                (-blur(&((&du_feat * du + &dv_feat * dv) * &mask)))
                    .flatten(0, -1)
                    .to_kind(Kind::Double)
            })
            .collect();
        let j = Tensor::stack(&cols, 1); // [N, n_active]
        let jtj_t: Vec<f64> = Vec::try_from(j.tr().matmul(&j).flatten(0, -1)).unwrap();
        let jtr_t: Vec<f64> = Vec::try_from(j.tr().matmul(&r0)).unwrap();
        let n = active.len();
        for a in 0..n {
            jtr[active[a]] += jtr_t[a];
            for b in 0..n {
                jtj[active[a]][active[b]] += jtj_t[a * n + b];
            }
        }
    }
    (jtj, jtr, sq / support.max(1.0))
}

fn calibrate_default(
    rig: &Rig,
    frames: &[Frame],
    settings: &Settings,
    p0: [f64; NUM_PARAMS],
    rng: &mut ChaCha8Rng,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Outcome> {
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.shuffle(rng);
    order.truncate(settings.batch_size.min(frames.len()));
    order.sort();
    let used: Vec<&Frame> = order.iter().map(|&i| &frames[i]).collect();
    let scaling = Scaling::new(&rig.rgb, p0, &used);
    let factors = pyramid_factors(rig.rgb.width);
    let total = factors.len() * settings.iterations + 1;
    let mut step = 0;
    let mut theta = [0.0; NUM_PARAMS];
    let all: Vec<i64> = (0..used.len() as i64).collect();
    let all_idx = Tensor::from_slice(&all);
    let mut final_loss = f64::NAN;
    let mut stopped = None;
    let mut iterations = 0;
    for (li, &factor) in factors.iter().enumerate() {
        let coarsest = li == 0;
        // A wide blur only where the basin must be wide (the coarsest level, after the shift
        // search); finer levels use the features unblurred, since blur lets edges present in
        // one band only pull on shared edges (σ = 1 / 0.6 / 0 at full and half resolution:
        // 0.32 / 0.22 / 0.18 px mean map error on a 160×120 rig).
        let (sigma, taps) = if coarsest { (2.0, 13) } else { (0.0, 1) };
        let level = Level::build(&rig.rgb, &used, factor, false, sigma, taps);
        if coarsest {
            // Exhaustive search over an image shift (cx, cy): the largest, most non-convex
            // part of the initial misalignment (rotation and principal-point offsets).
            let range = (0.1 * rig.thermal.width as f64 / factor as f64).ceil() as i64;
            let mut best = (cost(&level, &scaling, &theta, &all_idx), theta);
            for dy in -range..=range {
                for dx in -range..=range {
                    let mut t = theta;
                    t[2] += (dx * factor as i64) as f64;
                    t[3] += (dy * factor as i64) as f64;
                    let c = cost(&level, &scaling, &t, &all_idx);
                    if c < best.0 {
                        best = (c, t);
                    }
                }
            }
            theta = best.1;
            step += 1;
            progress(&Progress {
                stage: format!("search 1/{}", factor),
                step,
                total,
                loss: best.0,
            });
        }
        // Staged parameters: at coarse levels pan/tilt are indistinguishable from the principal
        // point and translation from both, and letting them drift along that valley leads
        // to wrong minima; so the coarsest levels fit an image-plane model (f, c, roll), the
        // next adds rotation, translation and k1, the finest everything.
        let active: Vec<usize> = match factors.len() - 1 - li {
            0 => (0..NUM_PARAMS).collect(),
            1 => vec![0, 1, 2, 3, 4, 8, 9, 10, 11, 12, 13],
            _ => vec![0, 1, 2, 3, 13],
        };
        // Trust region: at most 2 full-resolution pixels per iteration and level factor.
        let max_step = 2.0 * factor as f64;
        let mut lambda = 1e-5 / settings.learning_rate;
        let mut current = f64::NAN;
        for _ in 0..settings.iterations {
            let (jtj, jtr, c) = normal_equations(&level, &scaling, &theta, &active, &all);
            iterations += 1;
            step += 1;
            if !c.is_finite() {
                stopped = Some(format!(
                    "non-finite loss at level 1/{factor}; keeping the best parameters"
                ));
                break;
            }
            current = c;
            let mut accepted = false;
            let mut small = false;
            while lambda < 1e8 {
                let mut a = jtj;
                // Levenberg damping λ·mean(diag)·I: the units are commensurate (pixels), and
                // unlike Marquardt's diag scaling it resists drift along flat valleys.
                let mean_diag =
                    active.iter().map(|&i| jtj[i][i]).sum::<f64>() / active.len() as f64;
                for &i in &active {
                    a[i][i] += lambda * mean_diag.max(1e-12) + 1e-12;
                }
                let rhs = jtr.map(|x| -x);
                let Some(mut delta) = solve(&a, &rhs, &active) else {
                    lambda *= 10.0;
                    continue;
                };
                let biggest = delta.iter().fold(0.0f64, |m, d| m.max(d.abs()));
                if biggest > max_step {
                    delta = delta.map(|d| d * max_step / biggest);
                }
                small = biggest < 1e-3 * factor as f64;
                let trial: [f64; NUM_PARAMS] = std::array::from_fn(|i| theta[i] + delta[i]);
                let tc = cost(&level, &scaling, &trial, &all_idx);
                if tc.is_finite() && tc < current {
                    theta = trial;
                    current = tc;
                    lambda = (lambda / 3.0).max(1e-7);
                    accepted = true;
                    break;
                }
                lambda *= 4.0;
            }
            progress(&Progress {
                stage: format!("level 1/{factor}"),
                step,
                total,
                loss: current,
            });
            if !accepted || small {
                break;
            }
        }
        final_loss = current;
        if stopped.is_some() {
            break;
        }
    }
    progress(&Progress {
        stage: "done".into(),
        step: total,
        total,
        loss: final_loss,
    });
    Ok(Outcome {
        initial: model::to_calibration(&p0),
        calibration: model::to_calibration(&scaling.physical(&theta)),
        loss: final_loss,
        frames_used: used.len(),
        iterations,
        stopped,
    })
}

fn calibrate_paper(
    rig: &Rig,
    frames: &[Frame],
    settings: &Settings,
    p0: [f64; NUM_PARAMS],
    rng: &mut ChaCha8Rng,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Outcome> {
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
    Ok(Outcome {
        initial: model::to_calibration(&p0),
        calibration: model::to_calibration(&scaling.physical(&final_theta)),
        loss: final_loss,
        frames_used: used.len(),
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

    fn run_rig(cfg: &RigSynthConfig, settings: &Settings) -> (f64, f64, f64, Outcome) {
        let dir = tempfile::tempdir().unwrap();
        let synth = write_rig(dir.path(), cfg).unwrap();
        let rig = Rig::load(&synth.rig_path).unwrap();
        let frames = load_frames(&rig, &mut |w| eprintln!("{w}")).unwrap();
        let start = std::time::Instant::now();
        let t0 = std::time::Instant::now();
        let out = calibrate(&rig, &frames, settings, &mut |p| {
            if std::env::var_os("RTF_CALIB_DEBUG").is_some() {
                eprintln!(
                    "{:>7.2}s {} {}/{} loss {:.6}",
                    t0.elapsed().as_secs_f64(),
                    p.stage,
                    p.step,
                    p.total,
                    p.loss
                )
            }
        })
        .unwrap();
        eprintln!(
            "calibrate took {:.2}s, {} iterations",
            start.elapsed().as_secs_f64(),
            out.iterations
        );
        // Evaluate against the rendered (true) depth.
        let truth_dir = tempfile::tempdir().unwrap();
        let truth_rig = write_rig(
            truth_dir.path(),
            &RigSynthConfig {
                depth: DepthSource::Given,
                ..cfg.clone()
            },
        )
        .unwrap();
        let truth_frames =
            load_frames(&Rig::load(&truth_rig.rig_path).unwrap(), &mut |_| {}).unwrap();
        if std::env::var_os("RTF_CALIB_DEBUG").is_some() {
            let used: Vec<&Frame> = frames.iter().collect();
            let scaling = Scaling::new(&rig.rgb, initial_params(&rig), &used);
            let pt = model::from_calibration(&synth.truth);
            let pe = model::from_calibration(&out.calibration);
            let tt: [f64; NUM_PARAMS] =
                std::array::from_fn(|i| (pt[i] - scaling.p0[i]) / scaling.scale[i]);
            let te: [f64; NUM_PARAMS] =
                std::array::from_fn(|i| (pe[i] - scaling.p0[i]) / scaling.scale[i]);
            let all = Tensor::from_slice(&(0..used.len() as i64).collect::<Vec<_>>());
            for factor in pyramid_factors(rig.rgb.width) {
                let sigma = 1.0;
                let level = Level::build(
                    &rig.rgb,
                    &used,
                    factor,
                    settings.recipe == Recipe::Paper,
                    sigma,
                    7,
                );
                eprintln!(
                    "level 1/{factor}: cost at truth {:.6}, at estimate {:.6}",
                    cost(&level, &scaling, &tt, &all),
                    cost(&level, &scaling, &te, &all)
                );
            }
            eprintln!("theta truth {tt:.2?}\ntheta est   {te:.2?}");
        }
        let before = mean_map_error(&rig, &truth_frames, &out.initial, &synth.truth);
        let after = mean_map_error(&rig, &truth_frames, &out.calibration, &synth.truth);
        let (deg, metres) = out.calibration.extrinsic.difference(&synth.truth.extrinsic);
        eprintln!("map error {before:.2} px -> {after:.3} px; rotation error {deg:.4}°, translation error {:.2} cm", metres * 100.0);
        eprintln!("est {:?}\ntruth {:?}", out.calibration, synth.truth);
        (after, deg, metres, out)
    }

    #[test]
    #[ignore = "development aid: RTF_CALIB_DEBUG=1 WIDTH=.. SEED=.. N_FRAMES=.."]
    fn explore() {
        tch::set_num_threads(1);
        let frames: usize = std::env::var("N_FRAMES")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(6);
        let seed: u64 = std::env::var("SEED")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(1);
        let width: usize = std::env::var("WIDTH")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(160);
        let cfg = RigSynthConfig {
            width,
            height: width * 3 / 4,
            frames,
            depth: DepthSource::Given,
            seed,
            ..Default::default()
        };
        let settings = Settings::resolve(Recipe::Default, Default::default(), None, 0).unwrap();
        let (err, _, _, out) = run_rig(&cfg, &settings);
        assert!(err.is_finite() && out.stopped.is_none());
    }

    #[test]
    fn default_recipe_reaches_subpixel_on_small_synthetic_rig() {
        tch::set_num_threads(1);
        let cfg = RigSynthConfig {
            width: 160,
            height: 120,
            frames: 6,
            depth: DepthSource::Given,
            seed: 1,
            ..Default::default()
        };
        let settings = Settings::resolve(Recipe::Default, Default::default(), None, 0).unwrap();
        let (err, _, _, out) = run_rig(&cfg, &settings);
        assert!(out.stopped.is_none());
        assert!(err < 0.3, "mean pixel-map error {err} px");
    }

    #[test]
    fn stereo_depth_rig_reaches_half_pixel() {
        tch::set_num_threads(1);
        let cfg = RigSynthConfig {
            width: 160,
            height: 120,
            frames: 6,
            depth: DepthSource::Stereo,
            seed: 4,
            ..Default::default()
        };
        let settings = Settings::resolve(Recipe::Default, Default::default(), None, 0).unwrap();
        let (err, _, _, out) = run_rig(&cfg, &settings);
        assert!(out.stopped.is_none());
        assert!(err < 0.5, "mean pixel-map error with SGM depth {err} px");
    }

    #[test]
    fn eight_bit_thermal_rig_calibrates_too() {
        tch::set_num_threads(1);
        let cfg = RigSynthConfig {
            width: 160,
            height: 120,
            frames: 5,
            depth: DepthSource::Given,
            seed: 7,
            thermal_16bit: false,
            ..Default::default()
        };
        let settings = Settings::resolve(Recipe::Default, Default::default(), None, 0).unwrap();
        let (err, _, _, _) = run_rig(&cfg, &settings);
        assert!(err < 0.3, "mean pixel-map error {err} px");
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
        let out = calibrate(&synth.rig, &frames, &sane, &mut |p| losses.push(p.loss)).unwrap();
        assert_eq!((out.iterations, losses.len()), (20, 20));
        assert!(out.loss.is_finite() && out.stopped.is_none());
        // Absurd steps: the loss runs away; the optimiser must stop and keep finite, best params.
        let wild = Settings {
            learning_rate: 1e4,
            iterations: 300,
            ..sane
        };
        let out = calibrate(&synth.rig, &frames, &wild, &mut |_| {}).unwrap();
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
