//! `rtf eval` as the field reports it: sliding windows, several scales and a flip (the official
//! CMX evaluator's modes, rtf-eval's `inference` module). On a tiny synthetic MF set: the run
//! succeeds, the printed header and the `--json` record say which mode, `rtf report` shows
//! it, and the default stays the whole image at scale 1.

mod common;
use common::*;

#[test]
fn sliding_multi_scale_flip_runs_and_the_json_and_report_record_it() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, run) = (tmp.path().join("data"), tmp.path().join("run"));
    synth_mf(&data, "8", "3", "64x48");
    ok(&short_train(&data, &run, "1", &["--model", "mfnet"]));
    let weights = run.join("final.safetensors");
    let eval = |json: &std::path::Path, extra: &[&str]| {
        let mut args = vec![
            "eval",
            "--model",
            "mfnet",
            "--weights",
            s(&weights),
            "--data",
            s(&data),
            "--split",
            "test",
            "--json",
            s(json),
        ];
        args.extend_from_slice(extra);
        ok(&args)
    };
    let modes = tmp.path().join("modes.json");
    let printed = eval(
        &modes,
        &[
            "--sliding",
            "--crop",
            "32x32",
            "--scales",
            "0.75,1",
            "--flip",
        ],
    );
    assert!(
        printed.contains("inference: sliding 32x32 (HxW), stride rate 0.667, scales 0.75,1, flip"),
        "{printed}"
    );
    let j = json_file(&modes);
    assert_eq!(j["schema"], "rtf-eval/1");
    let inference = &j["inference"];
    assert_eq!(inference["mode"], "sliding", "{inference}");
    assert_eq!(inference["crop"], serde_json::json!([32, 32]));
    assert!((inference["stride_rate"].as_f64().unwrap() - 2.0 / 3.0).abs() < 1e-12);
    assert_eq!(inference["scales"], serde_json::json!([0.75, 1.0]));
    assert_eq!(inference["flip"], true);
    assert!(j["miou"].as_f64().is_some_and(f64::is_finite), "{j}");

    let plain = tmp.path().join("plain.json");
    let printed = eval(&plain, &[]);
    assert!(
        printed.contains("inference: whole image, scale 1\n"),
        "{printed}"
    );
    let p = json_file(&plain);
    assert_eq!(
        p["inference"],
        serde_json::json!({"mode": "whole", "scales": [1.0], "flip": false})
    );
    assert_eq!(p["pixels"], j["pixels"], "the same pixels are scored");

    let page = tmp.path().join("report.html");
    ok(&[
        "report",
        s(&run),
        "--eval",
        s(&modes),
        "--out",
        s(&page),
        "--frames",
        "0",
    ]);
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(
        html.contains("inference: sliding 32x32 (HxW), stride rate 0.667, scales 0.75,1, flip"),
        "report does not show the mode"
    );

    // A crop without --sliding is refused, as is a stride rate above 1.
    let bad = tmp.path().join("bad.json");
    let mut args = vec!["eval", "--model", "mfnet", "--weights", s(&weights)];
    args.extend(["--data", s(&data), "--json", s(&bad), "--crop", "32x32"]);
    assert!(fails(&args).contains("--sliding"));
    let mut args = vec!["eval", "--model", "mfnet", "--weights", s(&weights)];
    args.extend(["--data", s(&data), "--sliding", "--stride-rate", "3/2"]);
    assert!(fails(&args).contains("stride rate"));
}
