//! Where the search starts and what pulls on it besides the images.
//!
//! [`initial_params`] is eq. 8 of HeatNet §IV-A (K_T from the nominal lens, the rest ~0),
//! moved to the rotation, camera centre and principal point of rig.yaml's `prior:` where it
//! gives them (issue 28). [`Priors`] are the built-in priors (issue 12: the principal point
//! near the image centre with a free zone, bounded distortion) and the user's (issue 28), as
//! residuals in physical units that the Levenberg-Marquardt solver adds to the data cost
//! (docs/src/calibration.md: "rig.yaml" for `prior:`, "Method" and round 7 for the built-in
//! ones).

use super::levels::Scaling;
use crate::model::NUM_PARAMS;
use crate::rig::Rig;

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
/// constraint (fx = fy) is exact instead (a tied search direction, see
/// [`directions`](super::directions)).
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
