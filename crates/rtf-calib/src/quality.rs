//! Knowing when a calibration failed (issue 12). After any recipe, the solution is assessed
//! on the frames it used, without ground truth:
//!
//! - **Alignment score**: per frame, the normalised cross-correlation of the centred edge
//!   features ([`crate::model::edge_features`]) of the RGB image and of the thermal image
//!   warped with the solution, over the loss support; the rig's score is the mean over frames.
//!   It is compared with the score at the nominal start and at perturbed solutions (±δ px of
//!   image shift in u and v, of scale and of roll): `sharpness` is the relative drop of the
//!   score from the solution to the perturbed solutions (is it a sharp optimum?).
//! - **Frames that agree**: a frame agrees when its own score peaks within ±δ of the solution
//!   in u and in v (a parabola through the three scores) and is positive there.
//! - **Uncertainty**: formal standard deviations of the parameters from the Gauss-Newton
//!   normal equations at the solution (residual variance, pixels counted as N/9 independent
//!   observations for the 3×3 gradient footprint), and each parameter's conditioning (the
//!   factor by which its variance is inflated by correlation with the others).
//! - **Moved**: the mean distance between the start and the final RGB→thermal map.
//! - **Split-half**: the solution refined on the even and on the odd frames alone; half the
//!   distance between the two maps estimates the error due to the frames' disagreement. It
//!   cannot see a bias common to all frames.
//! - **Restarts** (default recipe, the wrong-basin check): the solution perturbed by ±2 % of
//!   the thermal width in cx, cy and f and refined again at the levels up to 160 px wide; the
//!   best-scoring solution is kept (the objective decides, never the truth). The result is
//!   `uncertain` if solutions scoring within 0.2 % of each other lie more than
//!   [`SPREAD_UNCERTAIN_PX`] apart, or if the last round still found a better, distinct one.
//!   On the 160×120 real-imagery trials the first run stopped 2–3.5 px off in wrong basins
//!   that no other figure here could tell from successes (all frames agreeing, sharp, small
//!   split-half); the restarts found the better-scoring true basin.
//!
//! The verdict (`ok` / `uncertain` / `failed`) and its reason follow from these; the
//! thresholds were set on the real-imagery trials of `cargo xtask calib-check`
//! (docs/src/calibration.md).

use crate::bound::Bound;
use crate::camera::Calibration;
use crate::error::Result;
use crate::frames::Frame;
use crate::model::{self, NUM_PARAMS, PARAM_NAMES};
use crate::optimize::{self, Level, Scaling};
use crate::rig::Rig;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use tch::{Kind, Tensor};

/// Perturbation size (full-resolution thermal pixels) for sharpness and frame agreement.
pub const DELTA_PX: f64 = 1.5;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    Ok,
    Uncertain,
    Failed,
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Verdict::Ok => "ok",
            Verdict::Uncertain => "uncertain",
            Verdict::Failed => "failed",
        })
    }
}

/// Alignment scores (mean per-frame normalised cross-correlation of edge features).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scores {
    pub at_solution: f64,
    pub at_start: f64,
    /// Mean score over the perturbed solutions (±δ px in u, v, scale, roll).
    pub perturbed_mean: f64,
    /// Best score among the perturbed solutions.
    pub perturbed_best: f64,
    /// (at_solution − perturbed_mean) / |at_solution|.
    pub sharpness: f64,
    /// The perturbation, full-resolution thermal pixels.
    pub delta_px: f64,
}

pub use crate::optimize::Restarts;

