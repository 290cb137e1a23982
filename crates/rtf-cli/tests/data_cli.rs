//! `rtf data check`, `rtf data stats`, `rtf data fingerprint` and `rtf bench data` through
//! the binary.

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

#[test]
fn fingerprint_names_every_split_and_follows_the_content() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    synth_mf(&data, "8", "2", "32x32");
    let fp = json_out(&["data", "fingerprint", s(&data), "--json"]);
    assert_eq!(fp["format"], "mf");
    assert_eq!(fp["algorithm"], "sha256");
    let splits: Vec<&str> = fp["splits"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["name"].as_str().unwrap())
        .collect();
    for split in ["train", "val", "test", "test_day", "test_night"] {
        assert!(splits.contains(&split), "{split} in {splits:?}");
    }
    let table = ok(&["data", "fingerprint", s(&data)]);
    assert!(table.contains(fp["hash"].as_str().unwrap()), "{table}");

    // A copy hashes the same; editing one training image changes train and the whole only.
    let copy = tmp.path().join("copy");
    std::fs::create_dir_all(copy.join("images")).unwrap();
    std::fs::create_dir_all(copy.join("labels")).unwrap();
    for entry in walk(&data) {
        let rel = entry.strip_prefix(&data).unwrap();
        std::fs::copy(&entry, copy.join(rel)).unwrap();
    }
    let same = json_out(&["data", "fingerprint", s(&copy), "--json"]);
    assert_eq!(same["hash"], fp["hash"]);
    let train = std::fs::read_to_string(copy.join("train.txt")).unwrap();
    let name = train.lines().next().unwrap().trim();
    let image = copy.join("images").join(format!("{name}.png"));
    let mut bytes = std::fs::read(&image).unwrap();
    bytes.push(0); // trailing byte: still a valid PNG, other content
    std::fs::write(&image, bytes).unwrap();
    let edited = json_out(&["data", "fingerprint", s(&copy), "--json"]);
    assert_ne!(edited["hash"], fp["hash"]);
    let split_hash = |v: &serde_json::Value, name: &str| {
        v["splits"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["name"] == name)
            .unwrap()["hash"]
            .clone()
    };
    assert_ne!(split_hash(&edited, "train"), split_hash(&fp, "train"));
    assert_eq!(split_hash(&edited, "test"), split_hash(&fp, "test"));
}

#[test]
fn check_names_odd_sizes_leaks_and_duplicates() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    synth_mf(&data, "8", "3", "32x32");
    let train: Vec<String> = std::fs::read_to_string(data.join("train.txt"))
        .unwrap()
        .lines()
        .map(|l| l.trim().to_string())
        .collect();
    // An odd-sized frame (image and label agree), a train frame listed in test too, and one
    // image copied over another.
    image::RgbaImage::new(40, 32)
        .save(data.join("images").join(format!("{}.png", train[0])))
        .unwrap();
    image::GrayImage::new(40, 32)
        .save(data.join("labels").join(format!("{}.png", train[0])))
        .unwrap();
    let mut test = std::fs::read_to_string(data.join("test.txt")).unwrap();
    test.push_str(&format!("{}\n", train[1]));
    std::fs::write(data.join("test.txt"), test).unwrap();
    std::fs::copy(
        data.join("images").join(format!("{}.png", train[2])),
        data.join("images").join(format!("{}.png", train[3])),
    )
    .unwrap();
    let out = rtf(&["data", "check", s(&data)]);
    assert_eq!(out.status.code(), Some(1));
    let report = text(&out);
    for needle in [
        format!(
            "images/{}.png: is 40x32 but 7 of 8 frames are 32x32",
            train[0]
        ),
        format!("'{}' is also in split 'train'", train[1]),
        "same bytes as".to_string(),
    ] {
        assert!(report.contains(&needle), "{needle} not in:\n{report}");
    }
    let json = rtf(&["data", "check", s(&data), "--json"]);
    let parsed: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    assert!(
        parsed["problems"].as_array().unwrap().len() >= 3,
        "{parsed}"
    );
}

fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}
