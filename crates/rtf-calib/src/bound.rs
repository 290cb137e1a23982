//! The stated error bound (issue 28): how far the RGB→thermal map can be from the solution
//! among solutions the data cannot tell apart.
//!
//! Local curvature alone (the formal σ of [`crate::quality`]) can state a small error on a
//! real-imagery rig whose answer is pixels off (measured: docs/src/calibration.md, section
//! "calib.yaml", paragraph "The stated bound"): the objective is nearly flat along focal length
//! against forward offset and principal point against rotation. So the bound measures the
//! *flat set* of the objective (the recipe's own cost plus the user's priors, at the
//! assessment level ≤ 320 px wide): the solutions whose cost rise is not significant against
//! the frame-resampling noise of that rise. Frames are the independent samples (pixels of one
//! frame are correlated, so a per-pixel count over-states the information, which is what made
//! the formal σ too small); the rise's mean over the frames must exceed [`critical_value`]
//! standard errors of that mean — the Student-t quantile with n − 1 degrees of freedom at the
//! one-sided level of 2 normal standard errors, since the standard error is itself estimated
//! from the n frames (a fixed 2 calls rises significant 2.2× too often with 6 frames: 5.1 %
//! instead of 2.3 %).
//!
//! 1. *Centre.* The solution comes from the finest level; the assessment level's own minimum
//!    lies near it but not at it. A few Gauss-Newton steps move to that minimum first, and the
//!    rises are measured from there (from the solution, the cost the finer level's optimum
//!    leaves on the table would read as flatness). The map distance solution → centre is
//!    added to the bound (the triangle inequality).
//! 2. *Walks.* Along each eigen-direction of the Gauss-Newton Hessian, both senses, the step
//!    grows ×2 from 0.25 θ units (≈ px) until the rise is significant, with one geometric
//!    bisection. The *straight-line* walk moves only along the direction; where the flat
//!    valley is curved or the parameters coupled, the line climbs out of the valley early and
//!    under-states the flat extent. The *profile* walk, from the straight line's extent on,
//!    holds the coordinate along the direction and re-minimises all the other directions at
//!    each step (a few damped Gauss-Newton iterations, warm-started from the previous valley
//!    point): the flat set's extent projected on that axis. Its points never cost more than
//!    the straight line's, so its extent is at least the straight line's.
//! 3. *Bound.* The ellipsoid (√Σ d²) of the map displacements of the axis points at the
//!    profile's extents, plus the centre's offset; at least the farthest valley point (each is
//!    a solution the data accept), the restart spread, twice the split-half distance and twice
//!    the distance to a second objective's optimum. The axis points are used rather than the
//!    valley points for the ellipsoid because a valley point also carries the re-minimised
//!    motion along the other (flat) directions, which their own axes already count.
//!
//! What it cannot see: a bias of the objective that all frames share (the rig's edges
//! mis-registered between the bands the same way in every frame, a lens the model cannot
//! follow): resampling frames cannot reveal what every frame agrees on. The second
//! objective's gap is the only probe of that here.
//!
//! Per-parameter (and camera-centre / rotation) intervals come from the same axis points; for
//! each quantity with a rig.yaml prior the share of the information that came from the prior
//! (1 − var(with prior)/var(images only), from the Hessians) says who set it.

use crate::camera::Calibration;
use crate::frames::Frame;
use crate::model::{self, NUM_PARAMS, PARAM_NAMES};
use crate::optimize::{self, camera_centre, Level, Priors, Scaling};
use crate::rig::Rig;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use tch::{Kind, Tensor};

/// A cost rise counts as real at the one-sided level of this many normal standard errors
/// (Φ(2) ≈ 97.7 %); with the standard error estimated from n frames the cut-off is the
/// Student-t quantile of that level with n − 1 degrees of freedom ([`critical_value`]).
pub const SIGNIFICANCE: f64 = 2.0;

/// The cut-off for a mean over `frames` frames whose standard error is estimated from those
/// frames: the Student-t quantile (n − 1 degrees of freedom) at the one-sided level of
/// [`SIGNIFICANCE`] normal standard errors. The statistic mean/SE follows t, not the normal,
/// when the SE is itself estimated: with 6 frames a cut-off of 2 calls a rise significant
/// 2.2× as often as intended (5.1 % instead of 2.3 %), which cuts the flat set short. Exact
/// for 1 and 2 degrees of freedom, the Cornish-Fisher expansion (Abramowitz & Stegun 26.7.5,
/// four terms; < 0.2 % off from 3 on) beyond.
pub fn critical_value(frames: usize) -> f64 {
    t_quantile(SIGNIFICANCE, frames.saturating_sub(1))
}

