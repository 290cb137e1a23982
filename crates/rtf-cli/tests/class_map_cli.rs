//! `rtf eval --class-map`: a network trained on the MF layout scored on a Freiburg Thermal
//! root (another class set) through the built-in map of HeatNet Tab. I and through a user's
//! YAML map; a bad map is refused naming its file and the class before anything runs.

mod common;
use common::*;

use std::path::Path;

/// IoU of class `c` from a confusion matrix given as JSON rows (truth, then prediction).
fn iou_by_hand(confusion: &serde_json::Value, c: usize) -> Option<f64> {
    let m: Vec<Vec<u64>> = serde_json::from_value(confusion.clone()).unwrap();
    let tp = m[c][c];
    let truth: u64 = m[c].iter().sum();
    let predicted: u64 = m.iter().map(|row| row[c]).sum();
    let union = truth + predicted - tp;
    (union > 0).then(|| tp as f64 / union as f64)
}

fn eval_args<'a>(weights: &'a Path, data: &'a Path, json: &'a Path, map: &'a str) -> Vec<&'a str> {
    vec![
        "eval",
        "--model",
        "mfnet",
        "--weights",
        s(weights),
        "--data",
        s(data),
        "--split",
        "test",
        "--resize",
        "64x48",
        "--json",
        s(json),
        "--class-map",
        map,
    ]
}

#[test]
fn an_mf_network_is_scored_on_freiburg_through_the_papers_map_and_a_users() {
    let tmp = tempfile::tempdir().unwrap();
    let (mf, fr, run) = (
        tmp.path().join("mf"),
        tmp.path().join("fr"),
        tmp.path().join("run"),
    );
    synth_mf(&mf, "8", "3", "64x48");
    ok(&[
        "synth",
        "--format",
        "freiburg",
        "--out",
        s(&fr),
        "--count",
        "12",
        "--size",
        "64x48",
    ]);
    ok(&short_train(&mf, &run, "1", &["--model", "mfnet"]));
    let weights = run.join("final.safetensors");

    // Without a map the class sets differ: refused, naming both.
    let plain = fails(&[
        "eval",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--data",
        s(&fr),
        "--split",
        "test",
    ]);
    assert!(
        plain.contains("bicycle") && plain.contains("bike"),
        "{plain}"
    );

    let json = tmp.path().join("mapped.json");
    let mut args = eval_args(&weights, &fr, &json, "mf-to-freiburg");
    args.extend(["--drop", "thermal"]);
    let printed = ok(&args);
    assert!(
        printed.contains("class map mf-to-freiburg (built-in): scored person, car, bicycle"),
        "{printed}"
    );
    assert!(
        printed.contains("mIoU over the scored classes"),
        "{printed}"
    );
    let j = json_file(&json);
    assert_eq!(
        j["class_names"],
        serde_json::json!(["person", "car", "bicycle", "other"])
    );
    let map = &j["class_map"];
    assert_eq!(map["name"], "mf-to-freiburg");
    assert_eq!(map["source"], "built-in");
    assert_eq!(
        map["scored"],
        serde_json::json!(["person", "car", "bicycle"])
    );
    assert_eq!(map["network"]["bicycle"], serde_json::json!(["bike"]));
    assert_eq!(map["data"]["bicycle"], serde_json::json!(["bicycle"]));
    assert!(j.get("heatnet").is_none(), "no 13-class HeatNet mIoU: {j}");
    // The scores are the matrix's: each class IoU by hand, the mean over the defined ones.
    let mut defined = Vec::new();
    for c in 0..4 {
        let by_hand = iou_by_hand(&j["confusion"], c);
        let reported = j["per_class"][c]["iou"].as_f64();
        match (by_hand, reported) {
            (Some(a), Some(b)) => assert!((a - b).abs() < 1e-12, "class {c}: {a} vs {b}"),
            (a, b) => assert_eq!(a, b, "class {c}"),
        }
        if c < 3 {
            defined.extend(by_hand);
        }
    }
    let total: u64 = serde_json::from_value::<Vec<Vec<u64>>>(j["confusion"].clone())
        .unwrap()
        .iter()
        .flatten()
        .sum();
    assert_eq!(Some(total), j["pixels"].as_u64());
    assert!(total > 0);
    match map["miou"].as_f64() {
        Some(m) => {
            let mean = defined.iter().sum::<f64>() / defined.len() as f64;
            assert!((m - mean).abs() < 1e-12, "{m} vs {mean}");
        }
        None => assert!(defined.is_empty()),
    }
    assert_eq!(
        j["dropped"].as_array().map(Vec::len),
        Some(1),
        "--drop through the map"
    );

    // A user's map: people only, the other classes' pixels dropped.
    let yaml = tmp.path().join("people.yaml");
    std::fs::write(
        &yaml,
        "classes:\n  - name: people\n    network: [person]\n    data: [person]\n\
         other_pixels: ignored\n",
    )
    .unwrap();
    let mine = tmp.path().join("mine.json");
    ok(&eval_args(&weights, &fr, &mine, s(&yaml)));
    let m = json_file(&mine);
    assert_eq!(m["class_names"], serde_json::json!(["people", "other"]));
    assert_eq!(m["class_map"]["name"], "people");
    assert_eq!(m["class_map"]["other_pixels"], "ignored");
    assert_eq!(
        m["confusion"][1],
        serde_json::json!([0, 0]),
        "no other truth"
    );

    // Bad maps: named with the class, before anything is written.
    let bad = tmp.path().join("bad.yaml");
    let refused = tmp.path().join("refused.json");
    for (text, needle) in [
        (
            "classes:\n  - name: p\n    network: [pedestrian]\n    data: [person]\n",
            "`pedestrian`",
        ),
        (
            "classes:\n  - name: p\n    network: [person]\n    data: [40]\n",
            "id 40",
        ),
        ("classes:\n  - name: p\n    network: [person\n", "line"),
    ] {
        std::fs::write(&bad, text).unwrap();
        let err = fails(&eval_args(&weights, &fr, &refused, s(&bad)));
        assert!(
            err.contains("bad.yaml") && err.contains(needle),
            "{needle}: {err}"
        );
        assert!(!refused.exists());
    }
    let err = fails(&eval_args(&weights, &fr, &refused, "mf-to-nowhere"));
    assert!(
        err.contains("mf-to-nowhere") && err.contains("freiburg-to-mf"),
        "{err}"
    );
}