/// Restart spread (px) above which the verdict is `uncertain`: two solutions that score about
/// the same map pixels this differently, so a < 1 px result cannot be claimed.
pub const SPREAD_UNCERTAIN_PX: f64 = 1.0;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Assessment {
    pub verdict: Verdict,
    pub reason: String,
    pub score: Scores,
    /// Share of the frames used whose own score peaks within ±δ of the solution.
    pub frames_agreeing: f64,
    /// Mean distance between the start and the final RGB→thermal maps (px).
    pub moved_px: f64,
    /// Split-half consistency (px): half the mean distance between the maps refined from the
    /// solution on the even and on the odd frames alone — an estimate of the solution's map
    /// error from the frames' disagreement (0 with fewer than 4 frames).
    #[serde(default)]
    pub split_px: f64,
    /// The wrong-basin check (default recipe only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub restarts: Option<Restarts>,
    /// Formal 1-σ uncertainty per parameter (physical units; fx and fy are one parameter
    /// with square pixels).
    pub sigma: BTreeMap<String, f64>,
    /// Variance inflation per parameter from correlation with the others (1 = independent).
    pub conditioning: BTreeMap<String, f64>,
    /// Bound on the mean RGB→thermal map error (px) from the solutions the data cannot tell
    /// apart ([`crate::bound`]); `ok` needs it below [`BOUND_OK_PX`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub map_error_bound_px: Option<f64>,
    /// How the bound was found, the per-parameter intervals and who set the priored ones.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bound: Option<Bound>,
}

/// The largest map error bound (px) an `ok` verdict allows (issue 28).
pub const BOUND_OK_PX: f64 = 1.0;

impl Assessment {
    /// Records the bound; an `ok` verdict becomes `uncertain` when the bound is not below
    /// [`BOUND_OK_PX`], and the prior warnings join the reason.
    pub fn with_bound(mut self, bound_px: f64, bound: Bound) -> Self {
        // A NaN bound is no bound: `!(x < 1)` is true for it, where `x >= 1` would not be.
        #[allow(clippy::neg_cmp_op_on_partial_ord)]
        let not_below = !(bound_px < BOUND_OK_PX);
        if self.verdict == Verdict::Ok && not_below {
            self.verdict = Verdict::Uncertain;
            let spread = if bound.capped {
                format!("the data do not bound the map (solutions they cannot tell apart reach the search's edge, {bound_px:.0} px)")
            } else {
                format!("solutions the data cannot tell apart map pixels up to {bound_px:.2} px apart (bound ≥ {BOUND_OK_PX} px)")
            };
            self.reason = format!(
                "{spread}: add frames with structure at several depths, or priors (rig.yaml \
                 `prior:`) for what you know of the rig"
            );
        }
        if self.verdict == Verdict::Ok && !bound.warnings.is_empty() {
            // A prior the images contradict makes the bound conditional on a wrong prior.
            self.verdict = Verdict::Uncertain;
        }
        for w in &bound.warnings {
            self.reason.push_str(&format!("; warning {w}"));
        }
        self.map_error_bound_px = Some(bound_px);
        self.bound = Some(bound);
        self
    }
}

