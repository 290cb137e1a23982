//! `rtf bench train --json` and `rtf train --precision` through the binary.

mod common;
use common::*;
use std::path::Path;
use std::process::Command;

/// `rtf bench train --json` of one MFNet step on one 32×32 frame in `precision`.
fn tiny_bench(precision: &str) -> Vec<&str> {
    let mut args = vec![
        "bench", "train", "--model", "mfnet", "--batch", "1", "--size", "32x32",
    ];
    args.extend(["--precision", precision, "--warmup", "0", "--steps", "1"]);
    args.extend(["--threads", "1", "--json"]);
    args
}

/// `rtf bench train --json` of [`tiny_bench`] with its probe cache in `cache` and `vars` set
/// (`RTF_BF16_CONVOLUTIONS` removed unless given); requires success.
fn bench_with(precision: &str, cache: &Path, vars: &[(&str, &str)]) -> serde_json::Value {
    let out = Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args(tiny_bench(precision))
        .env("RTF_CACHE_DIR", cache)
        .env_remove(BF16_CONVOLUTIONS)
        .envs(vars.iter().copied())
        .output()
        .expect("rtf runs");
    assert!(out.status.success(), "{}", text(&out));
    serde_json::from_slice(&out.stdout).expect("JSON report")
}

const BF16_CONVOLUTIONS: &str = "RTF_BF16_CONVOLUTIONS";

/// The choice the probe's cached `conv3x3-training` measurement makes (issue 41): mixed where
/// fp32 kernels over bf16 operands were the faster, else native.
fn probed_choice(cache: &Path) -> &'static str {
    let file = cache.join("bf16-probe.json");
    let cache: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&file).expect("the probe's cache")).unwrap();
    let (_, m) = cache["measurements"]
        .as_object()
        .unwrap()
        .iter()
        .find(|(key, _)| key.starts_with("conv3x3-training | "))
        .expect("a conv3x3-training measurement");
    match m["fp32_s"].as_f64().unwrap() < m["bf16_s"].as_f64().unwrap() {
        true => "mixed",
        false => "native",
    }
}

/// Sets the cached `conv3x3-training` bf16 time to `factor` × its fp32 time.
fn edit_probe(cache: &Path, factor: f64) {
    let file = cache.join("bf16-probe.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    for (key, m) in json["measurements"].as_object_mut().unwrap() {
        if key.starts_with("conv3x3-training | ") {
            m["bf16_s"] = serde_json::json!(m["fp32_s"].as_f64().unwrap() * factor);
        }
    }
    std::fs::write(&file, serde_json::to_string(&json).unwrap()).unwrap();
}

/// The report's fields, and its convolution choice as what is invariant across CPU kinds
/// (issue 57): bf16's choice is the one this machine's probe recorded (emulated where the CPU
/// has no bf16 arithmetic), and each of the probe's outcomes is reported as such when its
/// cached measurement is edited to decide it, on every kind.
#[test]
fn bench_train_reports_the_issue_fields() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    for precision in ["fp32", "bf16"] {
        let report = bench_with(precision, &cache, &[]);
        assert_eq!(report["model"], "mfnet");
        assert_eq!(report["batch"], 1);
        assert_eq!(report["size"], "32x32");
        assert_eq!(report["precision"], precision);
        let convolutions = report["convolutions"].as_str().unwrap();
        let expected = match precision {
            "fp32" => "fp32".to_string(),
            _ if bf16_arithmetic().is_native() != Some(true) => "bf16 emulated".into(),
            _ => format!("bf16 {}", probed_choice(&cache)),
        };
        assert_eq!(convolutions, expected, "{report}");
        assert!(report["images_per_s"].as_f64().unwrap() > 0.0, "{report}");
        assert!(report["peak_rss_mb"].as_f64().unwrap() > 0.0, "{report}");
    }
    if bf16_arithmetic().is_native() == Some(true) {
        for (factor, choice) in [(2.0, "bf16 mixed"), (0.5, "bf16 native")] {
            edit_probe(&cache, factor);
            assert_eq!(bench_with("bf16", &cache, &[])["convolutions"], choice);
        }
    }
}

#[test]
fn bad_precisions_are_refused_with_the_reason() {
    let err = fails(&["bench", "train", "--model", "mfnet", "--precision", "fp8"]);
    assert!(err.contains("fp8") && err.contains("bf16"), "{err}");
    let err = fails(&[
        "bench",
        "train",
        "--model",
        "mfnet",
        "--precision",
        "fp16",
        "--size",
        "32x32",
    ]);
    assert!(err.contains("fp16") && err.contains("CUDA"), "{err}");
}

#[test]
fn emulated_bf16_convolutions_are_chosen_by_the_variable_and_a_bad_value_is_refused() {
    let run = |value: &str| {
        Command::new(env!("CARGO_BIN_EXE_rtf"))
            .args(tiny_bench("bf16"))
            .env("RTF_BF16_CONVOLUTIONS", value)
            .output()
            .expect("rtf runs")
    };
    for choice in ["native", "emulated", "mixed"] {
        let out = run(choice);
        assert!(out.status.success(), "{}", text(&out));
        let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(report["convolutions"], format!("bf16 {choice}"));
    }
    let out = run("fast");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("RTF_BF16_CONVOLUTIONS=`fast`"), "{err}");
    // `rtf train` refuses it before writing its run folder.
    let tmp = tempfile::tempdir().unwrap();
    let (data, run_dir) = (tmp.path().join("data"), tmp.path().join("run"));
    synth_mf(&data, "6", "0", "32x32");
    let out = Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args([
            "train",
            "--model",
            "mfnet",
            "--epochs",
            "1",
            "--precision",
            "bf16",
        ])
        .args(["--data", s(&data), "--out", s(&run_dir)])
        .env("RTF_BF16_CONVOLUTIONS", "fast")
        .output()
        .expect("rtf runs");
    assert!(!out.status.success());
    assert!(
        text(&out).contains("RTF_BF16_CONVOLUTIONS=`fast`"),
        "{}",
        text(&out)
    );
    assert!(!run_dir.exists(), "run folder written");
}
