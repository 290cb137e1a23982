//! Calibration (issue 28): rig.yaml's `prior:` block, malformed one way per case, and a
//! prior far from what the images say (a named warning, whatever the verdict).

use std::path::{Path, PathBuf};

use crate::common::*;
use crate::verdict::{case, recovers, Case};
use crate::Fixture;

/// A synthetic 64×48 rig of `frames` frames with depth (`rtf synth --format
/// calibration-rig`), in `f.t/name`.
fn rig(f: &Fixture, name: &str, frames: &str) -> PathBuf {
    let dir = f.t.join(name);
    ok(&[
        "synth",
        "--format",
        "calibration-rig",
        "--out",
        s(&dir),
        "--size",
        "64x48",
        "--count",
        frames,
        "--rig-depth",
        "given",
        "--seed",
        "1",
    ]);
    dir.join("rig.yaml")
}

/// A copy of `rig` (beside it, so its relative paths hold) with `prior` appended.
fn with_prior(rig: &Path, name: &str, prior: &str) -> PathBuf {
    let text = std::fs::read_to_string(rig).unwrap();
    let path = rig.with_file_name(format!("{name}.yaml"));
    std::fs::write(&path, format!("{text}\nprior:\n{prior}")).unwrap();
    path
}

fn calibrate(name: &str, rig: &Path, out: &Path, must: &[&str]) -> Case {
    let args = [
        "calibrate",
        "--rig",
        s(rig),
        "--out",
        s(out),
        "--iterations",
        "5",
    ];
    let written = out.to_path_buf();
    case(&format!("calibrate: {name}"), &args, must).intact(move || !written.exists())
}

pub fn cases(f: &Fixture) -> Vec<Case> {
    // Two frames are enough to be refused for a malformed prior.
    let two = rig(f, "rig", "2");
    let out = f.t.join("calib.yaml");
    let malformed: [(&str, &str, &[&str]); 9] = [
        (
            "negative translation sigma",
            "  translation_m: [0.1, 0, 0]\n  translation_sigma_m: -0.02\n",
            &["prior.translation_sigma_m", "-0.02"],
        ),
        (
            "zero rotation sigma",
            "  rotation_deg: [0, 0, 0]\n  rotation_sigma_deg: 0\n",
            &["prior.rotation_sigma_deg"],
        ),
        (
            "negative principal-point sigma",
            "  principal_point_sigma_px: -10\n",
            &["prior.principal_point_sigma_px"],
        ),
        (
            "translation of 2 numbers",
            "  translation_m: [0.1, 0]\n  translation_sigma_m: 0.02\n",
            &["prior.translation_m", "needs 3 numbers, got 2"],
        ),
        (
            "rotation of 4 numbers",
            "  rotation_deg: [0, 0, 0, 1]\n  rotation_sigma_deg: 2\n",
            &["prior.rotation_deg", "got 4"],
        ),
        (
            "principal point of 1 number",
            "  principal_point_px: [32]\n  principal_point_sigma_px: 5\n",
            &["prior.principal_point_px"],
        ),
        (
            "a value without its sigma",
            "  translation_m: [0.1, 0, 0]\n",
            &["prior.translation_m", "translation_sigma_m"],
        ),
        (
            "a sigma without its value",
            "  rotation_sigma_deg: 2\n",
            &["prior.rotation_sigma_deg", "rotation_deg"],
        ),
        (
            "unknown key in prior",
            "  translaton_m: [0.1, 0, 0]\n",
            &["rig", "translaton_m"],
        ),
    ];
    let mut cases: Vec<Case> = malformed
        .iter()
        .enumerate()
        .map(|(i, (name, prior, must))| {
            let path = with_prior(&two, &format!("prior{i}"), prior);
            calibrate(&format!("prior, {name}"), &path, &out, must)
        })
        .collect();
    // A prior the images overrule: 55 cm from where the synthetic rig's thermal camera sits
    // (x), σ 5 cm, so the images set the solution, every frame's own best alignment is near
    // it and the prior is named as far from them. "Significantly" is judged over the frames
    // with their standard error estimated from them (Student-t, rtf_calib::bound::
    // critical_value): with two frames (1 degree of freedom) the cut-off is 13.7 standard
    // errors and no disagreement is significant, so this case has six (cut-off 2.65).
    //
    // Decisive on this rig (issue 44): with σ 1 cm the prior set the translation and the
    // frames could not all be aligned at it, so the verdict (`ok`, `uncertain` or `failed`)
    // turned on MKL's vendor-dependent kernels: `failed` (17 % agree) on Intel AVX-512,
    // `uncertain` with MKL_ENABLE_INSTRUCTIONS=AVX2, `ok` on AMD. At σ 5 cm, rig seed 1 ends
    // exit 0 (`uncertain`, the warning 4.9/0.3/11.5 σ, the line is 2.65) identically under
    // Intel AVX-512, all-AVX2 caps, MKL alone at AVX2 and MKL_CBWR=COMPATIBLE.
    //
    // And invariant: whether images overrule a prior is the rig's own matter, not a fixed
    // fact (rig seed 5 at σ 5 cm ends `failed`, 0 % of frames agreeing, exit 1, under every
    // one of those kernels; without the prior it is `uncertain` with all agreeing). Both are
    // honest outcomes, so exit 0 and the calibration's own failure (exit 1) are both right
    // here, as long as the warning is printed and written into calib.yaml: what must never
    // happen is the prior far from the images going unnamed, or a refusal of the prior.
    let far = with_prior(
        &rig(f, "rig6", "6"),
        "prior_far",
        "  translation_m: [0.6, 0, 0]\n  translation_sigma_m: 0.05\n",
    );
    let far_out = f.t.join("calib_far.yaml");
    let written = far_out.clone();
    cases.push(
        recovers(
            "calibrate: prior far from the images (warning; exit 0, or 1 if it fails)",
            &[
                "calibrate",
                "--rig",
                s(&far),
                "--out",
                s(&far_out),
                "--iterations",
                "10",
            ],
            &["prior_far_from_images"],
            Box::new(move || {
                std::fs::read_to_string(&written).is_ok_and(|t| t.contains("prior_far_from_images"))
            }),
        )
        .or_exit(1),
    );
    cases
}
