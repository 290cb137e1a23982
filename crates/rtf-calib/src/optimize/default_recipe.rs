//! The `default` recipe (ours; the [module doc](super) sets it against HeatNet §IV-A as
//! published): a seeded subset of the frames, the exhaustive shift search at the coarsest
//! level, the staged coarse-to-fine Levenberg-Marquardt run of the [`Pipeline`] (both
//! stagings up to the check level where they differ, [`Staging`]), then the wrong-basin
//! check ([`Pipeline::restart`]). docs/src/calibration.md, "Method", describes each step
//! and the rounds that measured it.

use super::levels::cost;
use super::pipeline::{Pipeline, Refined, Staging};
use super::restart::RESTART_TIE;
use super::settings::Settings;
use super::solution::{Progress, Restarts, Solution};
use crate::error::Result;
use crate::frames::Frame;
use crate::model::{self, NUM_PARAMS};
use crate::rig::Rig;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use tch::Tensor;

/// The default recipe on `frames` from `p0`, the frame subset drawn from `rng`.
pub(super) fn calibrate_default(
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
    let run = main_run(&mut pipe, start, q, both, &mut on_level);
    let (theta, restarts, stopped) = check_basins(&pipe, &run, (step, total), progress);
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

/// The wrong-basin check ([`Pipeline::restart`]) after a main run that stayed finite,
/// reported at progress step `step` of `total`: the chosen θ, the check's summary and, if the
/// run did not stay finite, its θ and why it stopped.
fn check_basins(
    pipe: &Pipeline,
    run: &Refined,
    (step, total): (usize, usize),
    progress: &mut dyn FnMut(&Progress),
) -> ([f64; NUM_PARAMS], Option<Restarts>, Option<String>) {
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
    (theta, restarts, stopped)
}

/// The main run from the search's best shift `start`: the levels up to the check level `q`
/// with the late staging and, where the stagings differ there (`both`), with the early one
/// too, kept only where the data clearly favour it; then the finer levels.
fn main_run(
    pipe: &mut Pipeline,
    start: [f64; NUM_PARAMS],
    q: usize,
    both: bool,
    on_level: &mut dyn FnMut(usize, f64),
) -> Refined {
    let mut coarse = pipe.refine_levels(start, 0, q + 1, on_level);
    if coarse.non_finite.is_none() && both {
        pipe.staging = Staging::Early;
        let early = pipe.refine_levels(start, 0, q + 1, on_level);
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
    if coarse.non_finite.is_some() || q + 1 == pipe.levels.len() {
        coarse
    } else {
        let fine = pipe.refine(coarse.theta, q + 1, on_level);
        Refined {
            iterations: coarse.iterations + fine.iterations,
            ..fine
        }
    }
}