/// The Student-t quantile with `dof` degrees of freedom at the one-sided level Φ(z).
fn t_quantile(z: f64, dof: usize) -> f64 {
    let nu = dof.max(1) as f64;
    // The one-sided level p = Φ(z), for the exact small-ν forms.
    let p = 1.0 - 0.5 * erfc_approx(z / std::f64::consts::SQRT_2);
    match dof {
        0 | 1 => (std::f64::consts::PI * (p - 0.5)).tan(),
        2 => (2.0 * p - 1.0) / (2.0 * p * (1.0 - p)).sqrt(),
        _ => {
            let g1 = (z.powi(3) + z) / 4.0;
            let g2 = (5.0 * z.powi(5) + 16.0 * z.powi(3) + 3.0 * z) / 96.0;
            let g3 = (3.0 * z.powi(7) + 19.0 * z.powi(5) + 17.0 * z.powi(3) - 15.0 * z) / 384.0;
            let g4 = (79.0 * z.powi(9) + 776.0 * z.powi(7) + 1482.0 * z.powi(5)
                - 1920.0 * z.powi(3)
                - 945.0 * z)
                / 92160.0;
            z + g1 / nu + g2 / nu.powi(2) + g3 / nu.powi(3) + g4 / nu.powi(4)
        }
    }
}

/// erfc(x) for x ≥ 0 (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7).
fn erfc_approx(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    poly * (-x * x).exp()
}
/// First profile step and the largest one tried (θ units ≈ px of map motion).
const FIRST_STEP: f64 = 0.25;
const MAX_STEP: f64 = 64.0;
/// Gauss-Newton iterations that re-minimise the other directions at each profile step (warm
/// started from the previous step's valley point), and that move the solution to the
/// assessment level's own minimum before the walks.
const PROFILE_ITERATIONS: usize = 2;
const CENTRE_ITERATIONS: usize = 5;
/// A quantity is "set by the prior" when the prior supplies at least this share of its
/// information.
pub const PRIOR_SET_SHARE: f64 = 0.5;

/// Who set a quantity that has a prior, and how wide it is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PriorRole {
    pub prior_sigma: f64,
    /// Half-width of the interval after calibration (same units as the prior).
    pub posterior_half_width: f64,
    /// Share of the information that came from the prior (0: the images alone, 1: the prior).
    pub prior_share: f64,
    /// `images` or `prior`.
    pub set_by: String,
}

/// How the bound was found, and the intervals (`quality.bound` in calib.yaml; the bound itself
/// is `quality.map_error_bound_px`, see the module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Bound {
    /// Largest map displacement within the flat set along one direction (px).
    pub flattest_px: f64,
    /// True if some direction stayed indistinguishable up to the largest step tried.
    pub capped: bool,
    /// Map distance (px) from the solution to the optimum of a second objective (normalised
    /// cross-correlation of centred features, the assessment's score): a proxy for the bias
    /// of the objective itself, which the profile cannot see.
    pub objective_gap_px: f64,
    /// The ellipsoid of the straight-line walks alone (the bound before the profile
    /// re-minimised the other directions; 0 in files written before it).
    #[serde(default)]
    pub straight_line_px: f64,
    /// [low, high] per parameter (physical units), camera centre (m) and rotation (deg).
    pub intervals: BTreeMap<String, [f64; 2]>,
    /// For each quantity with a rig.yaml prior.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub priors: BTreeMap<String, PriorRole>,
    /// Named warnings about the priors (a prior far from what the images say).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// The objective at the assessment level, per frame, with the priors.
struct Profile<'a> {
    level: Level,
    scaling: &'a Scaling,
    priors: Priors,
    /// Per-frame support (pixels × channels).
    support: Vec<f64>,
    base: Vec<f64>,
    base_prior: f64,
}

