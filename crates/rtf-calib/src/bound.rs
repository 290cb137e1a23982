//! The stated error bound (issue 28): how far the RGB→thermal map can be from the solution
//! among solutions the data cannot tell apart.
//!
//! Local curvature alone (the formal σ of [`crate::quality`]) said ±0.4 px on a real-imagery
//! rig whose answer was 4.1 px off: the objective is nearly flat along focal length against
//! forward offset and principal point against rotation. So the bound *profiles* the objective
//! (the recipe's own cost plus the priors, at the assessment level ≤ 320 px wide): along each
//! eigen-direction of its Gauss-Newton Hessian, in both senses, the step grows (×2 from
//! 0.25 px) until the cost rise is significant against the frame-resampling noise of that
//! rise — the mean per-frame cost difference must exceed [`SIGNIFICANCE`] times its standard
//! error over the frames (frames are the independent samples; a rise smaller than that could
//! vanish with another draw of frames). The last step that was not significant is the extent
//! of the flat set along that direction. The bound is the map displacement over that set
//! (the half-axes combined as an ellipsoid, √Σ d²), and at least the restart spread and the
//! distance between the split-half solutions (both are solutions the data accepted).
//!
//! Per-parameter (and camera-centre / rotation) intervals come from the same endpoints; for
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

/// A cost rise counts as real when it exceeds this many standard errors of its
/// frame-resampling noise (≈ 95 % one-sided).
pub const SIGNIFICANCE: f64 = 2.0;
/// First profile step and the largest one tried (θ units ≈ px of map motion).
const FIRST_STEP: f64 = 0.25;
const MAX_STEP: f64 = 64.0;
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
        mean + prior_rise <= SIGNIFICANCE * var.sqrt()
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
}

/// The bound on the mean map error (px) of `inputs.solution` on the frames `chosen`, and the
/// intervals (see the module doc).
pub fn bound(rig: &Rig, chosen: &[&Frame], inputs: &BoundInputs) -> (f64, Bound) {
    let _guard = tch::no_grad_guard();
    let scaling = Scaling::new(&rig.rgb, model::from_calibration(inputs.initial), chosen);
    let theta = scaling.theta_of(inputs.solution);
    let factor = optimize::assessment_factor(rig.rgb.width);
    let level = Level::build(&rig.rgb, chosen, factor, false, 0.0, 1)
        .subsample(optimize::MAX_LEVEL_PIXELS, 0);
    let square = rig.thermal.square_pixels.unwrap_or(true);
    let all: Vec<usize> = (0..NUM_PARAMS).collect();
    let dirs = optimize::directions(&all, &scaling, square);
    let frames: Vec<i64> = (0..chosen.len() as i64).collect();
    let (data_h, _, _) = optimize::normal_equations(&level, &scaling, &theta, &dirs, &frames);
    let n = dirs.len();
    let mut priors = Priors::new(rig);
    // The built-in bounds (free zones: distortion, the principal point's ±5 %) are left out
    // of the profile: a solution pinned at a bound is where the objective is biased, and a
    // bound's steep wall would cut the flat set short there. The user's priors stay.
    priors.terms.retain(|t| t.3 == 0.0);
    // The weight lm_level gives the priors: one σ costs the data's mean curvature.
    priors.weight = ((0..n).map(|i| data_h[i][i]).sum::<f64>() / n as f64).max(1e-12);
    let mut total_h = data_h.clone();
    optimize::add_priors(
        &priors,
        &scaling,
        &theta,
        &dirs,
        &mut total_h,
        &mut vec![0.0; n],
    );
    let support: Vec<f64> = frames
        .iter()
        .map(|&f| level.support(&Tensor::from_slice(&[f])))
        .collect();
    let mut profile = Profile {
        level,
        scaling: &scaling,
        base_prior: priors.cost(&scaling, &theta),
        priors,
        support,
        base: Vec::new(),
    };
    profile.base = profile.frame_costs(&theta);
    let correlation = Level::build(&rig.rgb, chosen, factor, false, 0.0, 1)
        .subsample(optimize::MAX_LEVEL_PIXELS, 0)
        .into_correlation();
    let other = refine(
        &correlation,
        &scaling,
        Priors::new(rig),
        &theta,
        &dirs,
        &frames,
    );
    let objective_gap_px = map_distance(&profile.level, &scaling, &theta, &other);
    let disagreement = prior_disagreement(rig, &profile, &theta, &dirs, &frames);
    let (endpoints, capped) = profile_endpoints(&profile, &theta, &total_h, &dirs);
    let (bound_px, mut b) = summarise(
        rig,
        &profile,
        &theta,
        &endpoints,
        (&data_h, &total_h, &dirs),
        inputs,
        capped,
    );
    b.objective_gap_px = objective_gap_px;
    b.warnings.extend(disagreement);
    (bound_px.max(2.0 * objective_gap_px), b)
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

/// The ends of the flat set along each eigen-direction of `total_h` (both senses, in order),
/// and whether some direction stayed flat up to the largest step.
fn profile_endpoints(
    profile: &Profile,
    theta: &[f64; NUM_PARAMS],
    total_h: &[Vec<f64>],
    dirs: &[[f64; NUM_PARAMS]],
) -> (Vec<[f64; NUM_PARAMS]>, bool) {
    let (_, vecs) = eigh(total_h);
    let mut endpoints = Vec::new();
    let mut capped = false;
    for v in &vecs {
        let mut d = [0.0; NUM_PARAMS];
        for (c, dir) in v.iter().zip(dirs) {
            (0..NUM_PARAMS).for_each(|i| d[i] += c * dir[i]);
        }
        let norm = d.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-12);
        for sign in [1.0, -1.0] {
            let unit = d.map(|x| sign * x / norm);
            let (t, hit_cap) = profile.extent(theta, &unit);
            capped |= hit_cap;
            endpoints.push(std::array::from_fn::<f64, NUM_PARAMS, _>(|i| {
                theta[i] + t * unit[i]
            }));
        }
    }
    (endpoints, capped)
}

