//! `rtf data check`, `rtf data stats` and `rtf bench data` through the binary.

mod common;
use common::*;

#[test]
fn check_reports_every_problem_and_stats_count_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    synth_mf(&data, "12", "4", "64x48");

    let clean = rtf(&["data", "check", s(&data)]);
    assert!(
        clean.status.success(),
        "{}",
        String::from_utf8_lossy(&clean.stdout)
    );

    let stats = rtf(&["data", "stats", s(&data), "--json"]);
    assert!(stats.status.success());
    let json: serde_json::Value = serde_json::from_slice(&stats.stdout).unwrap();
    let text = json.to_string();
    assert!(
        text.contains("train") && text.contains("unlabeled"),
        "{text}"
    );

    // Two independent problems: a corrupt image and a split line naming a missing frame.
    let first = std::fs::read_to_string(data.join("train.txt"))
        .unwrap()
        .lines()
        .next()
        .unwrap()
        .trim()
        .to_string();
    std::fs::write(
        data.join("images").join(format!("{first}.png")),
        b"\x89PNG\r\n\x1a\nnot really",
    )
    .unwrap();
    let mut val = std::fs::read_to_string(data.join("val.txt")).unwrap();
    val.push_str("\nghost_frameD\n");
    std::fs::write(data.join("val.txt"), val).unwrap();
    let broken = rtf(&["data", "check", s(&data)]);
    assert!(!broken.status.success());
    let report = format!(
        "{}{}",
        String::from_utf8_lossy(&broken.stdout),
        String::from_utf8_lossy(&broken.stderr)
    );
    assert!(report.contains(&format!("{first}.png")), "{report}");
    assert!(report.contains("ghost_frameD"), "{report}");
}

#[test]
fn bench_data_reports_throughput_as_json() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    synth_mf(&data, "8", "1", "64x48");
    let out = rtf(&[
        "bench",
        "data",
        "--data",
        s(&data),
        "--frames",
        "8",
        "--batch",
        "4",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(json["frames_per_s"].as_f64().unwrap() > 0.0, "{json}");
}