impl<'a> Profile<'a> {
    /// A copy sharing the level's tensors (for another thread).
    fn shallow(&self) -> Profile<'a> {
        Profile {
            level: self.level.shallow(),
            scaling: self.scaling,
            priors: self.priors.clone(),
            support: self.support.clone(),
            base: self.base.clone(),
            base_prior: self.base_prior,
        }
    }

    fn frame_costs(&self, theta: &[f64; NUM_PARAMS]) -> Vec<f64> {
        let b = self.support.len() as i64;
        let idx = Tensor::arange(b, (Kind::Int64, tch::Device::Cpu));
        let c = self.level.pixel_cost(&self.scaling.tensor(theta), &idx);
        let sums: Vec<f64> = Vec::try_from(c.view([b, -1]).sum_dim_intlist(1, false, Kind::Double))
            .unwrap_or_default();
        sums.iter()
            .zip(&self.support)
            .map(|(s, n)| s / n.max(1.0))
            .collect()
    }

    /// True when θ's cost rise over the solution is not significant (see the module doc).
    fn indistinguishable(&self, theta: &[f64; NUM_PARAMS]) -> bool {
        let c = self.frame_costs(theta);
        let total: f64 = self.support.iter().sum::<f64>().max(1.0);
        let n = c.len() as f64;
        let w: Vec<f64> = self.support.iter().map(|s| s / total).collect();
        let d: Vec<f64> = c.iter().zip(&self.base).map(|(a, b)| a - b).collect();
        let mean: f64 = d.iter().zip(&w).map(|(d, w)| d * w).sum();
        let var: f64 = d
            .iter()
            .zip(&w)
            .map(|(d, w)| (w * (d - mean)).powi(2))
            .sum::<f64>()
            * n
            / (n - 1.0).max(1.0);
        let prior_rise = self.priors.cost(self.scaling, theta) - self.base_prior;
        mean + prior_rise <= critical_value(c.len()) * var.sqrt()
    }

    /// The largest step along `dir` (unit θ norm) whose cost rise is not significant.
    fn extent(&self, theta: &[f64; NUM_PARAMS], dir: &[f64; NUM_PARAMS]) -> (f64, bool) {
        let at = |t: f64| -> [f64; NUM_PARAMS] { std::array::from_fn(|i| theta[i] + t * dir[i]) };
        let mut ok = 0.0;
        let mut t = FIRST_STEP;
        while t <= MAX_STEP {
            if !self.indistinguishable(&at(t)) {
                // One bisection (geometric) between the last accepted and the first rejected.
                let mid = if ok > 0.0 { (ok * t).sqrt() } else { t / 2.0 };
                return (
                    if self.indistinguishable(&at(mid)) {
                        mid
                    } else {
                        ok
                    },
                    false,
                );
            }
            ok = t;
            t *= 2.0;
        }
        (ok, true)
    }

    /// Total cost (data + priors) at θ, normalised like the per-frame differences of
    /// [`Profile::indistinguishable`].
    fn total_cost(&self, theta: &[f64; NUM_PARAMS]) -> f64 {
        let total: f64 = self.support.iter().sum::<f64>().max(1.0);
        let data: f64 = self
            .frame_costs(theta)
            .iter()
            .zip(&self.support)
            .map(|(c, s)| c * s / total)
            .sum();
        data + self.priors.cost(self.scaling, theta)
    }

    /// θ with the directions `others` re-minimised: `iterations` damped
    /// Gauss-Newton steps at the profile's fixed prior weight (lm_level would re-weigh the
    /// priors from the reduced system), each limited like lm_level's to 2 px × the level's
    /// factor. Only cost decreases are taken, so the result never costs more than θ.
    fn reminimise(
        &self,
        theta: &[f64; NUM_PARAMS],
        others: &[[f64; NUM_PARAMS]],
        frames: &[i64],
        iterations: usize,
    ) -> [f64; NUM_PARAMS] {
        let (mut best, mut current) = (*theta, self.total_cost(theta));
        let max_step = 2.0 * self.level.factor as f64;
        let mut lambda = 1e-3;
        for _ in 0..iterations {
            let (mut jtj, mut jtr, _) =
                optimize::normal_equations(&self.level, self.scaling, &best, others, frames);
            optimize::add_priors(
                &self.priors,
                self.scaling,
                &best,
                others,
                &mut jtj,
                &mut jtr,
            );
            let n = others.len();
            let mean_diag = ((0..n).map(|i| jtj[i][i]).sum::<f64>() / n as f64).max(1e-12);
            let rhs: Vec<f64> = jtr.iter().map(|x| -x).collect();
            let mut accepted = false;
            for _ in 0..4 {
                let mut a = jtj.clone();
                (0..n).for_each(|i| a[i][i] += lambda * mean_diag);
                let Some(coef) = optimize::solve_spd(&a, &rhs) else {
                    lambda *= 10.0;
                    continue;
                };
                let mut delta = [0.0; NUM_PARAMS];
                for (c, d) in coef.iter().zip(others) {
                    (0..NUM_PARAMS).for_each(|i| delta[i] += c * d[i]);
                }
                let biggest = delta.iter().fold(0.0f64, |m, d| m.max(d.abs()));
                let shrink = if biggest > max_step {
                    max_step / biggest
                } else {
                    1.0
                };
                let trial: [f64; NUM_PARAMS] = std::array::from_fn(|i| best[i] + shrink * delta[i]);
                let tc = self.total_cost(&trial);
                if tc < current {
                    (best, current, accepted) = (trial, tc, true);
                    lambda = (lambda / 3.0).max(1e-7);
                    break;
                }
                lambda *= 10.0;
            }
            if !accepted {
                break;
            }
        }
        best
    }

    /// The profile along `unit`: the coordinate along it held at t, the directions `others`
    /// re-minimised at each t (from the straight-line point or the previous step's valley
    /// point moved on, whichever costs less). t doubles from `start` (the straight-line
    /// extent, which the profile can only lengthen: its points cost at most the straight
    /// line's; its end is where the chain starts) until the re-minimised point's rise is
    /// significant; one geometric bisection as
    /// in [`Profile::extent`]. Returns the last indistinguishable valley point (None if none
    /// beyond the solution) and whether the largest step was reached.
    fn profile_extent(
        &self,
        theta: &[f64; NUM_PARAMS],
        unit: &[f64; NUM_PARAMS],
        others: &[[f64; NUM_PARAMS]],
        frames: &[i64],
        start: f64,
    ) -> (Option<(f64, [f64; NUM_PARAMS])>, bool) {
        let at = |t: f64| -> [f64; NUM_PARAMS] { std::array::from_fn(|i| theta[i] + t * unit[i]) };
        let valley = |t: f64, prev: Option<(f64, [f64; NUM_PARAMS])>| {
            let mut from = at(t);
            if let Some((tp, p)) = prev {
                let moved = std::array::from_fn(|i| p[i] + (t - tp) * unit[i]);
                if self.total_cost(&moved) < self.total_cost(&from) {
                    from = moved;
                }
            }
            self.reminimise(&from, others, frames, PROFILE_ITERATIONS)
        };
        // The straight line's end is already indistinguishable: the chain starts there and
        // the first re-minimised step is the next one (it costs at most the straight line's).
        let mut ok: Option<(f64, [f64; NUM_PARAMS])> = (start > 0.0).then(|| (start, at(start)));
        let mut t = if start > 0.0 { 2.0 * start } else { FIRST_STEP };
        while t <= MAX_STEP {
            let p = valley(t, ok);
            if !self.indistinguishable(&p) {
                let mid = ok.map_or(t / 2.0, |(a, _)| (a * t).sqrt());
                let pm = valley(mid, ok);
                let last = if self.indistinguishable(&pm) {
                    Some((mid, pm))
                } else {
                    ok
                };
                return (last, false);
            }
            ok = Some((t, p));
            t *= 2.0;
        }
        (ok, true)
    }
}

