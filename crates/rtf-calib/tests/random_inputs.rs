//! Stable-Rust randomised run of the `rig.yaml` reader: seeded mutations of a valid rig and
//! random bytes ([`rtf_data::fuzzing::mutations`]) give a rig or an error naming the file,
//! never a panic.

use rtf_calib::rig::Rig;

const RIG: &str = "
rgb:      { width: 640, height: 480, fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0 }
thermal:  { width: 640, height: 512, focal_length_mm: 13.0, pixel_pitch_mm: 0.017 }
frames:
  - { rgb: f/000_rgb.png, thermal: f/000_thermal.png, depth: f/000_depth.png }
  - { rgb: f/001_rgb.png, thermal: f/001_thermal.png, rgb_right: f/001_right.png }
stereo:   { baseline_m: 0.3 }
optimizer: { iterations: 2000, batch_size: 10, learning_rate: 0.01 }
prior:
  translation_m: [0.12, -0.02, 0.03]
  translation_sigma_m: 0.02
  rotation_deg: [0.0, 0.0, 0.0]
  rotation_sigma_deg: 2.0
  principal_point_sigma_px: 10
";

#[test]
fn rig_yaml_never_panics() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rig.yaml");
    let outcome =
        rtf_data::fuzzing::check_reader("rig.yaml", RIG.as_bytes(), 31, 1000, "rig.yaml", |b| {
            std::fs::write(&path, b).unwrap();
            Rig::load(&path)
        });
    assert!(outcome.refused > 400, "{outcome:?}");
}
