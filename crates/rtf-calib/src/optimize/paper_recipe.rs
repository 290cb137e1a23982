//! The `paper` recipe: HeatNet §IV-A as published — the eq. 7 loss at full resolution (∇ of
//! the warped thermal image vs ∇ of the RGB image, Gaussian σ = 3 / 51 px,
//! [`super::levels`]), Adam on batches of 10 from up to 600 random pairs, 8000 iterations,
//! step halved every 500 — with a stop on a non-finite loss or divergence that keeps the
//! best parameters (docs/src/calibration.md, "Method" and "Results" for its time).

use super::levels::{cost, Level, Scaling};
use super::settings::Settings;
use super::solution::{Progress, Solution};
use crate::error::Result;
use crate::frames::Frame;
use crate::model::{self, NUM_PARAMS};
use crate::rig::Rig;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use tch::{Device, Kind, Tensor};

/// Adam's decay rates of the first and second moments, and its ε.
const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-8;

/// The paper recipe on `frames` from `p0`, the pairs and batches drawn from `rng`.
pub(super) fn calibrate_paper(
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
    let (final_theta, iterations, stopped) = adam(rig, &used, &scaling, settings, rng, progress);
    // Final loss over (up to) the first 20 pairs, frame by frame.
    let (mut sq, mut support) = (0.0, 0.0);
    for frame in used.iter().take(20) {
        let level = paper_level(rig, &[*frame]);
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

/// The paper's single full-resolution level of `frames`. Tensors are built per batch: 600
/// full-resolution frames would not fit in memory.
fn paper_level(rig: &Rig, frames: &[&Frame]) -> Level {
    Level::build(&rig.rgb, frames, 1, true, 3.0, 51)
}

/// Adam over `used` in random batches from θ = 0: the final θ (the best smoothed one if it
/// stopped early), the iterations run and why it stopped early, if it did.
fn adam(
    rig: &Rig,
    used: &[&Frame],
    scaling: &Scaling,
    settings: &Settings,
    rng: &mut ChaCha8Rng,
    progress: &mut dyn FnMut(&Progress),
) -> ([f64; NUM_PARAMS], usize, Option<String>) {
    let mut adam = Adam::new(scaling);
    let mut watch = Watch {
        best: (f64::INFINITY, vec![0.0; NUM_PARAMS]),
        smoothed: f64::NAN,
    };
    let mut stopped = None;
    let mut iterations = 0;
    let batch = settings.batch_size.min(used.len());
    for it in 0..settings.iterations {
        let lr = settings.learning_rate * 0.5f64.powi((it / 500) as i32);
        let mut pick: Vec<i64> = (0..used.len() as i64).collect();
        pick.shuffle(rng);
        pick.truncate(batch);
        let batch_frames: Vec<&Frame> = pick.iter().map(|&i| used[i as usize]).collect();
        let loss = adam.loss(&paper_level(rig, &batch_frames), batch_frames.len());
        iterations += 1;
        let grad = adam.theta.grad();
        stopped = watch.check(it, loss, &grad, &adam.theta, rig.thermal.width);
        if stopped.is_some() {
            break;
        }
        adam.step(&grad, it, lr);
        progress(&Progress {
            stage: "paper".into(),
            step: it + 1,
            total: settings.iterations,
            loss,
        });
    }
    let final_theta: [f64; NUM_PARAMS] = if stopped.is_some() {
        std::array::from_fn(|i| watch.best.1[i] as f64)
    } else {
        let t: Vec<f32> = Vec::try_from(&adam.theta.detach()).unwrap();
        std::array::from_fn(|i| t[i] as f64)
    };
    (final_theta, iterations, stopped)
}

/// Adam's state: the pixel-scaled parameters θ (with gradient), its moments, and the map to
/// physical parameters p = p0 + scale ⊙ θ as tensors.
struct Adam {
    theta: Tensor,
    m: Tensor,
    v: Tensor,
    p0: Tensor,
    scale: Tensor,
}

impl Adam {
    fn new(scaling: &Scaling) -> Self {
        let theta =
            Tensor::zeros([NUM_PARAMS as i64], (Kind::Float, Device::Cpu)).set_requires_grad(true);
        let m = Tensor::zeros([NUM_PARAMS as i64], (Kind::Float, Device::Cpu));
        let v = m.zeros_like();
        Self {
            theta,
            m,
            v,
            p0: Tensor::from_slice(&scaling.p0.map(|x| x as f32)),
            scale: Tensor::from_slice(&scaling.scale.map(|x| x as f32)),
        }
    }

    /// The loss of the `n` frames of `level` at θ, its gradient accumulated into θ.
    fn loss(&self, level: &Level, n: usize) -> f64 {
        let idx = Tensor::arange(n as i64, (Kind::Int64, Device::Cpu));
        tch::with_grad(|| {
            let p = &self.p0 + &self.scale * &self.theta;
            let r = level.residual(&p, &idx);
            let loss = r.square().sum(Kind::Float) / level.support(&idx);
            loss.backward();
            loss.double_value(&[])
        })
    }

    /// Adam's update of θ with gradient `grad` at iteration `it` and step `lr`; clears the
    /// gradient.
    fn step(&mut self, grad: &Tensor, it: usize, lr: f64) {
        let t = (it + 1) as i32;
        self.m = &self.m * BETA1 + grad * (1.0 - BETA1);
        self.v = &self.v * BETA2 + grad.square() * (1.0 - BETA2);
        let m_hat = &self.m / (1.0 - BETA1.powi(t));
        let v_hat = &self.v / (1.0 - BETA2.powi(t));
        let update = m_hat / (v_hat.sqrt() + EPS) * lr;
        tch::no_grad(|| {
            let _ = self.theta.f_sub_(&update);
        });
        let _ = self.theta.grad().zero_();
    }
}

/// The paper run's stopping rules: the smoothed loss and the best parameters seen.
struct Watch {
    /// (smoothed loss, θ) of the best smoothed loss so far.
    best: (f64, Vec<f32>),
    smoothed: f64,
}

impl Watch {
    /// Why the run must stop at iteration `it` (a non-finite loss or gradient, or divergence),
    /// if it must; otherwise updates the smoothed loss and the best parameters.
    fn check(
        &mut self,
        it: usize,
        loss: f64,
        grad: &Tensor,
        theta: &Tensor,
        width: usize,
    ) -> Option<String> {
        let grad_ok = grad.isfinite().all().int64_value(&[]) == 1;
        if !loss.is_finite() || !grad_ok {
            return Some(format!(
                "non-finite loss or gradient at iteration {it}; keeping the best parameters"
            ));
        }
        self.smoothed = if self.smoothed.is_nan() {
            loss
        } else {
            0.95 * self.smoothed + 0.05 * loss
        };
        // Divergence: parameters far beyond any plausible misalignment (θ is in pixels), or a
        // smoothed loss well above the best seen (a diverged warp often plateaus instead, so
        // the parameter test is the one that usually fires).
        let runaway = theta.abs().max().double_value(&[]) > 10.0 * width as f64;
        if runaway || (it > 50 && self.smoothed > 3.0 * self.best.0.max(1e-12)) {
            return Some(format!(
                "diverged at iteration {it}; keeping the best parameters"
            ));
        }
        if self.smoothed < self.best.0 {
            self.best = (self.smoothed, Vec::try_from(&theta.detach()).unwrap());
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::load_frames;
    use crate::optimize::{solve, Recipe};
    use crate::rig::OptimizerOverrides;
    use crate::synth_rig::{write_rig, DepthSource, RigSynthConfig};

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
}