/// Mean distance (full-resolution thermal px) between the maps of θa and θb over the level's
/// pixels with depth.
fn map_distance(
    level: &Level,
    scaling: &Scaling,
    a: &[f64; NUM_PARAMS],
    b: &[f64; NUM_PARAMS],
) -> f64 {
    let (ua, va) = model::project(&level.points, &scaling.tensor(a));
    let (ub, vb) = model::project(&level.points, &scaling.tensor(b));
    let m = level.mask.flatten(0, -1).to_kind(Kind::Double);
    let d = ((ua - ub).square() + (va - vb).square())
        .sqrt()
        .flatten(0, -1)
        .to_kind(Kind::Double);
    (d * &m).sum(Kind::Double).double_value(&[]) / m.sum(Kind::Double).double_value(&[]).max(1.0)
}

/// Quantities reported with intervals: the parameters, the camera centre and the rotation.
fn quantities(p: &[f64; NUM_PARAMS]) -> Vec<(String, f64)> {
    let mut q: Vec<(String, f64)> = PARAM_NAMES
        .iter()
        .zip(p)
        .map(|(n, v)| (n.to_string(), *v))
        .collect();
    let c = camera_centre(p);
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        q.push((format!("centre_{axis}_m"), c[k]));
        q.push((format!("rotation_{axis}_deg"), p[11 + k].to_degrees()));
    }
    q
}

/// Eigen-decomposition of a symmetric matrix (eigenvalues ascending, eigenvectors as rows).
fn eigh(a: &[Vec<f64>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = a.len();
    let flat: Vec<f64> = a.iter().flatten().copied().collect();
    let (vals, vecs) = Tensor::from_slice(&flat)
        .view([n as i64, n as i64])
        .linalg_eigh("L");
    let vals: Vec<f64> = Vec::try_from(vals).unwrap_or_default();
    let vecs: Vec<f64> = Vec::try_from(vecs.tr().contiguous().flatten(0, -1)).unwrap_or_default();
    (vals, vecs.chunks(n).map(<[f64]>::to_vec).collect())
}

/// Iterations of the short refinements (second objective, images alone), as the split-half
/// check's.
const REFINE_ITERATIONS: usize = 8;

/// θ refined from `theta` on `level` with `priors` (all parameters, every frame).
fn refine(
    level: &Level,
    scaling: &Scaling,
    mut priors: Priors,
    theta: &[f64; NUM_PARAMS],
    dirs: &[[f64; NUM_PARAMS]],
    frames: &[i64],
) -> [f64; NUM_PARAMS] {
    optimize::lm_level(
        level,
        scaling,
        &mut priors,
        *theta,
        dirs,
        frames,
        REFINE_ITERATIONS,
        1e-3,
        &mut |_| {},
    )
    .theta
}

/// Inputs of [`bound`] beyond the frames: the start (sets the θ scaling), the solution, and
/// the spreads the other checks measured (px).
pub struct BoundInputs<'a> {
    pub initial: &'a Calibration,
    pub solution: &'a Calibration,
    pub split_px: f64,
    pub restart_spread_px: f64,
    /// Each walk's extents on stderr ([`crate::optimize::Settings::debug`]).
    pub debug: bool,
}

