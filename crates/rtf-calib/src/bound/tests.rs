use super::*;
use crate::frames::load_frames;
use crate::synth_rig::{write_rig, DepthSource, RigSynthConfig};

#[test]
fn critical_value_is_the_student_t_quantile() {
    // Textbook two-sided 95 % values (one-sided 97.5 %, z = 1.959964).
    for (dof, table) in [
        (1, 12.706),
        (2, 4.303),
        (3, 3.182),
        (5, 2.571),
        (10, 2.228),
        (19, 2.093),
        (30, 2.042),
    ] {
        let t = t_quantile(1.959_964, dof);
        assert!((t - table).abs() < 2e-3 * table, "ν {dof}: {t} vs {table}");
    }
    // More frames, a smaller cut-off, tending to the normal's.
    assert!(critical_value(6) > critical_value(20));
    assert!((critical_value(100_000) - SIGNIFICANCE).abs() < 1e-3);
}

/// A synthetic rig (160×120, 4 frames) and its profile around the truth.
fn synthetic() -> (tempfile::TempDir, Rig, Vec<Frame>, Calibration) {
    let dir = tempfile::tempdir().unwrap();
    let cfg = RigSynthConfig {
        seed: 2,
        width: 160,
        height: 120,
        frames: 4,
        depth: DepthSource::Given,
        ..Default::default()
    };
    let synth = write_rig(dir.path(), &cfg).unwrap();
    let rig = Rig::load(&synth.rig_path).unwrap();
    let frames = load_frames(&rig, &mut |_| {}).unwrap();
    (dir, rig, frames, synth.truth)
}

/// The profile re-minimises the other directions (its valley points cost less than the
/// straight line's and differ from them), and along every direction its flat extent is
/// at least the straight line's.
#[test]
fn profile_follows_the_valley_at_least_as_far_as_the_straight_line() {
    tch::set_num_threads(1);
    let _guard = tch::no_grad_guard();
    let (_dir, rig, frames, truth) = synthetic();
    let chosen: Vec<&Frame> = frames.iter().collect();
    let scaling = Scaling::new(&rig.rgb, optimize::initial_params(&rig), &chosen);
    let first = Setup::new(&rig, &chosen, &scaling, &scaling.theta_of(&truth));
    let theta = first.profile.reminimise(
        &scaling.theta_of(&truth),
        &first.dirs,
        &first.frames,
        CENTRE_ITERATIONS,
    );
    let setup = Setup::new(&rig, &chosen, &scaling, &theta);
    let p = &setup.profile;
    let eigen = eigen_directions(&setup.total_h, &setup.dirs);
    let mut lowered = 0;
    for (j, unit) in eigen.iter().enumerate() {
        let others: Vec<_> = (0..eigen.len())
            .filter(|&k| k != j)
            .map(|k| eigen[k])
            .collect();
        let (t, _) = p.extent(&theta, unit);
        let straight: [f64; NUM_PARAMS] =
            std::array::from_fn(|i| theta[i] + 2.0 * t.max(FIRST_STEP) * unit[i]);
        let valley = p.reminimise(&straight, &others, &setup.frames, PROFILE_ITERATIONS);
        let (cs, cv) = (p.total_cost(&straight), p.total_cost(&valley));
        assert!(cv <= cs, "re-minimised {cv} > straight {cs}");
        let moved: f64 = (0..NUM_PARAMS)
            .map(|i| (valley[i] - straight[i]).powi(2))
            .sum();
        if cv < cs && moved > 1e-6 {
            lowered += 1;
        }
        let w = walk(p, &theta, unit, &others, &setup.frames);
        assert_eq!(w.straight_t, t);
        assert!(w.profile_t >= t, "profile {} < straight {t}", w.profile_t);
        if let Some(v) = w.valley {
            assert!(
                p.indistinguishable(&v),
                "a valley end the data can tell apart"
            );
        }
    }
    assert!(lowered > 0, "the profile never re-minimised anything");
}
