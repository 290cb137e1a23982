//! `rtf calibrate` end to end: a tiny synthetic rig → calib.yaml (+ overlays, comparison with
//! the ground truth); malformed rig.yaml → exit 1 naming the field.

use std::path::Path;

mod common;
use common::*;

#[test]
fn calibrates_a_small_synthetic_rig_with_overlays() {
    let dir = tempfile::tempdir().unwrap();
    let rig_dir = dir.path().join("rig");
    let d = |p: &str| dir.path().join(p).to_str().unwrap().to_string();
    let r = rtf(&[
        "synth",
        "--format",
        "calibration-rig",
        "--out",
        &d("rig"),
        "--size",
        "128x96",
        "--count",
        "4",
        "--rig-depth",
        "given",
        "--seed",
        "3",
    ]);
    assert!(r.status.success(), "{}", text(&r));
    let r = rtf(&[
        "calibrate",
        "--rig",
        &d("rig/rig.yaml"),
        "--out",
        &d("calib.yaml"),
        "--overlay",
        &d("overlay"),
        "--ground-truth",
        &d("rig/ground_truth.yaml"),
        "--iterations",
        "10",
        "--format",
        "kalibr",
    ]);
    let log = text(&r);
    assert!(r.status.success(), "{log}");
    assert!(log.contains("verdict: "), "the verdict is printed:\n{log}");
    assert!(
        log.contains("restarts (wrong-basin check):"),
        "the wrong-basin check is printed:\n{log}"
    );
    // The Kalibr camchain carries the same thermal parameters as calib.yaml.
    let camchain = std::fs::read_to_string(dir.path().join("calib-camchain.yaml")).unwrap();
    for key in ["cam1:", "T_cn_cnm1:", "distortion_model: radtan"] {
        assert!(camchain.contains(key), "camchain lacks {key}:\n{camchain}");
    }
    let calib = std::fs::read_to_string(dir.path().join("calib.yaml")).unwrap();
    for key in [
        "fx:",
        "distortion:",
        "rotation:",
        "translation:",
        "se3:",
        "frames_used: 4",
        "verdict:",
        "frames_agreeing:",
        "sharpness:",
        "sigma:",
        "restarts:",
        "spread_px:",
        "improved_px:",
    ] {
        assert!(calib.contains(key), "calib.yaml lacks {key}:\n{calib}");
    }
    let overlays = std::fs::read_dir(dir.path().join("overlay"))
        .unwrap()
        .count();
    assert_eq!(overlays, 4 * 3, "initial, final and residual per frame");
    // The printed comparison: the final map error is below the initial one and sub-pixel.
    let line = log
        .lines()
        .find(|l| l.starts_with("vs ground truth:"))
        .expect("comparison line");
    let number = |after: &str| -> f64 {
        let rest = &line[line.find(after).unwrap() + after.len()..];
        rest.trim_start()
            .split([' ', ')'])
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    let (fin, initial) = (number("pixel-map error"), number("(initial"));
    eprintln!("{line} (lines: 0.5 px and a fifth of the initial)");
    assert!(fin < 0.5 && fin < initial / 5.0, "{line}");
    assert!(Path::new(&rig_dir).join("ground_truth.yaml").exists());
}

#[test]
fn malformed_rig_is_an_error_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let rig = dir.path().join("rig.yaml");
    std::fs::write(
        &rig,
        "rgb: { width: 64, height: 48, fx: 50.0, fy: 50.0, cx: 32.0, cy: 24.0 }\n\
         thermal: { width: 64, height: 51, focal_length_mm: 0.0, pixel_pitch_mm: 0.017 }\n\
         frames:\n  - { rgb: a.png, thermal: b.png, depth: c.png }\n",
    )
    .unwrap();
    let out = dir.path().join("calib.yaml");
    let r = rtf(&[
        "calibrate",
        "--rig",
        rig.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!r.status.success());
    let log = text(&r);
    assert!(
        log.contains("rig.yaml") && log.contains("thermal.focal_length_mm"),
        "{log}"
    );
    assert!(!out.exists(), "no calib.yaml on error");
}

#[test]
fn refuses_to_overwrite_the_rig_or_its_inputs_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = |p: &str| dir.path().join(p).to_str().unwrap().to_string();
    ok(&[
        "synth",
        "--format",
        "calibration-rig",
        "--out",
        &d("rig"),
        "--size",
        "64x48",
        "--count",
        "2",
        "--rig-depth",
        "given",
        "--seed",
        "1",
    ]);
    let rig_text = std::fs::read(dir.path().join("rig/rig.yaml")).unwrap();
    let thermal = std::fs::read(dir.path().join("rig/f/000_thermal.png")).unwrap();
    let rig_path = rig_text_path(&dir);
    for (flag, target, what) in [
        ("--out", d("rig/rig.yaml"), "rig description"),
        ("--out", d("rig/f/../rig.yaml"), "rig description"),
        // Through a folder the write would create first.
        ("--out", d("rig/new-dir/../rig.yaml"), "rig description"),
        ("--out", d("rig/f/000_thermal.png"), "frames[0].thermal"),
        ("--overlay", d("rig/f/001_depth.png"), "frames[1].depth"),
    ] {
        let mut args = vec!["calibrate", "--rig", rig_path.as_str(), "--out"];
        let out_default = d("calib.yaml");
        if flag == "--out" {
            args.push(target.as_str());
        } else {
            args.extend([out_default.as_str(), "--overlay", &target]);
        }
        let err = fails(&args);
        assert!(
            err.contains(flag) && err.contains(what) && err.contains("refusing"),
            "{err}"
        );
    }
    assert_eq!(
        std::fs::read(dir.path().join("rig/rig.yaml")).unwrap(),
        rig_text
    );
    assert_eq!(
        std::fs::read(dir.path().join("rig/f/000_thermal.png")).unwrap(),
        thermal
    );
    assert!(!dir.path().join("calib.yaml").exists());
}

fn rig_text_path(dir: &tempfile::TempDir) -> String {
    dir.path()
        .join("rig/rig.yaml")
        .to_str()
        .unwrap()
        .to_string()
}
