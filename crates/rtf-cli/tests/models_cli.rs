//! `rtf models --json` and `rtf bench model --json` through the binary.

mod common;
use common::*;

#[test]
fn models_lists_every_network_with_reference_counts() {
    let list = json_out(&["models", "--json"]);
    let rows = list.as_array().unwrap();
    let params = |name: &str| {
        rows.iter()
            .find(|r| r["name"] == name)
            .unwrap_or_else(|| panic!("{name} missing"))["params"]
            .as_i64()
            .unwrap()
    };
    // Reference counts (spec §3–5).
    assert_eq!(params("mfnet"), 736_275);
    assert_eq!(params("rtfnet50"), 185_238_501);
    assert_eq!(params("heatnet"), 54_361_040);
    assert_eq!(params("heatnet-critic"), 2_774_977);
    // CMX (the official EncoderDecoder's count, lab/parity/cmx_reference.py --count).
    assert_eq!(params("cmx-mit-b2"), 66_565_521);
    for name in [
        "rtfnet152-fci",
        "rtfnet18-nre",
        "erfnet-4c",
        "unet-3c",
        "fusenet",
        "enet-3c",
        "mfnet-n",
        "heatnet-ir",
    ] {
        assert!(params(name) > 0, "{name}");
    }
    let mfnet = rows.iter().find(|r| r["name"] == "mfnet").unwrap();
    let megabytes = mfnet["megabytes"].as_f64().unwrap();
    assert!((megabytes - 736_275.0 * 4.0 / 1048576.0).abs() < 1e-9);
}

#[test]
fn bench_model_reports_timings_as_json() {
    let r = json_out(&[
        "bench",
        "model",
        "--model",
        "mfnet",
        "--size",
        "64x48",
        "--warmup",
        "1",
        "--iterations",
        "2",
        "--json",
    ]);
    assert_eq!(r["model"], "mfnet");
    assert_eq!(r["batch"], 1);
    assert_eq!(r["precision"], "fp32");
    let (median, min, fps) = (
        r["median_ms"].as_f64().unwrap(),
        r["min_ms"].as_f64().unwrap(),
        r["fps"].as_f64().unwrap(),
    );
    assert!(min > 0.0 && min <= median, "{r}");
    assert!(fps > 0.0, "{r}");
}
