//! Parity with PyTorch: a network of the published layout, built and run by the project's
//! `.venv` PyTorch (lab/parity/parity_reference.py), saved as a checkpoint the way published
//! weights come, converted by scripts/convert_pth.py, loaded strictly by rtf, must give the
//! same outputs — on the plain path, and on the fused fast path within float tolerance.

use std::path::{Path, PathBuf};
use std::process::Command;

use rtf_models::fast::{argmax_agreement, max_relative_difference, InferenceNet, Precision};
use rtf_models::io::weights;
use rtf_models::{build, ModelConfig};
use tch::{nn, Device, Kind};

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn python() -> Option<PathBuf> {
    let python = repo_root().join(".venv/bin/python");
    if python.is_file() {
        Some(python)
    } else {
        eprintln!(
            "notice: .venv/bin/python not found (run `cargo xtask setup`); torch parity skipped"
        );
        None
    }
}

fn run(python: &Path, script: &str, args: &[&Path]) {
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

fn check(model: &str) {
    let Some(python) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(&python)
        .arg(repo_root().join("lab/parity/parity_reference.py"))
        .arg(dir.path())
        .arg(model)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "parity_reference.py failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let pth = dir.path().join(format!("{model}.pth"));
    let converted = dir.path().join(format!("{model}.safetensors"));
    run(&python, "scripts/convert_pth.py", &[&pth, &converted]);

    let cfg = ModelConfig::from_name(model, 9).unwrap();
    let mut vs = nn::VarStore::new(Device::Cpu);
    let net = build(&vs.root(), &cfg).unwrap();
    weights::load_safetensors(&mut vs, &converted).unwrap();
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

    let plain = tch::no_grad(|| net.forward_t(&input, false));
    assert_eq!(plain.size(), expected.size());
    let diff = max_relative_difference(&expected, &plain);
    assert!(
        diff < 1e-4,
        "{model}: plain path differs from PyTorch by {diff} (relative)"
    );

    let fast = InferenceNet::new(net, Precision::Fp32).unwrap();
    let fused = fast.forward(&input).unwrap();
    let diff = max_relative_difference(&expected, &fused);
    assert!(
        diff < 1e-3,
        "{model}: fast path differs from PyTorch by {diff} (relative)"
    );
    let agreement = argmax_agreement(&fused, &expected);
    assert!(
        agreement >= 0.999,
        "{model}: fast path agrees on {agreement} of the pixels"
    );
    assert_eq!(fused.kind(), Kind::Float);
}

#[test]
fn mfnet_matches_pytorch_reference() {
    check("mfnet");
}

#[test]
fn rtfnet18_matches_pytorch_reference() {
    check("rtfnet18");
}