/// Per-frame score [b] of `level` (correlation mode, unblurred) at θ.
pub fn frame_scores(level: &Level, scaling: &Scaling, theta: &[f64; NUM_PARAMS]) -> Vec<f64> {
    let b = level.points.size()[0];
    let idx = Tensor::arange(b, (Kind::Int64, tch::Device::Cpu));
    let t = level.warp(&scaling.tensor(theta), &idx) * &level.mask;
    let a = &level.rgb_feat;
    let dims = &[1i64, 2, 3][..];
    let at = (a * &t).sum_dim_intlist(dims, false, Kind::Double);
    let aa = a.square().sum_dim_intlist(dims, false, Kind::Double);
    let tt = t.square().sum_dim_intlist(dims, false, Kind::Double);
    let s = at / (aa * tt).sqrt().clamp_min(1e-12);
    Vec::try_from(s).unwrap()
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Split-half consistency: refines the solution (all parameters, a few Levenberg-Marquardt
/// iterations on `level`) on the even and on the odd frames alone and returns half the mean
/// distance between the two maps, over the frames used. If the frames' own best alignments
/// scatter (scene content that differs between the bands, too little structure), the halves
/// disagree; for independent halves the full solution's error is about half their distance.
#[allow(clippy::too_many_arguments)]
fn split_half(
    rig: &Rig,
    frames: &[Frame],
    used: &[usize],
    chosen: &[&Frame],
    factor: usize,
    scaling: &Scaling,
    theta: &[f64; NUM_PARAMS],
    square: bool,
) -> f64 {
    if used.len() < 4 {
        return 0.0;
    }
    // The calibrator's own objective (squared feature differences, no blur) at this level.
    let level = Level::build(&rig.rgb, chosen, factor, false, 0.0, 1)
        .subsample(optimize::MAX_LEVEL_PIXELS, 0);
    let all: Vec<usize> = (0..NUM_PARAMS).collect();
    let dirs = optimize::directions(&all, scaling, square);
    let solve = |parity: usize| -> Calibration {
        let idx: Vec<i64> = (0..used.len() as i64)
            .filter(|i| *i as usize % 2 == parity)
            .collect();
        let mut priors = optimize::Priors::new(rig);
        let run = optimize::lm_level(
            &level,
            scaling,
            &mut priors,
            *theta,
            &dirs,
            &idx,
            SPLIT_ITERATIONS,
            1e-3,
            &mut |_| {},
        );
        model::to_calibration(&scaling.physical(&run.theta))
    };
    let (even, odd) = (solve(0), solve(1));
    let chosen: Vec<Frame> = used.iter().map(|&i| frames[i].clone()).collect();
    0.5 * optimize::mean_map_error(rig, &chosen, &even, &odd)
}

/// Split-half estimate (px) above which the verdict is `uncertain`.
pub const SPLIT_UNCERTAIN_PX: f64 = 0.5;

/// Levenberg-Marquardt iterations of each half in [`split_half`].
const SPLIT_ITERATIONS: usize = 8;

/// Sharpness below which the verdict is `uncertain`. On the 640×480 real-imagery trials
/// (docs/src/calibration.md) the map error was 0.03–0.19 px divided by the sharpness, and
/// every trial with sharpness below 0.077 ended above 1 px except one (0.90 px); the 160×120
/// trials (sharpness 0.14–0.31), the RGB-as-thermal control at 640×480 (0.196, 0.09 px) and
/// the synthetic rigs stay above it.
pub const SHARPNESS_UNCERTAIN: f64 = 0.08;

/// The figures the verdict reads.
pub(crate) struct Figures<'a> {
    pub stopped: Option<&'a str>,
    pub at_solution: f64,
    pub agreeing: f64,
    pub sharpness: f64,
    pub split_px: f64,
    pub restarts: Option<&'a Restarts>,
    pub moved_px: f64,
    /// Score gain from the start to the solution.
    pub gain: f64,
    pub at_bounds: &'a [String],
}

/// The verdict and its reason, from the figures (rules in order; the first that fires wins):
/// failures first, then doubts, else `ok`.
pub(crate) fn decide(f: &Figures) -> (Verdict, String) {
    if let Some(why) = failure(f) {
        (Verdict::Failed, why)
    } else if let Some(why) = doubt(f) {
        (Verdict::Uncertain, why)
    } else {
        (
            Verdict::Ok,
            format!(
                "sharp optimum ({:.1} % lower score at ±{DELTA_PX} px), {:.0} % of frames agree",
                f.sharpness * 100.0,
                f.agreeing * 100.0
            ),
        )
    }
}

/// Why the figures say the calibration failed, if they do.
fn failure(f: &Figures) -> Option<String> {
    if let Some(why) = f.stopped {
        Some(format!("the optimiser stopped early: {why}"))
    } else if f.at_solution < 0.05 {
        Some(format!("the frames share too little edge structure: alignment score {:.3} at the solution (aligned real frames score 0.13–0.21 at 320×240)", f.at_solution))
    } else if f.agreeing < 0.5 {
        Some(format!(
            "only {:.0} % of the frames agree with the solution (their own best alignment is elsewhere): the thermal and RGB frames may not show the same scene",
            f.agreeing * 100.0
        ))
    } else if f.sharpness < 0.02 {
        Some(format!("no clear optimum: perturbing the solution by {DELTA_PX} px lowers the alignment score by only {:.1} %", f.sharpness * 100.0))
    } else {
        None
    }
}

/// Why the figures leave the calibration uncertain, if they do (after [`failure`]).
fn doubt(f: &Figures) -> Option<String> {
    if f.agreeing < 0.8 {
        Some(format!(
            "only {:.0} % of the frames agree with the solution",
            f.agreeing * 100.0
        ))
    } else if f.sharpness < SHARPNESS_UNCERTAIN {
        Some(format!(
            "a shallow optimum: perturbing by {DELTA_PX} px lowers the score by only {:.1} % (below {:.0} %); on real-imagery rigs the map error was about 0.03–0.19 px divided by this sharpness, so < 1 px cannot be claimed (more frames with structure seen by both cameras help)",
            f.sharpness * 100.0,
            SHARPNESS_UNCERTAIN * 100.0
        ))
    } else if f.split_px > SPLIT_UNCERTAIN_PX {
        Some(format!(
            "the frames disagree: solved on the even and on the odd frames alone, the maps differ by {:.2} px, so the solution is likely off by about {:.2} px (more frames, or frames with more structure seen by both cameras, help)",
            2.0 * f.split_px,
            f.split_px
        ))
    } else if let Some(why) = f.restarts.and_then(restart_doubt) {
        Some(why)
    } else if f.moved_px > 5.0 && f.gain < 0.1 * f.at_solution.abs() {
        Some(format!("the map moved {:.1} px from the start while the alignment score improved by only {:.1} %", f.moved_px, 100.0 * f.gain / f.at_solution.abs().max(1e-9)))
    } else if !f.at_bounds.is_empty() {
        Some(format!(
            "implausible parameters: {}",
            f.at_bounds.join("; ")
        ))
    } else {
        None
    }
}

/// What the restarts say against the solution: unsettled basins, or distinct optima that tie.
fn restart_doubt(r: &Restarts) -> Option<String> {
    if !r.settled {
        Some(format!(
            "wrong basins: restarts from the solution perturbed by {:.1} px kept finding better, distinct solutions ({} rounds, {:.2} px from the first run's); the objective has several optima here",
            r.perturbation_px, r.rounds, r.improved_px
        ))
    } else if r.spread_px > SPREAD_UNCERTAIN_PX {
        Some(format!(
            "several optima: restarts from the solution perturbed by {:.1} px reach solutions {:.2} px apart that score within {:.1} % of each other",
            r.perturbation_px,
            r.spread_px,
            100.0 * crate::optimize::RESTART_TIE
        ))
    } else {
        None
    }
}

/// The level the figures are computed on, and its downsampling factor: half resolution at
/// 640 wide (≤ 320 px wide), where δ = 1.5 px is still resolved; above MAX_LEVEL_PIXELS per
/// frame (the 320×240 level of a 640×480 rig) on a random subset of the support, as in the
/// optimiser; correlation mode, unblurred.
pub fn assessment_level(rig: &Rig, chosen: &[&Frame]) -> (usize, Level) {
    let factor = optimize::assessment_factor(rig.rgb.width);
    let level = Level::build(&rig.rgb, chosen, factor, false, 0.0, 1)
        .subsample(optimize::MAX_LEVEL_PIXELS, 0)
        .into_correlation();
    (factor, level)
}

/// Formal 1-σ per parameter (physical units) and variance inflation by correlation, from the
/// normal equations at θ (all parameters; fx = fy tied if square).
fn formal_sigma(
    level: &Level,
    scaling: &Scaling,
    theta: &[f64; NUM_PARAMS],
    frames: usize,
    square: bool,
) -> (BTreeMap<String, f64>, BTreeMap<String, f64>) {
    let all: Vec<usize> = (0..NUM_PARAMS).collect();
    let pdirs = optimize::directions(&all, scaling, square);
    let frames_idx: Vec<i64> = (0..frames as i64).collect();
    let (jtj, _, _) = optimize::normal_equations(level, scaling, theta, &pdirs, &frames_idx);
    let n = pdirs.len();
    let idx = Tensor::from_slice(&frames_idx);
    let r = level.residual(&scaling.tensor(theta), &idx);
    let support = level.support(&idx);
    let resid_var = r.square().sum(Kind::Double).double_value(&[]) / support.max(1.0);
    let n_eff = (support / 9.0).max(1.0);
    let mut sigma = BTreeMap::new();
    let mut conditioning = BTreeMap::new();
    for k in 0..n {
        let mut e = vec![0.0; n];
        e[k] = 1.0;
        let Some(col) = optimize::solve_spd(&jtj, &e) else {
            continue;
        };
        let var_theta = resid_var * col[k] / n_eff;
        let p = pdirs[k].iter().position(|&x| x != 0.0).unwrap_or(0);
        let names: Vec<usize> = if square && p == 0 {
            vec![0, 1]
        } else {
            vec![p]
        };
        for i in names {
            sigma.insert(
                PARAM_NAMES[i].to_string(),
                var_theta.sqrt() * scaling.scale[i] * pdirs[k][i].abs(),
            );
            conditioning.insert(PARAM_NAMES[i].to_string(), col[k] * jtj[k][k]);
        }
    }
    (sigma, conditioning)
}

/// What lies beyond the physical bounds (distortion, principal point, pixel aspect), in words.
fn beyond_bounds(rig: &Rig, solution: &Calibration, square: bool) -> Vec<String> {
    let k = &solution.thermal;
    let (w, h) = (rig.thermal.width as f64, rig.thermal.height as f64);
    let off_centre = ((k.cx - w / 2.0) / w)
        .abs()
        .max(((k.cy - h / 2.0) / w).abs());
    let [k1, k2, p1, p2] = k.distortion;
    let aspect = (k.fx / k.fy - 1.0).abs();
    let mut at_bounds = Vec::new();
    if k1.abs() > 0.5 || k2.abs() > 0.3 || p1.abs().max(p2.abs()) > 0.01 {
        at_bounds.push(format!(
            "distortion beyond its bounds (k1 {k1:.3}, k2 {k2:.3}, p1 {p1:.4}, p2 {p2:.4})"
        ));
    }
    if off_centre > 0.1 {
        at_bounds.push(format!(
            "principal point {:.0} % of the width off centre",
            100.0 * off_centre
        ));
    }
    if (square && aspect > 1e-6) || aspect > 0.02 {
        at_bounds.push(format!("pixel aspect fx/fy {:.4}", k.fx / k.fy));
    }
    at_bounds
}

/// Per-frame scores at the solution and at ±δ px along each probe direction.
struct Perturbations {
    at_solution: Vec<f64>,
    /// (minus, plus) per direction, each per frame.
    per_dir: Vec<(Vec<f64>, Vec<f64>)>,
}

impl Perturbations {
    fn measure(
        level: &Level,
        scaling: &Scaling,
        theta: &[f64; NUM_PARAMS],
        dirs: &[[f64; NUM_PARAMS]],
    ) -> Self {
        // θ units move the map by ~1 px RMS, so ±δ along a unit direction is ±δ px.
        let at = |d: &[f64; NUM_PARAMS], s: f64| -> [f64; NUM_PARAMS] {
            std::array::from_fn(|i| theta[i] + s * DELTA_PX * d[i])
        };
        let per_dir = dirs
            .iter()
            .map(|d| {
                let minus = frame_scores(level, scaling, &at(d, -1.0));
                let plus = frame_scores(level, scaling, &at(d, 1.0));
                (minus, plus)
            })
            .collect();
        Perturbations {
            at_solution: frame_scores(level, scaling, theta),
            per_dir,
        }
    }

    /// Mean score of each perturbed solution: −δ and +δ for each direction in turn.
    fn means(&self) -> Vec<f64> {
        self.per_dir
            .iter()
            .flat_map(|(m, p)| [mean(m), mean(p)])
            .collect()
    }

    /// Fraction of frames that agree in u and v: the parabola's vertex within ±δ and a
    /// maximum there (the first two directions are u and v).
    fn agreeing(&self) -> f64 {
        let s0 = &self.at_solution;
        let agrees = |f: usize| -> bool {
            s0[f] > 0.0
                && self.per_dir[..2].iter().all(|(m, p)| {
                    let curv = m[f] + p[f] - 2.0 * s0[f];
                    let slope = (p[f] - m[f]) / 2.0;
                    curv < 0.0 && (slope / curv).abs() <= 1.0
                })
        };
        (0..s0.len()).filter(|&f| agrees(f)).count() as f64 / s0.len().max(1) as f64
    }
}

/// The directions the solution is perturbed along (±DELTA_PX of map shift each): the
/// principal point's x and y, the focal length (both axes when pixels are square) and the
/// rotation about the optical axis.
fn probe_directions(scaling: &Scaling, square: bool) -> [[f64; NUM_PARAMS]; 4] {
    let focal = optimize::directions(&[0, 1], scaling, square)[0];
    let axis = |i: usize| {
        let mut d = [0.0; NUM_PARAMS];
        d[i] = 1.0;
        d
    };
    [axis(2), axis(3), focal, axis(13)]
}

impl Scores {
    /// The alignment scores at the solution, around it (`probe`) and at the start.
    fn from_probe(probe: &Perturbations, start: &[f64]) -> Scores {
        let at_solution = mean(&probe.at_solution);
        let perturbed = probe.means();
        let perturbed_mean = mean(&perturbed);
        Scores {
            at_solution,
            at_start: mean(start),
            perturbed_mean,
            perturbed_best: perturbed.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            sharpness: (at_solution - perturbed_mean) / at_solution.abs().max(1e-9),
            delta_px: DELTA_PX,
        }
    }
}

/// Assesses `solution` (found from `initial`) on the frames `used` of `frames`.
pub fn assess(
    rig: &Rig,
    frames: &[Frame],
    used: &[usize],
    initial: &Calibration,
    solution: &Calibration,
    stopped: Option<&str>,
    restarts: Option<Restarts>,
) -> Result<Assessment> {
    let _guard = tch::no_grad_guard();
    let chosen: Vec<&Frame> = used.iter().map(|&i| &frames[i]).collect();
    let p0 = model::from_calibration(initial);
    let scaling = Scaling::new(&rig.rgb, p0, &chosen);
    let ps = model::from_calibration(solution);
    let theta: [f64; NUM_PARAMS] =
        std::array::from_fn(|i| (ps[i] - scaling.p0[i]) / scaling.scale[i]);
    let (factor, level) = assessment_level(rig, &chosen);
    let square = rig.thermal.square_pixels.unwrap_or(true);
    let probe = Perturbations::measure(
        &level,
        &scaling,
        &theta,
        &probe_directions(&scaling, square),
    );
    let start = frame_scores(&level, &scaling, &[0.0; NUM_PARAMS]);
    let score = Scores::from_probe(&probe, &start);
    let (at_solution, sharpness) = (score.at_solution, score.sharpness);
    let agreeing = probe.agreeing();
    let (sigma, conditioning) = formal_sigma(&level, &scaling, &theta, chosen.len(), square);
    let moved_px = optimize::mean_map_error(rig, frames, solution, initial);
    let split_px = split_half(rig, frames, used, &chosen, factor, &scaling, &theta, square);
    let gain = at_solution - mean(&start);
    let at_bounds = beyond_bounds(rig, solution, square);
    let (verdict, reason) = decide(&Figures {
        stopped,
        at_solution,
        agreeing,
        sharpness,
        split_px,
        restarts: restarts.as_ref(),
        moved_px,
        gain,
        at_bounds: &at_bounds,
    });
    Ok(Assessment {
        verdict,
        reason,
        score,
        frames_agreeing: agreeing,
        moved_px,
        split_px,
        restarts,
        sigma,
        conditioning,
        map_error_bound_px: None,
        bound: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ok_assessment() -> Assessment {
        Assessment {
            verdict: Verdict::Ok,
            reason: String::new(),
            score: Scores {
                at_solution: 0.3,
                at_start: 0.2,
                perturbed_mean: 0.25,
                perturbed_best: 0.28,
                sharpness: 0.1,
                delta_px: DELTA_PX,
            },
            frames_agreeing: 1.0,
            moved_px: 5.0,
            split_px: 0.1,
            restarts: None,
            sigma: BTreeMap::new(),
            conditioning: BTreeMap::new(),
            map_error_bound_px: None,
            bound: None,
        }
    }

    fn bound(capped: bool) -> Bound {
        Bound {
            flattest_px: 3.0,
            capped,
            objective_gap_px: 0.0,
            straight_line_px: 3.0,
            intervals: BTreeMap::new(),
            priors: BTreeMap::new(),
            warnings: Vec::new(),
        }
    }

    #[test]
    fn a_bound_at_one_px_or_more_makes_ok_uncertain_and_an_unbounded_fit_says_so() {
        let small = ok_assessment().with_bound(0.4, bound(false));
        assert_eq!(small.verdict, Verdict::Ok);
        let wide = ok_assessment().with_bound(3.0, bound(false));
        assert_eq!(wide.verdict, Verdict::Uncertain);
        assert!(
            wide.reason.contains("up to 3.00 px apart"),
            "{}",
            wide.reason
        );
        // A 2-frame rig: the walks reach the search's edge; the number is no bound.
        let free = ok_assessment().with_bound(2.4e6, bound(true));
        assert_eq!(free.verdict, Verdict::Uncertain);
        assert!(
            free.reason.contains("do not bound the map") && !free.reason.contains("up to"),
            "{}",
            free.reason
        );
    }

    /// Figures of the 640×480 real-imagery trial seed 1 (day, thermal f / RGB f 0.77), which
    /// ended 1.09 px off with the earlier 5 % sharpness threshold calling it `ok`.
    fn trial_one() -> (Restarts, Vec<String>) {
        let restarts = Restarts {
            count: 7,
            rounds: 1,
            perturbation_px: 12.8,
            improved_px: 0.0,
            cost_drop: 0.0006,
            spread_px: 0.10,
            settled: true,
        };
        (restarts, Vec::new())
    }

    fn figures<'a>(sharpness: f64, r: &'a Restarts, bounds: &'a [String]) -> Figures<'a> {
        Figures {
            stopped: None,
            at_solution: 0.304,
            agreeing: 1.0,
            sharpness,
            split_px: 0.161,
            restarts: Some(r),
            moved_px: 18.7,
            gain: 0.2,
            at_bounds: bounds,
        }
    }

    #[test]
    fn shallow_optimum_of_a_silent_real_imagery_failure_is_uncertain() {
        let (r, b) = trial_one();
        let (verdict, reason) = decide(&figures(0.076, &r, &b));
        assert_eq!(verdict, Verdict::Uncertain);
        assert!(reason.contains("shallow optimum"), "{reason}");
        assert!(reason.contains("7.6 %"), "{reason}");
        // The same figures with the control rig's sharpness (0.196, 0.09 px off) are `ok`,
        // and below 2 % there is no optimum at all.
        assert_eq!(decide(&figures(0.196, &r, &b)).0, Verdict::Ok);
        assert_eq!(decide(&figures(0.015, &r, &b)).0, Verdict::Failed);
    }
}
