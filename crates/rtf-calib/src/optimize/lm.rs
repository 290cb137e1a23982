//! Damped Gauss-Newton (Levenberg-Marquardt) on one pyramid level: the default recipe's
//! solver (the [module doc](super); HeatNet §IV-A itself uses Adam, see `paper_recipe.rs`).
//!
//! [`normal_equations`] forms JᵀJ and Jᵀr of the eq. 7-style data term ([`super::levels`])
//! along the search [`directions`] (Lucas-Kanade style: warped feature gradients times
//! finite-difference motions of the smooth projection), [`add_priors`] adds the priors'
//! Gauss-Newton terms ([`super::prior`]), and [`lm_level`] iterates with Levenberg damping and
//! a step limit. [`solve_spd`] is the Cholesky solve they share with the quality assessment
//! and the bound.

use super::levels::{cost, Level, Scaling};
use super::prior::Priors;
use crate::model::{self, NUM_PARAMS};
use tch::{Kind, Tensor};

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

/// Finite-difference step (pixel-scaled units) of ∂(u, v)/∂d in [`normal_equations`].
const MOTION_STEP: f64 = 0.05;

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
    for &f in frames {
        let idx = Tensor::from_slice(&[f]);
        support += level.support(&idx);
        let s = Sampled::new(level, scaling, theta, &idx);
        let (sw, r0, frame_cost) = s.residuals(level, &idx);
        sq += frame_cost;
        let (jtj_t, jtr_t) = if level.taps <= 1 && !level.correlation && level.robust == 0.0 {
            s.structure_tensor_system(level, scaling, theta, dirs, &r0)
        } else {
            s.jacobian_system(level, scaling, theta, dirs, &sw, &r0)
        };
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

/// One frame of a level at θ for [`normal_equations`]: its points, their projection and the
/// thermal features and feature gradients sampled there.
struct Sampled {
    pts: Tensor,
    u0: Tensor,
    v0: Tensor,
    /// [1, Ct, H, W] warped features; `du_feat`, `dv_feat`: their ∂/∂u, ∂/∂v (level pixels).
    feat: Tensor,
    du_feat: Tensor,
    dv_feat: Tensor,
    mask: Tensor,
}

impl Sampled {
    fn new(level: &Level, scaling: &Scaling, theta: &[f64; NUM_PARAMS], idx: &Tensor) -> Self {
        let ct = level.thermal_src.size()[1];
        let pts = level.points.index_select(0, idx);
        let (u0, v0) = model::project(&pts, &scaling.tensor(theta));
        let grid =
            model::sampling_grid(&u0, &v0, level.factor, level.tw, level.th, level.h, level.w);
        let src = Tensor::cat(
            &[
                level.thermal_src.index_select(0, idx),
                level.thermal_grad.index_select(0, idx),
            ],
            1,
        );
        let sampled = src.grid_sampler_2d(&grid, 0, 0, true); // [1, 3·Ct, H, W]
        let feat = sampled.narrow(1, 0, ct);
        let (du_feat, dv_feat) = (sampled.narrow(1, ct, ct), sampled.narrow(1, 2 * ct, ct));
        let mask = level.mask.index_select(0, idx);
        Self {
            pts,
            u0,
            v0,
            feat,
            du_feat,
            dv_feat,
            mask,
        }
    }

    /// The square-root IRLS weights, the residuals the Jacobian multiplies (weighted; for the
    /// correlation objective a = G * (M·F_RGB)) and the frame's data cost (unnormalised).
    fn residuals(&self, level: &Level, idx: &Tensor) -> (Tensor, Tensor, f64) {
        let blur = |x: &Tensor| model::gaussian_blur(x, level.sigma, level.taps);
        let r0 = blur(&((level.rgb_feat.index_select(0, idx) - &self.feat) * &self.mask))
            .flatten(0, -1)
            .to_kind(Kind::Double);
        if level.correlation {
            // Gradient of Σ(a² − 2a·t) is 2·Jᵀa (J = ∂r/∂θ = −∂t/∂θ); JᵀJ stays the metric.
            let a = level.blurred_rgb(idx).flatten(0, -1).to_kind(Kind::Double);
            let sq = (a.square() - &a * (&a - &r0) * 2.0)
                .sum(Kind::Double)
                .double_value(&[]);
            (r0.ones_like(), a, sq)
        } else {
            let sq = level.rho(&r0).sum(Kind::Double).double_value(&[]);
            let sw = level.irls_weight(&r0).sqrt();
            let r = &r0 * &sw;
            (sw, r, sq)
        }
    }

    /// ∂(u, v)/∂d in level pixels (finite differences of the projection), [1, N] each.
    fn motion(
        &self,
        level: &Level,
        scaling: &Scaling,
        theta: &[f64; NUM_PARAMS],
        d: &[f64; NUM_PARAMS],
    ) -> (Tensor, Tensor) {
        let inv_f = 1.0 / level.factor as f64;
        let t: [f64; NUM_PARAMS] = std::array::from_fn(|i| theta[i] + MOTION_STEP * d[i]);
        let (u1, v1) = model::project(&self.pts, &scaling.tensor(&t));
        (
            (u1 - &self.u0) * (inv_f / MOTION_STEP),
            (v1 - &self.v0) * (inv_f / MOTION_STEP),
        )
    }

    /// Unblurred squares (the finer levels of the default recipe): J = −M·(F_u·du + F_v·dv)
    /// per channel, so JᵀJ and Jᵀr reduce over the channels first — a 2×2 structure tensor
    /// and a 2-vector per pixel — and only the 2·n motion columns (du, dv per direction) enter
    /// the products (3–4× fewer operations than forming the [C·N, n] Jacobian). Returns JᵀJ
    /// (row-major) and Jᵀr, unnormalised.
    fn structure_tensor_system(
        &self,
        level: &Level,
        scaling: &Scaling,
        theta: &[f64; NUM_PARAMS],
        dirs: &[[f64; NUM_PARAMS]],
        r0: &Tensor,
    ) -> (Vec<f64>, Vec<f64>) {
        let (mut dus, mut dvs) = (Vec::new(), Vec::new());
        for d in dirs {
            let (du, dv) = self.motion(level, scaling, theta, d);
            dus.push(du.flatten(0, -1));
            dvs.push(dv.flatten(0, -1));
        }
        let du = Tensor::stack(&dus, 1).to_kind(Kind::Double); // [N, n]
        let dv = Tensor::stack(&dvs, 1).to_kind(Kind::Double);
        let m = self.mask.flatten(0, -1).to_kind(Kind::Double); // M² = M (0/1)
        let chan = |x: Tensor| x.sum_dim_intlist(1, false, Kind::Double).flatten(0, -1);
        let (du_feat, dv_feat) = (&self.du_feat, &self.dv_feat);
        let suu = chan(du_feat.square()) * &m;
        let suv = chan(du_feat * dv_feat) * &m;
        let svv = chan(dv_feat.square()) * &m;
        let r = r0.view_as(&self.feat).to_kind(Kind::Float);
        let gu = chan(du_feat * &r) * &m;
        let gv = chan(dv_feat * &r) * &m;
        let cross = du.tr().matmul(&(&dv * suv.unsqueeze(1)));
        let a = du.tr().matmul(&(&du * suu.unsqueeze(1)))
            + &cross
            + cross.tr()
            + dv.tr().matmul(&(&dv * svv.unsqueeze(1)));
        let b = -(du.tr().matmul(&gu) + dv.tr().matmul(&gv));
        let jtj_t: Vec<f64> = Vec::try_from(a.flatten(0, -1)).unwrap();
        let jtr_t: Vec<f64> = Vec::try_from(b).unwrap();
        (jtj_t, jtr_t)
    }

    /// The general case (blur, robust loss or correlation): the [C·N, n] Jacobian, each
    /// column −G * (M·(F_u·du + F_v·dv)), weighted by `sw`. Returns JᵀJ (row-major) and Jᵀr,
    /// unnormalised.
    fn jacobian_system(
        &self,
        level: &Level,
        scaling: &Scaling,
        theta: &[f64; NUM_PARAMS],
        dirs: &[[f64; NUM_PARAMS]],
        sw: &Tensor,
        r0: &Tensor,
    ) -> (Vec<f64>, Vec<f64>) {
        let blur = |x: &Tensor| model::gaussian_blur(x, level.sigma, level.taps);
        let hw = [1, 1, level.h, level.w];
        let cols: Vec<Tensor> = dirs
            .iter()
            .map(|d| {
                let (du, dv) = self.motion(level, scaling, theta, d);
                let (du, dv) = (du.view(hw), dv.view(hw));
                (-blur(&((&self.du_feat * du + &self.dv_feat * dv) * &self.mask)))
                    .flatten(0, -1)
                    .to_kind(Kind::Double)
            })
            .collect();
        let j = Tensor::stack(&cols, 1) * sw.unsqueeze(1); // [N, n]
        let jtj_t: Vec<f64> = Vec::try_from(j.tr().matmul(&j).flatten(0, -1)).unwrap();
        let jtr_t: Vec<f64> = Vec::try_from(j.tr().matmul(r0)).unwrap();
        (jtj_t, jtr_t)
    }
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
        let problem = Problem {
            level,
            scaling,
            priors,
            dirs,
            idx: &idx,
        };
        let system = System {
            jtj,
            jtr,
            mean_diag,
        };
        let (accepted, small) = problem.step(&system, &mut theta, &mut current, &mut lambda);
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

/// What one iteration of [`lm_level`] minimises: the level's data cost over frames `idx`
/// plus the priors (at their set weight), along `dirs`.
struct Problem<'a> {
    level: &'a Level,
    scaling: &'a Scaling,
    priors: &'a Priors,
    dirs: &'a [[f64; NUM_PARAMS]],
    idx: &'a Tensor,
}

/// The Gauss-Newton system of one iteration: JᵀJ and Jᵀr with the priors' terms, and the
/// data's mean curvature (diagonal of JᵀJ before the priors).
struct System {
    jtj: Vec<Vec<f64>>,
    jtr: Vec<f64>,
    mean_diag: f64,
}

impl Problem<'_> {
    /// One iteration's step: solves the damped `system`, limits the step to the trust region
    /// and raises λ (×10 if the system is not positive definite, ×4 if the cost rose) until
    /// the cost drops below `current` (then θ and `current` move there and λ falls by 3) or λ
    /// reaches 10⁸. Returns whether a step was accepted and whether the last step tried was
    /// small (< 10⁻³ px × the level's factor).
    fn step(
        &self,
        system: &System,
        theta: &mut [f64; NUM_PARAMS],
        current: &mut f64,
        lambda: &mut f64,
    ) -> (bool, bool) {
        // Trust region: at most 2 full-resolution pixels per iteration and level factor.
        let max_step = 2.0 * self.level.factor as f64;
        let mut small = false;
        while *lambda < 1e8 {
            let mut a = system.jtj.clone();
            // Levenberg damping λ·mean(diag)·I: the units are commensurate (pixels), and
            // unlike Marquardt's diag scaling it resists drift along flat valleys.
            for (i, row) in a.iter_mut().enumerate() {
                row[i] += *lambda * system.mean_diag.max(1e-12) + 1e-12;
            }
            let rhs: Vec<f64> = system.jtr.iter().map(|x| -x).collect();
            let Some(coef) = solve_spd(&a, &rhs) else {
                *lambda *= 10.0;
                continue;
            };
            let mut delta = [0.0; NUM_PARAMS];
            for (c, d) in coef.iter().zip(self.dirs) {
                for i in 0..NUM_PARAMS {
                    delta[i] += c * d[i];
                }
            }
            let biggest = delta.iter().fold(0.0f64, |m, d| m.max(d.abs()));
            if biggest > max_step {
                delta = delta.map(|d| d * max_step / biggest);
            }
            small = biggest < 1e-3 * self.level.factor as f64;
            let trial: [f64; NUM_PARAMS] = std::array::from_fn(|i| theta[i] + delta[i]);
            let tc = cost(self.level, self.scaling, &trial, self.idx)
                + self.priors.cost(self.scaling, &trial);
            if tc.is_finite() && tc < *current {
                *theta = trial;
                *current = tc;
                *lambda = (*lambda / 3.0).max(1e-7);
                return (true, small);
            }
            *lambda *= 4.0;
        }
        (false, small)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::Frame;
    use crate::optimize::initial_params;

    #[test]
    fn structure_tensor_normal_equations_match_the_full_jacobian() {
        tch::set_num_threads(1);
        let dir = tempfile::tempdir().unwrap();
        let (synth, frames) = crate::optimize::tests::small_test_rig(dir.path());
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
}
