//! The optimisers. Both minimise eq. 7-style losses over K_T, distortion and ξ ∈ se(3), in
//! parameters scaled so that one unit moves the RGB→thermal map by ~1 px (see
//! [`model::pixel_scales`](crate::model::pixel_scales)).
//!
//! - `paper`: HeatNet §IV-A as published: full resolution, ∇ of the warped thermal image vs ∇
//!   of the RGB image, Gaussian σ = 3 / 51 px, Adam, batches of 10 from up to 600 random
//!   pairs, 8000 iterations, step halved every 500.
//! - `default` (ours): coarse-to-fine pyramid (coarsest ≥ 40 px wide), a polarity-blind edge
//!   representation ([`model::edge_features`](crate::model::edge_features)) warped from
//!   thermal space with zero padding (no artificial border edges), a fixed loss support (RGB
//!   pixels with depth), an exhaustive shift search at the coarsest level (the rough
//!   landscape's basin), then damped Gauss-Newton (Levenberg-Marquardt with finite-difference
//!   Jacobians and a step limit) per level, which also handles the strongly correlated
//!   parameters (cx vs. ω_y vs. t_x).
//!
//! The parts, each file using only those listed before it (shared types first, their users
//! after):
//!
//! - `settings.rs`: [`Recipe`] and [`Settings`] (flags > rig.yaml > recipe).
//! - `solution.rs`: what a run reports ([`Progress`], [`Solution`], [`Restarts`]).
//! - `levels.rs`: the data term — pyramid [`Level`]s, the eq. 7-style [`cost`], the
//!   pixel [`Scaling`] of the parameters.
//! - `prior.rs`: the eq. 8 start ([`initial_params`]) and the [`Priors`].
//! - `lm.rs`: Levenberg-Marquardt on one level ([`normal_equations`], [`lm_level`]).
//! - `pipeline.rs`: the default recipe's staged coarse-to-fine [`Pipeline`] and its
//!   exhaustive shift search.
//! - `restart.rs`: the wrong-basin check ([`Pipeline::restart`]).
//! - `default_recipe.rs`, `paper_recipe.rs`: the two recipes, which [`solve`] runs.

mod default_recipe;
mod levels;
mod lm;
mod paper_recipe;
mod pipeline;
mod prior;
mod restart;
mod settings;
mod solution;

pub use levels::{assessment_factor, cost, pyramid_factors, Level, Scaling, MAX_LEVEL_PIXELS};
pub use lm::{add_priors, directions, lm_level, normal_equations, solve_spd, LmRun};
pub use pipeline::{staged_params, Pipeline, Refined, Staging};
pub use prior::{camera_centre, initial_params, Priors};
pub use restart::{RESTART_FRACTION, RESTART_MAX_WIDTH, RESTART_ROUNDS, RESTART_TIE};
pub use settings::{Recipe, Settings};
pub use solution::{Progress, Restarts, Solution};

use default_recipe::calibrate_default;
use paper_recipe::calibrate_paper;

use crate::camera::Calibration;
use crate::error::Result;
use crate::frames::Frame;
use crate::rig::Rig;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

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

/// Fixtures of the optimiser's unit tests.
#[cfg(test)]
pub(crate) mod tests {
    /// The optimiser's unit-test fixture: a 64×48 two-frame synthetic rig with given depth
    /// (seed 5), written to `dir`, and its frames loaded.
    pub(crate) fn small_test_rig(
        dir: &std::path::Path,
    ) -> (crate::synth_rig::SynthRig, Vec<crate::frames::Frame>) {
        use crate::synth_rig::{write_rig, DepthSource, RigSynthConfig};
        let cfg = RigSynthConfig {
            width: 64,
            height: 48,
            frames: 2,
            depth: DepthSource::Given,
            seed: 5,
            ..Default::default()
        };
        let synth = write_rig(dir, &cfg).unwrap();
        let frames = crate::frames::load_frames(&synth.rig, &mut |_| {}).unwrap();
        (synth, frames)
    }
}
