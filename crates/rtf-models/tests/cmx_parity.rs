//! Parity of CMX with the official network: lab/parity/cmx_reference.py builds it in the project's
//! `.venv` PyTorch (the official module tree and state_dict names, seeded random weights,
//! random BatchNorm statistics), runs it on a real MF frame through the official preprocessing
//! and saves a checkpoint as the official trainer does; converted by scripts/convert_pth.py and
//! loaded strictly by rtf under the official names, the network must give the same logits from
//! rtf's unit-range input.
//!
//! B0 (the whole 480×640 frame) and B2 (a 256×320 centre crop) run by default, the other sizes
//! (on the crop) with `RTF_CMX_SLOW=1`. On B0 the same weights fed R, G, B instead of the
//! official B, G, R must miss the reference by far: the comparison can tell a wrong network.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use rtf_models::cmx::ColorOrder;
use rtf_models::io::weights;
use rtf_models::ModelConfig;
use tch::{nn, Device};

/// Largest |rtf − PyTorch| allowed on the logits.
const TOLERANCE: f64 = 2e-3;

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn python() -> Option<PathBuf> {
    let python = repo_root().join(".venv/bin/python");
    if python.is_file() {
        Some(python)
    } else {
        eprintln!(
            "notice: .venv/bin/python not found (run `cargo xtask setup`); CMX parity skipped"
        );
        None
    }
}

/// The MF frame of `shared/data` (thermal in the alpha channel), if present.
fn frame() -> Option<PathBuf> {
    let frame = repo_root().join("../shared/data/mf-samples/01234N.png");
    if frame.is_file() {
        Some(frame)
    } else {
        eprintln!("notice: {} not found; CMX parity skipped", frame.display());
        None
    }
}

fn run(python: &Path, script: &str, args: &[OsString]) {
    let out = Command::new(python)
        .arg(repo_root().join(script))
        .args(args)
        .output()
        .expect("python runs");
    assert!(
        out.status.success(),
        "{script} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `size` = b0 … b5; `crop` = HxW centre crop of the frame, None for the whole frame.
fn check(size: &str, crop: Option<&str>) {
    let (Some(python), Some(frame)) = (python(), frame()) else {
        return;
    };
    let model = format!("cmx-mit-{size}");
    let dir = tempfile::tempdir().unwrap();
    let start = Instant::now();
    let mut args: Vec<OsString> = vec![
        dir.path().into(),
        size.into(),
        "--frame".into(),
        frame.into(),
    ];
    if let Some(crop) = crop {
        args.extend(["--crop".into(), crop.into()]);
    }
    run(&python, "lab/parity/cmx_reference.py", &args);
    let pth = dir.path().join(format!("{model}.pth"));
    let converted = dir.path().join(format!("{model}.safetensors"));
    run(
        &python,
        "scripts/convert_pth.py",
        &[pth.into(), converted.clone().into()],
    );
    let reference_s = start.elapsed().as_secs_f64();

    let start = Instant::now();
    let cfg = ModelConfig::from_name(&model, 9).unwrap();
    let mut vs = nn::VarStore::new(Device::Cpu);
    // Every variable is loaded: no need to draw fresh weights first.
    let net = rtf_models::build_with(&vs.root(), &cfg, &rtf_models::BuildOptions::uninitialised())
        .unwrap();
    weights::load_safetensors(&mut vs, &converted).unwrap();
    let loaded_s = start.elapsed().as_secs_f64();
    let io =
        weights::read_safetensors(&dir.path().join(format!("{model}_io.safetensors"))).unwrap();
    let get = |name: &str| {
        io.iter()
            .find(|(n, _)| n == name)
            .unwrap()
            .1
            .shallow_clone()
    };
    let (input, expected) = (get("input"), get("output"));
    net.check_input(&input.size()).unwrap();
    let logits = tch::no_grad(|| net.forward_t(&input, false));
    assert_eq!(logits.size(), expected.size());
    let diff = (&logits - &expected).abs().max().double_value(&[]);
    let scale = expected.abs().max().double_value(&[]);
    eprintln!(
        "{model} {:?}: max |rtf - PyTorch| = {diff:.3e} (max |logit| {scale:.3}); reference \
         {reference_s:.1} s, rtf build + load {loaded_s:.1} s, forward {:.1} s",
        input.size(),
        start.elapsed().as_secs_f64() - loaded_s
    );
    assert!(
        diff <= TOLERANCE,
        "{model}: logits differ from PyTorch by {diff}"
    );
    if size == "b0" {
        let ModelConfig::Cmx(mut rgb_cfg) = cfg else {
            unreachable!()
        };
        rgb_cfg.color_order = ColorOrder::Rgb;
        let cfg = ModelConfig::Cmx(rgb_cfg);
        let mut vs = nn::VarStore::new(Device::Cpu);
        let net =
            rtf_models::build_with(&vs.root(), &cfg, &rtf_models::BuildOptions::uninitialised())
                .unwrap();
        weights::load_safetensors(&mut vs, &converted).unwrap();
        let logits = tch::no_grad(|| net.forward_t(&input, false));
        let diff = (&logits - &expected).abs().max().double_value(&[]);
        eprintln!("{model} fed R, G, B: max |rtf - PyTorch| = {diff:.3e}");
        assert!(
            diff > 100.0 * TOLERANCE,
            "{model}: colour order makes no difference"
        );
    }
}

fn slow(size: &str, crop: &str) {
    if std::env::var_os("RTF_CMX_SLOW").is_none() {
        eprintln!("notice: cmx-mit-{size} parity skipped (set RTF_CMX_SLOW=1)");
        return;
    }
    check(size, Some(crop));
}

#[test]
fn cmx_mit_b0_matches_the_official_network() {
    check("b0", None);
}

#[test]
fn cmx_mit_b2_matches_the_official_network() {
    check("b2", Some("256x320"));
}

#[test]
fn cmx_mit_b1_matches_the_official_network() {
    slow("b1", "256x320");
}

#[test]
fn cmx_mit_b3_matches_the_official_network() {
    slow("b3", "256x320");
}

#[test]
fn cmx_mit_b4_matches_the_official_network() {
    slow("b4", "256x320");
}

#[test]
fn cmx_mit_b5_matches_the_official_network() {
    slow("b5", "256x320");
}