/// The bound on the mean map error (px) of `inputs.solution` on the frames `chosen`, and the
/// intervals (see the module doc).
pub fn bound(rig: &Rig, chosen: &[&Frame], inputs: &BoundInputs) -> (f64, Bound) {
    let _guard = tch::no_grad_guard();
    let scaling = Scaling::new(&rig.rgb, model::from_calibration(inputs.initial), chosen);
    let solution = scaling.theta_of(inputs.solution);
    // The walks start from the assessment level's own minimum near the solution: rises are
    // measured from the lowest cost the level reaches, as a profile's must be (from the
    // solution, the cost the finer levels' optimum leaves on the table would be mistaken for
    // flatness). The map distance between the two is added to the bound.
    let first = Setup::new(rig, chosen, &scaling, &solution);
    let centre = first
        .profile
        .reminimise(&solution, &first.dirs, &first.frames, CENTRE_ITERATIONS);
    drop(first);
    let setup = Setup::new(rig, chosen, &scaling, &centre);
    let (profile, dirs, frames) = (&setup.profile, &setup.dirs, &setup.frames);
    let factor = optimize::assessment_factor(rig.rgb.width);
    let correlation = Level::build(&rig.rgb, chosen, factor, false, 0.0, 1)
        .subsample(optimize::MAX_LEVEL_PIXELS, 0)
        .into_correlation();
    let other = refine(
        &correlation,
        &scaling,
        Priors::new(rig),
        &solution,
        dirs,
        frames,
    );
    let objective_gap_px = map_distance(&profile.level, &scaling, &solution, &other);
    let disagreement = prior_disagreement(rig, profile, &solution, dirs, frames);
    let ends = profile_endpoints(profile, &centre, &setup.total_h, dirs, frames, inputs.debug);
    let (bound_px, mut b) = summarise(
        rig,
        profile,
        (&centre, &solution),
        &ends,
        (&setup.data_h, &setup.total_h, dirs),
        inputs,
    );
    b.objective_gap_px = objective_gap_px;
    b.warnings.extend(disagreement);
    (bound_px.max(2.0 * objective_gap_px), b)
}

/// The profiled objective at the assessment level around θ, its search directions, frames
/// and Gauss-Newton Hessians (the images alone, and with the user's priors).
struct Setup<'a> {
    profile: Profile<'a>,
    dirs: Vec<[f64; NUM_PARAMS]>,
    frames: Vec<i64>,
    data_h: Vec<Vec<f64>>,
    total_h: Vec<Vec<f64>>,
}

impl<'a> Setup<'a> {
    fn new(rig: &Rig, chosen: &[&Frame], scaling: &'a Scaling, theta: &[f64; NUM_PARAMS]) -> Self {
        let factor = optimize::assessment_factor(rig.rgb.width);
        let level = Level::build(&rig.rgb, chosen, factor, false, 0.0, 1)
            .subsample(optimize::MAX_LEVEL_PIXELS, 0);
        let square = rig.thermal.square_pixels.unwrap_or(true);
        let all: Vec<usize> = (0..NUM_PARAMS).collect();
        let dirs = optimize::directions(&all, scaling, square);
        let frames: Vec<i64> = (0..chosen.len() as i64).collect();
        let (data_h, _, _) = optimize::normal_equations(&level, scaling, theta, &dirs, &frames);
        let n = dirs.len();
        let mut priors = Priors::new(rig);
        // The built-in bounds (free zones: distortion, the principal point's ±5 %) are left
        // out of the profile: a solution pinned at a bound is where the objective is biased,
        // and a bound's steep wall would cut the flat set short there. The user's priors stay.
        priors.terms.retain(|t| t.3 == 0.0);
        // The weight lm_level gives the priors: one σ costs the data's mean curvature.
        priors.weight = ((0..n).map(|i| data_h[i][i]).sum::<f64>() / n as f64).max(1e-12);
        let mut total_h = data_h.clone();
        let mut ignored = vec![0.0; n];
        optimize::add_priors(&priors, scaling, theta, &dirs, &mut total_h, &mut ignored);
        let support: Vec<f64> = frames
            .iter()
            .map(|&f| level.support(&Tensor::from_slice(&[f])))
            .collect();
        let mut profile = Profile {
            level,
            scaling,
            base_prior: priors.cost(scaling, theta),
            priors,
            support,
            base: Vec::new(),
        };
        profile.base = profile.frame_costs(theta);
        Self {
            profile,
            dirs,
            frames,
            data_h,
            total_h,
        }
    }
}