/// Combines the profile's endpoints (pairs ± per direction) into the bound and intervals.
fn summarise(
    rig: &Rig,
    profile: &Profile,
    theta: &[f64; NUM_PARAMS],
    endpoints: &[[f64; NUM_PARAMS]],
    (data_h, total_h, dirs): (&[Vec<f64>], &[Vec<f64>], &[[f64; NUM_PARAMS]]),
    inputs: &BoundInputs,
    capped: bool,
) -> (f64, Bound) {
    let scaling = profile.scaling;
    let disp: Vec<f64> = endpoints
        .iter()
        .map(|e| map_distance(&profile.level, scaling, theta, e))
        .collect();
    let per_dir: Vec<f64> = disp.chunks(2).map(|p| p[0].max(p[1])).collect();
    let ellipsoid = per_dir.iter().map(|d| d * d).sum::<f64>().sqrt();
    let flattest_px = per_dir.iter().copied().fold(0.0, f64::max);
    let map_error_bound_px = ellipsoid
        .max(inputs.restart_spread_px)
        .max(2.0 * inputs.split_px);
    let q0 = quantities(&scaling.physical(theta));
    let qs: Vec<Vec<(String, f64)>> = endpoints
        .iter()
        .map(|e| quantities(&scaling.physical(e)))
        .collect();
    let mut intervals = BTreeMap::new();
    let mut half = BTreeMap::new();
    for (j, (name, v)) in q0.iter().enumerate() {
        let h = qs
            .chunks(2)
            .map(|p| (p[0][j].1 - v).abs().max((p[1][j].1 - v).abs()).powi(2))
            .sum::<f64>()
            .sqrt();
        intervals.insert(name.clone(), [v - h, v + h]);
        half.insert(name.clone(), h);
    }
    let (priors, warnings) = prior_roles(rig, scaling, theta, (data_h, total_h, dirs), &half);
    let bound = Bound {
        flattest_px,
        capped,
        objective_gap_px: 0.0,
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
    (data_h, total_h, dirs): (&[Vec<f64>], &[Vec<f64>], &[[f64; NUM_PARAMS]]),
    half: &BTreeMap<String, f64>,
) -> (BTreeMap<String, PriorRole>, Vec<String>) {
    let (mut roles, mut warnings) = (BTreeMap::new(), Vec::new());
    let Some(prior) = &rig.prior else {
        return (roles, warnings);
    };
    let q0 = quantities(&scaling.physical(theta));
    let find = |name: &str| q0.iter().position(|q| q.0 == name);
    let mut items: Vec<(&str, String, f64, f64)> = Vec::new();
    let axes = ["x", "y", "z"];
    if let (Some(t), Some(sd)) = (&prior.translation_m, prior.translation_sigma_m) {
        for k in 0..3 {
            items.push(("translation_m", format!("centre_{}_m", axes[k]), t[k], sd));
        }
    }
    if let (Some(r), Some(sd)) = (&prior.rotation_deg, prior.rotation_sigma_deg) {
        for k in 0..3 {
            items.push((
                "rotation_deg",
                format!("rotation_{}_deg", axes[k]),
                r[k],
                sd,
            ));
        }
    }
    if let Some(sd) = prior.principal_point_sigma_px {
        let (w, h) = (rig.thermal.width as f64, rig.thermal.height as f64);
        let c = prior
            .principal_point_px
            .clone()
            .unwrap_or(vec![w / 2.0, h / 2.0]);
        items.push(("principal_point_px", "cx".into(), c[0], sd));
        items.push(("principal_point_px", "cy".into(), c[1], sd));
    }
    let step = 1e-4;
    for (field, name, mu, sd) in items {
        let Some(j) = find(&name) else { continue };
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
        roles.insert(
            name.clone(),
            PriorRole {
                prior_sigma: sd,
                posterior_half_width: half.get(&name).copied().unwrap_or(f64::NAN),
                prior_share: share,
                set_by: if share >= PRIOR_SET_SHARE {
                    "prior"
                } else {
                    "images"
                }
                .into(),
            },
        );
    }
    (roles, warnings)
}
