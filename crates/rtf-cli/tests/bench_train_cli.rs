//! `rtf bench train --json` and `rtf train --precision` through the binary.

mod common;
use common::*;

#[test]
fn bench_train_reports_the_issue_fields() {
    for precision in ["fp32", "bf16"] {
        let report = json_out(&[
            "bench",
            "train",
            "--model",
            "mfnet",
            "--batch",
            "1",
            "--size",
            "32x32",
            "--precision",
            precision,
            "--warmup",
            "0",
            "--steps",
            "1",
            "--threads",
            "1",
            "--json",
        ]);
        assert_eq!(report["model"], "mfnet");
        assert_eq!(report["batch"], 1);
        assert_eq!(report["size"], "32x32");
        assert_eq!(report["precision"], precision);
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
