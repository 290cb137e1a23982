//! `rtf bench train --json` and `rtf train --precision` through the binary.

mod common;
use common::*;
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

#[test]
fn bench_train_reports_the_issue_fields() {
    for precision in ["fp32", "bf16"] {
        let report = json_out(&tiny_bench(precision));
        assert_eq!(report["model"], "mfnet");
        assert_eq!(report["batch"], 1);
        assert_eq!(report["size"], "32x32");
        assert_eq!(report["precision"], precision);
        let convolutions = report["convolutions"].as_str().unwrap();
        match precision {
            "fp32" => assert_eq!(convolutions, "fp32"),
            _ => assert!(
                ["bf16 native", "bf16 emulated"].contains(&convolutions),
                "{report}"
            ),
        }
        assert!(report["images_per_s"].as_f64().unwrap() > 0.0, "{report}");
        assert!(report["peak_rss_mb"].as_f64().unwrap() > 0.0, "{report}");
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
    for choice in ["native", "emulated"] {
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