/// Warnings when the rig.yaml prior and the images disagree: the solution refined without
/// the user's priors (the images alone, built-in bounds kept) fits the frames significantly
/// better than the MAP solution, and lies more than 3 σ from a prior item.
fn prior_disagreement(
    rig: &Rig,
    profile: &Profile,
    theta: &[f64; NUM_PARAMS],
    dirs: &[[f64; NUM_PARAMS]],
    frames: &[i64],
) -> Vec<String> {
    let Some(p) = &rig.prior else {
        return Vec::new();
    };
    let builtin = Rig {
        prior: None,
        ..rig.clone()
    };
    let alone = refine(
        &profile.level,
        profile.scaling,
        Priors::new(&builtin),
        theta,
        dirs,
        frames,
    );
    // Compared on the data only, with `alone` as the reference: is the MAP solution
    // significantly worse for the images?
    let mut no_priors = Priors::new(&builtin);
    no_priors.weight = 0.0;
    let data_only = Profile {
        level: profile.level.shallow(),
        scaling: profile.scaling,
        priors: no_priors,
        support: profile.support.clone(),
        base: profile.frame_costs(&alone),
        base_prior: 0.0,
    };
    if data_only.indistinguishable(theta) {
        return Vec::new();
    }
    let mine = Priors::new(rig);
    let r = mine.residuals(&profile.scaling.physical(&alone));
    let n = mine.terms.len();
    let items = [
        ("translation_m", p.translation_m.is_some(), n..n + 3),
        (
            "rotation_deg",
            p.rotation_deg.is_some(),
            n.saturating_sub(3)..n,
        ),
        (
            "principal_point_px",
            p.principal_point_sigma_px.is_some(),
            0..2,
        ),
    ];
    let mut out = Vec::new();
    for (field, given, range) in items {
        let off: Vec<f64> = range.filter_map(|k| r.get(k).map(|x| x.abs())).collect();
        if given && off.iter().any(|&x| x > 3.0) {
            let off: Vec<String> = off.iter().map(|x| format!("{x:.1}")).collect();
            out.push(format!(
                "prior_far_from_images: prior.{field}: the images alone fit the frames \
                 significantly better {} σ from it; check the measurement",
                off.join("/")
            ));
        }
    }
    out
}

/// One walk of [`profile_endpoints`]: the straight line's extent, the profile's (≥ it), the
/// profile's last valley point, and whether the largest step was reached.
struct Walk {
    straight_t: f64,
    profile_t: f64,
    valley: Option<[f64; NUM_PARAMS]>,
    capped: bool,
}

/// Both walks along `unit` from `theta` (see the module doc).
fn walk(
    profile: &Profile,
    theta: &[f64; NUM_PARAMS],
    unit: &[f64; NUM_PARAMS],
    others: &[[f64; NUM_PARAMS]],
    frames: &[i64],
) -> Walk {
    let (t, hit_cap) = profile.extent(theta, unit);
    let (valley, valley_cap) = profile.profile_extent(theta, unit, others, frames, t);
    Walk {
        straight_t: t,
        profile_t: valley.map_or(t, |(tv, _)| tv.max(t)),
        valley: valley.map(|(_, v)| v),
        capped: hit_cap || valley_cap,
    }
}

/// The eigen-directions of `h` (flattest first) as θ-space vectors.
fn eigen_directions(h: &[Vec<f64>], dirs: &[[f64; NUM_PARAMS]]) -> Vec<[f64; NUM_PARAMS]> {
    let (_, vecs) = eigh(h);
    vecs.iter()
        .map(|v| {
            let mut d = [0.0; NUM_PARAMS];
            for (c, dir) in v.iter().zip(dirs) {
                (0..NUM_PARAMS).for_each(|i| d[i] += c * dir[i]);
            }
            let norm = d.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-12);
            d.map(|x| x / norm)
        })
        .collect()
}

/// The flat set along each eigen-direction of `total_h`, both senses, from the centre
/// `theta` (the assessment level's minimum): the straight-line ends, the profile's axis
/// points (the centre moved along the direction by the profile's extent, the flat set's
/// extent projected on that axis), and the profile's valley points (solutions the data
/// cannot tell apart). The walks run on two threads (libtorch's own threads stay at one);
/// `debug` prints each walk's extents on stderr.
fn profile_endpoints(
    profile: &Profile,
    theta: &[f64; NUM_PARAMS],
    total_h: &[Vec<f64>],
    dirs: &[[f64; NUM_PARAMS]],
    frames: &[i64],
    debug: bool,
) -> Endpoints {
    let eigen = eigen_directions(total_h, dirs);
    let jobs: Vec<(usize, [f64; NUM_PARAMS])> = eigen
        .iter()
        .enumerate()
        .flat_map(|(j, d)| [(j, *d), (j, d.map(|x| -x))])
        .collect();
    let walks = run_walks(profile, theta, &eigen, &jobs, frames);
    let mut out = Endpoints::default();
    for ((_, unit), w) in jobs.iter().zip(walks) {
        let at = |t: f64| std::array::from_fn::<f64, NUM_PARAMS, _>(|i| theta[i] + t * unit[i]);
        if debug {
            let d = |e: &[f64; NUM_PARAMS]| map_distance(&profile.level, profile.scaling, theta, e);
            eprintln!(
                "bound walk: straight t {:.2} ({:.3} px), profile t {:.2} ({:.3} px), valley {:.3} px",
                w.straight_t,
                d(&at(w.straight_t)),
                w.profile_t,
                d(&at(w.profile_t)),
                w.valley.map_or(f64::NAN, |v| d(&v))
            );
        }
        out.straight.push(at(w.straight_t));
        out.ends.push(at(w.profile_t));
        out.valleys.extend(w.valley);
        out.capped |= w.capped;
    }
    out
}

