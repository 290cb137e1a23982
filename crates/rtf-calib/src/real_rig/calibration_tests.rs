use super::*;
use crate::frames::load_frames;
use crate::optimize::{mean_map_error, Recipe, Settings};
use crate::quality::Verdict;
use crate::solve::{calibrate, Outcome};

fn run(degrade: Degrade, seed: u64) -> Option<(f64, f64, Outcome)> {
    let data = default_data_dir()?;
    tch::set_num_threads(1);
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = RealRigConfig::new(&data, seed, 160, 6);
    cfg.degrade = degrade;
    let real = write_real_rig(dir.path(), &cfg).unwrap();
    let frames = load_frames(&real.rig, &mut |w| eprintln!("{w}")).unwrap();
    let settings = Settings::resolve(Recipe::Default, Default::default(), None, 0).unwrap();
    let out = calibrate(&real.rig, &frames, &settings, &mut |_| {}).unwrap();
    let before = mean_map_error(&real.rig, &frames, &out.initial, &real.truth);
    let after = mean_map_error(&real.rig, &frames, &out.calibration, &real.truth);
    eprintln!(
        "{degrade:?} seed {seed}: map error {before:.2} -> {after:.3} px; {:?}",
        out.assessment
    );
    if degrade == Degrade::None {
        // The stated bound covers the true error on real imagery too (issue 28).
        let bound = out.assessment.as_ref().and_then(|a| a.map_error_bound_px);
        assert!(
            after <= bound.expect("bound stated"),
            "{after} px > bound {bound:?}"
        );
    }
    Some((before, after, out))
}

#[test]
fn small_real_rig_recovers_the_truth_with_square_pixels() {
    let Some((before, after, out)) = run(Degrade::None, 1) else {
        return;
    };
    assert!(before > 3.0, "the start is misaligned ({before} px)");
    assert!(after < 0.8, "mean map error {after} px at 160×120");
    let k = out.calibration.thermal;
    assert_eq!(k.fx, k.fy, "square pixels by default");
    assert_ne!(out.assessment.unwrap().verdict, Verdict::Failed);
}

/// Trial 3 of `real_trials` (20 trials, 160×120, 6 views; mixed day/night frames, thermal
/// f = 0.82 × the RGB f): the coarse-to-fine run alone stops in a wrong basin (2.8 px off
/// with every other quality figure as good as a success). The restarts must either find
/// the true basin or say the result is not `ok` — never a silent wrong answer.
#[test]
fn wrong_basin_rig_is_never_a_silent_ok() {
    let Some(data) = default_data_dir() else {
        return;
    };
    tch::set_num_threads(1);
    let dir = tempfile::tempdir().unwrap();
    let cfg = RealRigConfig::new(&data, 3, 160, 6).in_trial_set(2, 20);
    let real = write_real_rig(dir.path(), &cfg).unwrap();
    let frames = load_frames(&real.rig, &mut |w| eprintln!("{w}")).unwrap();
    let settings = Settings::resolve(Recipe::Default, Default::default(), None, 0).unwrap();
    // The main run alone (no restarts) is in a wrong basin.
    let used: Vec<&crate::frames::Frame> = frames.iter().collect();
    let p0 = crate::optimize::initial_params(&real.rig);
    let pipe = crate::optimize::Pipeline::new(&real.rig, used, p0, &settings);
    let start = pipe.search([0.0; crate::model::NUM_PARAMS], 1)[0].1;
    let main = pipe.refine(start, 0, &mut |_, _| {}).theta;
    let main = crate::model::to_calibration(&pipe.scaling.physical(&main));
    let wrong = mean_map_error(&real.rig, &frames, &main, &real.truth);
    assert!(wrong > 1.5, "the main run alone ends {wrong} px off");
    let out = calibrate(&real.rig, &frames, &settings, &mut |_| {}).unwrap();
    let after = mean_map_error(&real.rig, &frames, &out.calibration, &real.truth);
    let a = out.assessment.unwrap();
    eprintln!("wrong basin {wrong:.3} px -> {after:.3} px; {a:?}");
    // The straight-line bound did not cover this rig (0.61 px against 0.87 px); the
    // profile with the Student-t cut-off does (1.50 px, docs/src/calibration.md, "The
    // bound on the rigs"). Its verdict is not `ok` (the distortion sits at its bound).
    let bound = a.map_error_bound_px.unwrap();
    assert!(
        after <= bound || a.verdict != Verdict::Ok,
        "{after} px > {bound} px, ok"
    );
    assert!(after <= bound, "{after} px above the bound {bound} px");
    assert!(
        after < 1.0 || a.verdict != Verdict::Ok,
        "{after} px off but verdict ok: {a:?}"
    );
    let r = a
        .restarts
        .expect("the default recipe runs the restart check");
    assert!(r.count >= 7 && r.improved_px > 1.0, "{r:?}");
}

#[test]
fn verdict_flags_shuffled_thermal_frames() {
    let Some((_, _, out)) = run(Degrade::ShuffleThermal, 2) else {
        return;
    };
    let a = out.assessment.unwrap();
    assert_ne!(a.verdict, Verdict::Ok, "{a:?}");
}

#[test]
fn verdict_flags_textureless_frames() {
    let Some((_, _, out)) = run(Degrade::Textureless, 3) else {
        return;
    };
    let a = out.assessment.unwrap();
    assert_ne!(a.verdict, Verdict::Ok, "{a:?}");
}
