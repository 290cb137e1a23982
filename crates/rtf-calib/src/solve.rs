//! `rtf calibrate`'s whole computation: the recipe's optimiser ([`crate::optimize`]) and the
//! assessment of its solution ([`crate::quality`]). This module sits above both so that the
//! optimiser does not depend on the assessment.

use crate::camera::Calibration;
use crate::error::Result;
use crate::frames::Frame;
use crate::optimize::{self, Progress, Restarts, Settings};
use crate::quality::{self, Assessment};
use crate::rig::Rig;

/// A calibration and its assessment.
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
    /// Indices (into the frames given) of the frames the optimiser used.
    pub used: Vec<usize>,
    /// The quality assessment of the solution ([`crate::quality`]).
    pub assessment: Option<Assessment>,
    /// The wrong-basin check of the default recipe ([`optimize::Pipeline::restart`]).
    pub restarts: Option<Restarts>,
}

/// Calibrates from loaded frames and assesses the result.
pub fn calibrate(
    rig: &Rig,
    frames: &[Frame],
    settings: &Settings,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Outcome> {
    let s = optimize::solve(rig, frames, settings, progress)?;
    let _guard = tch::no_grad_guard();
    // Assess on (up to) 20 of the frames used, to bound the cost for the paper's 600.
    let used: Vec<usize> = s.used.iter().copied().take(20).collect();
    let assessment = quality::assess(
        rig,
        frames,
        &used,
        &s.initial,
        &s.calibration,
        s.stopped.as_deref(),
        s.restarts.clone(),
    )?;
    let chosen: Vec<&Frame> = used.iter().map(|&i| &frames[i]).collect();
    let (bound_px, bound) = crate::bound::bound(
        rig,
        &chosen,
        &crate::bound::BoundInputs {
            initial: &s.initial,
            solution: &s.calibration,
            split_px: assessment.split_px,
            restart_spread_px: s.restarts.as_ref().map_or(0.0, |r| r.spread_px),
            debug: settings.debug,
        },
    );
    let assessment = assessment.with_bound(bound_px, bound);
    Ok(Outcome {
        initial: s.initial,
        calibration: s.calibration,
        loss: s.loss,
        frames_used: s.frames_used,
        iterations: s.iterations,
        stopped: s.stopped,
        used: s.used,
        assessment: Some(assessment),
        restarts: s.restarts,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::load_frames;
    use crate::optimize::{mean_map_error, Recipe};
    use crate::synth_rig::{write_rig, DepthSource, RigSynthConfig};

    /// A 160×120 synthetic rig (6 frames, given depth) calibrated with the prior `make`
    /// builds from the truth: (map error px, camera-centre error m, outcome).
    fn calibrate_with_prior(
        seed: u64,
        make: impl Fn(&Calibration) -> crate::rig::PriorSpec,
    ) -> (f64, f64, Outcome) {
        tch::set_num_threads(1);
        let dir = tempfile::tempdir().unwrap();
        let cfg = RigSynthConfig {
            width: 160,
            height: 120,
            frames: 6,
            depth: DepthSource::Given,
            seed,
            ..Default::default()
        };
        let synth = write_rig(dir.path(), &cfg).unwrap();
        let mut rig = Rig::load(&synth.rig_path).unwrap();
        rig.prior = Some(make(&synth.truth));
        let frames = load_frames(&rig, &mut |_| {}).unwrap();
        let settings = Settings::resolve(Recipe::Default, Default::default(), None, 0).unwrap();
        let out = calibrate(&rig, &frames, &settings, &mut |_| {}).unwrap();
        let after = mean_map_error(&rig, &frames, &out.calibration, &synth.truth);
        let centre = |c: &Calibration| optimize::camera_centre(&crate::model::from_calibration(c));
        let (ce, ct) = (centre(&out.calibration), centre(&synth.truth));
        let centre_err = (0..3).map(|k| (ce[k] - ct[k]).powi(2)).sum::<f64>().sqrt();
        eprintln!(
            "seed {seed}: map error {after:.3} px, centre error {:.2} cm; {:?}",
            centre_err * 100.0,
            out.assessment
        );
        (after, centre_err, out)
    }

    /// The thermal camera centre and rotation vector of a calibration (m, degrees).
    fn centre_and_rotation(c: &Calibration) -> ([f64; 3], [f64; 3]) {
        let p = crate::model::from_calibration(c);
        (
            optimize::camera_centre(&p),
            [p[11], p[12], p[13]].map(f64::to_degrees),
        )
    }

    #[test]
    fn priors_near_the_truth_are_used_and_reported() {
        let (after, centre_err, out) = calibrate_with_prior(1, |truth| {
            let (c, r) = centre_and_rotation(truth);
            crate::rig::PriorSpec {
                // Measured within 1 cm per axis, as issue 28's target says (within 2 cm).
                translation_m: Some(vec![c[0] + 0.01, c[1] - 0.01, c[2] + 0.01]),
                translation_sigma_m: Some(0.02),
                rotation_deg: Some(r.to_vec()),
                rotation_sigma_deg: Some(2.0),
                principal_point_sigma_px: Some(10.0),
                principal_point_px: None,
            }
        });
        let a = out.assessment.expect("assessed");
        assert!(after < 0.3, "map error {after} px with priors");
        assert!(centre_err < 0.03, "camera centre {centre_err} m off");
        let bound = a.bound.expect("bound");
        assert!(after <= a.map_error_bound_px.unwrap());
        // Every priored quantity says who set it, with the prior's σ beside the result's width.
        for name in ["centre_x_m", "centre_z_m", "rotation_y_deg", "cx", "cy"] {
            let role = &bound.priors[name];
            assert!(
                role.set_by == "prior" || role.set_by == "images",
                "{role:?}"
            );
            assert!(role.posterior_half_width.is_finite() && role.prior_share >= 0.0);
        }
        assert_eq!(bound.priors["centre_x_m"].prior_sigma, 0.02);
        assert!(bound.warnings.is_empty(), "{:?}", bound.warnings);
    }

    #[test]
    fn a_prior_far_from_what_the_images_say_is_a_named_warning() {
        let (_, _, out) = calibrate_with_prior(1, |truth| {
            let (c, _) = centre_and_rotation(truth);
            crate::rig::PriorSpec {
                // 60 cm off along x with σ 1 cm: the images disagree.
                translation_m: Some(vec![c[0] + 0.6, c[1], c[2]]),
                translation_sigma_m: Some(0.01),
                ..Default::default()
            }
        });
        let a = out.assessment.expect("assessed");
        let warnings = &a.bound.as_ref().expect("bound").warnings;
        assert!(
            warnings
                .iter()
                .any(|w| w.starts_with("prior_far_from_images: prior.translation_m")),
            "{warnings:?}"
        );
        assert!(a.reason.contains("prior_far_from_images"), "{}", a.reason);
    }

    #[test]
    fn the_start_sits_at_the_prior() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = RigSynthConfig {
            width: 64,
            height: 48,
            frames: 2,
            seed: 2,
            ..Default::default()
        };
        let mut rig = write_rig(dir.path(), &cfg).unwrap().rig;
        rig.prior = Some(crate::rig::PriorSpec {
            translation_m: Some(vec![0.12, -0.02, 0.03]),
            translation_sigma_m: Some(0.02),
            rotation_deg: Some(vec![1.0, -2.0, 0.5]),
            rotation_sigma_deg: Some(2.0),
            principal_point_sigma_px: Some(5.0),
            principal_point_px: Some(vec![30.0, 25.0]),
        });
        let p = optimize::initial_params(&rig);
        let (c, r) = centre_and_rotation(&crate::model::to_calibration(&p));
        for (got, want) in c.iter().chain(&r).zip([0.12, -0.02, 0.03, 1.0, -2.0, 0.5]) {
            assert!((got - want).abs() < 1e-9, "{c:?} {r:?}");
        }
        assert_eq!((p[2], p[3]), (30.0, 25.0));
        // At the prior's mean every user prior residual is 0.
        let priors = optimize::Priors::new(&rig);
        let r = priors.residuals(&p);
        assert!(
            r[..2].iter().all(|x| x.abs() < 1e-12)
                && r[r.len() - 6..].iter().all(|x| x.abs() < 1e-9),
            "{r:?}"
        );
    }
}