/// The walks of `jobs` (eigen-direction index, signed unit direction), in order, on two
/// threads: interleaved halves, so that flat and stiff directions are shared between them.
fn run_walks(
    profile: &Profile,
    theta: &[f64; NUM_PARAMS],
    eigen: &[[f64; NUM_PARAMS]],
    jobs: &[(usize, [f64; NUM_PARAMS])],
    frames: &[i64],
) -> Vec<Walk> {
    let run = |p: &Profile, part: &[(usize, [f64; NUM_PARAMS])]| -> Vec<Walk> {
        let _guard = tch::no_grad_guard();
        part.iter()
            .map(|(j, unit)| {
                let others: Vec<[f64; NUM_PARAMS]> = (0..eigen.len())
                    .filter(|k| k != j)
                    .map(|k| eigen[k])
                    .collect();
                walk(p, theta, unit, &others, frames)
            })
            .collect()
    };
    let even: Vec<_> = jobs.iter().step_by(2).copied().collect();
    let odd: Vec<_> = jobs.iter().skip(1).step_by(2).copied().collect();
    let copy = profile.shallow();
    let (a, b) = std::thread::scope(|scope| {
        let run = &run;
        let h = scope.spawn(move || run(&copy, &odd));
        (
            run(profile, &even),
            h.join().expect("profile thread panicked"),
        )
    });
    // Re-interleave: even jobs from `a`, odd ones from `b`.
    let mut b = b.into_iter();
    a.into_iter()
        .flat_map(|w| std::iter::once(w).chain(b.next()))
        .collect()
}

/// The Gauss-Newton Hessians (images alone, with the priors) and their directions.
type Hessians<'a> = (&'a [Vec<f64>], &'a [Vec<f64>], &'a [[f64; NUM_PARAMS]]);

/// What [`profile_endpoints`] found.
#[derive(Default)]
struct Endpoints {
    /// Per direction and sense (pairs): the axis points at the profile's extent.
    ends: Vec<[f64; NUM_PARAMS]>,
    /// The straight-line ends (pairs).
    straight: Vec<[f64; NUM_PARAMS]>,
    /// The profile's valley points.
    valleys: Vec<[f64; NUM_PARAMS]>,
    capped: bool,
}

/// The ellipsoid (√Σ d²) of the per-direction map displacements of endpoint pairs.
fn ellipsoid_px(
    profile: &Profile,
    theta: &[f64; NUM_PARAMS],
    endpoints: &[[f64; NUM_PARAMS]],
) -> (f64, f64) {
    let disp: Vec<f64> = endpoints
        .iter()
        .map(|e| map_distance(&profile.level, profile.scaling, theta, e))
        .collect();
    let per_dir: Vec<f64> = disp.chunks(2).map(|p| p[0].max(p[1])).collect();
    let flattest = per_dir.iter().copied().fold(0.0, f64::max);
    (per_dir.iter().map(|d| d * d).sum::<f64>().sqrt(), flattest)
}

/// Combines the walks into the bound and the intervals: the ellipsoid (√Σ d²) of the axis
/// points' map displacements from the centre, plus the centre's distance from the solution;
/// at least the farthest valley point from the solution, the restart spread and twice the
/// split-half distance (all solutions the data accepted).
fn summarise(
    rig: &Rig,
    profile: &Profile,
    (centre, solution): (&[f64; NUM_PARAMS], &[f64; NUM_PARAMS]),
    ends: &Endpoints,
    (data_h, total_h, dirs): Hessians,
    inputs: &BoundInputs,
) -> (f64, Bound) {
    let scaling = profile.scaling;
    let dist =
        |a: &[f64; NUM_PARAMS], b: &[f64; NUM_PARAMS]| map_distance(&profile.level, scaling, a, b);
    let offset = dist(solution, centre);
    let (ellipsoid, flattest_px) = ellipsoid_px(profile, centre, &ends.ends);
    let floor = ends
        .valleys
        .iter()
        .map(|v| dist(solution, v))
        .fold(0.0, f64::max);
    let map_error_bound_px = (offset + ellipsoid)
        .max(floor)
        .max(inputs.restart_spread_px)
        .max(2.0 * inputs.split_px);
    let q0 = quantities(&scaling.physical(centre));
    let qs: Vec<Vec<(String, f64)>> = ends
        .ends
        .iter()
        .map(|e| quantities(&scaling.physical(e)))
        .collect();
    let q_solution = quantities(&scaling.physical(solution));
    let mut intervals = BTreeMap::new();
    let mut half = BTreeMap::new();
    for (j, (name, v)) in q0.iter().enumerate() {
        let h = qs
            .chunks(2)
            .map(|p| (p[0][j].1 - v).abs().max((p[1][j].1 - v).abs()).powi(2))
            .sum::<f64>()
            .sqrt();
        // Centred on the centre, widened to contain the solution's value.
        let s = q_solution[j].1;
        intervals.insert(name.clone(), [(v - h).min(s), (v + h).max(s)]);
        half.insert(name.clone(), h + (s - v).abs());
    }
    let (priors, warnings) = prior_roles(rig, scaling, solution, (data_h, total_h, dirs), &half);
    let bound = Bound {
        flattest_px,
        capped: ends.capped,
        objective_gap_px: 0.0,
        straight_line_px: offset + ellipsoid_px(profile, centre, &ends.straight).0,
        intervals,
        priors,
        warnings,
    };
    (map_error_bound_px, bound)
}

/// Variance of quantity `q` (gradient along `dirs` by finite differences) under the inverse
/// of `h` (∞ where `h` is singular along it).
fn variance(h: &[Vec<f64>], grad: &[f64]) -> f64 {
    let n = h.len();
    let ridge = 1e-9 * (0..n).map(|i| h[i][i]).sum::<f64>() / n as f64;
    let mut a = h.to_vec();
    (0..n).for_each(|i| a[i][i] += ridge);
    match optimize::solve_spd(&a, grad) {
        Some(x) => x.iter().zip(grad).map(|(a, b)| a * b).sum(),
        None => f64::INFINITY,
    }
}

/// Who set each quantity with a rig.yaml prior, and warnings for priors the images contradict.
fn prior_roles(
    rig: &Rig,
    scaling: &Scaling,
    theta: &[f64; NUM_PARAMS],
    (data_h, total_h, dirs): Hessians,
    half: &BTreeMap<String, f64>,
) -> (BTreeMap<String, PriorRole>, Vec<String>) {
    let (mut roles, mut warnings) = (BTreeMap::new(), Vec::new());
    let q0 = quantities(&scaling.physical(theta));
    let step = 1e-4;
    for PriorItem {
        field,
        name,
        mu,
        sd,
    } in prior_items(rig)
    {
        let Some(j) = q0.iter().position(|q| q.0 == name) else {
            continue;
        };
        // The quantity's gradient along the Hessians' directions, by forward differences.
        let grad: Vec<f64> = dirs
            .iter()
            .map(|d| {
                let t: [f64; NUM_PARAMS] = std::array::from_fn(|i| theta[i] + step * d[i]);
                (quantities(&scaling.physical(&t))[j].1 - q0[j].1) / step
            })
            .collect();
        let (with, alone) = (variance(total_h, &grad), variance(data_h, &grad));
        let share = if alone.is_finite() {
            (1.0 - with / alone).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let off = (q0[j].1 - mu) / sd;
        if off.abs() > 3.0 {
            warnings.push(format!(
                "prior_far_from_images: prior.{field}: the calibration puts {name} at {:.4}, \
                 {:.1} σ from the prior's {mu} (σ {sd}); check the measurement",
                q0[j].1,
                off.abs()
            ));
        }
        let set_by = if share >= PRIOR_SET_SHARE {
            "prior"
        } else {
            "images"
        };
        let role = PriorRole {
            prior_sigma: sd,
            posterior_half_width: half.get(&name).copied().unwrap_or(f64::NAN),
            prior_share: share,
            set_by: set_by.into(),
        };
        roles.insert(name, role);
    }
    (roles, warnings)
}

/// One priored quantity: the rig.yaml field it comes from, the quantity's name in the
/// bound's intervals, the prior's value and σ.
struct PriorItem {
    field: &'static str,
    name: String,
    mu: f64,
    sd: f64,
}

/// The quantities rig.yaml's `prior:` block sets, each with its value and σ (none without
/// a prior block).
fn prior_items(rig: &Rig) -> Vec<PriorItem> {
    let mut items = Vec::new();
    let Some(prior) = &rig.prior else {
        return items;
    };
    let axes = ["x", "y", "z"];
    let mut push = |field, name: String, mu, sd| {
        items.push(PriorItem {
            field,
            name,
            mu,
            sd,
        })
    };
    if let (Some(t), Some(sd)) = (&prior.translation_m, prior.translation_sigma_m) {
        for k in 0..3 {
            push("translation_m", format!("centre_{}_m", axes[k]), t[k], sd);
        }
    }
    if let (Some(r), Some(sd)) = (&prior.rotation_deg, prior.rotation_sigma_deg) {
        for k in 0..3 {
            push(
                "rotation_deg",
                format!("rotation_{}_deg", axes[k]),
                r[k],
                sd,
            );
        }
    }
    if let Some(sd) = prior.principal_point_sigma_px {
        let (w, h) = (rig.thermal.width as f64, rig.thermal.height as f64);
        let c = prior
            .principal_point_px
            .clone()
            .unwrap_or(vec![w / 2.0, h / 2.0]);
        push("principal_point_px", "cx".into(), c[0], sd);
        push("principal_point_px", "cy".into(), c[1], sd);
    }
    items
}

#[cfg(test)]
mod tests;
