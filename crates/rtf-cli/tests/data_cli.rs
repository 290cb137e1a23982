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

/// A plain-layout root as a user would write it: dataset.yaml, 16-bit thermal, two classes.
fn plain_dataset(root: &std::path::Path, yaml: &str) {
    use rtf_data::pngio::{write_png_u16, write_png_u8};
    let (w, h) = (8, 6);
    for split in ["train", "test"] {
        for name in ["f1", "f2"] {
            let file = |folder: &str| root.join(split).join(folder).join(format!("{name}.png"));
            let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i % 256) as u8).collect();
            write_png_u8(&file("rgb"), w, h, 3, &rgb).unwrap();
            let counts: Vec<u16> = (0..w * h).map(|i| 21800 + 50 * i as u16).collect();
            write_png_u16(&file("thermal"), w, h, 1, &counts).unwrap();
            let ids: Vec<u8> = (0..w * h).map(|i| (i % 2) as u8).collect();
            write_png_u8(&file("labels"), w, h, 1, &ids).unwrap();
        }
    }
    std::fs::write(root.join("dataset.yaml"), yaml).unwrap();
}

const PLAIN_YAML: &str = "classes:
  - {id: 0, name: background, color: [0, 0, 0]}
  - {id: 1, name: pedestrian, color: [220, 20, 60]}
ignore_id: 255
thermal:
  range: [21800, 25000]
";

#[test]
fn check_and_stats_name_the_plain_layout_its_classes_and_thermal_rule() {
    let tmp = tempfile::tempdir().unwrap();
    plain_dataset(tmp.path(), PLAIN_YAML);
    let out = ok(&["data", "check", s(tmp.path())]);
    let first = out.lines().next().unwrap();
    assert!(first.contains("plain (dataset.yaml)"), "{out}");
    assert!(
        first.contains("2 classes") && first.contains("background, pedestrian"),
        "{out}"
    );
    assert!(first.contains("range [21800, 25000]"), "{out}");
    let stats = ok(&["data", "stats", s(tmp.path())]);
    let pedestrian = stats.lines().find(|l| l.contains("pedestrian")).unwrap();
    // Half of the 4 x 48 labelled pixels.
    assert!(
        pedestrian.contains("50.0000 %") && pedestrian.contains(" 96 px"),
        "{stats}"
    );
    let fp = ok(&["data", "fingerprint", s(tmp.path())]);
    assert!(fp.contains("train") && fp.contains("test"), "{fp}");
    // The dataset.yaml given as the file is its folder: the same report, the same hashes.
    let yaml = tmp.path().join("dataset.yaml");
    assert_eq!(ok(&["data", "check", s(&yaml)]), out);
    assert_eq!(ok(&["data", "fingerprint", s(&yaml)]), fp);
}

#[test]
fn check_refuses_16_bit_thermal_without_a_rule_and_a_bad_description() {
    let tmp = tempfile::tempdir().unwrap();
    let no_rule = PLAIN_YAML.replace("thermal:\n  range: [21800, 25000]\n", "");
    plain_dataset(tmp.path(), &no_rule);
    let failed = |args: &[&str]| {
        let out = rtf(args);
        assert!(!out.status.success(), "rtf {args:?} should fail");
        text(&out)
    };
    let out = failed(&["data", "check", s(tmp.path())]);
    assert!(
        out.contains("train/thermal/f1.png")
            && out.contains("16-bit thermal needs a normalisation"),
        "{out}"
    );
    let typo = PLAIN_YAML.replace("ignore_id", "ignore_idd");
    std::fs::write(tmp.path().join("dataset.yaml"), typo).unwrap();
    let out = failed(&["data", "check", s(tmp.path())]);
    assert!(
        out.contains("dataset.yaml") && out.contains("ignore_idd") && out.contains("line 4"),
        "{out}"
    );
}

/// A PST900 root (train and test, 4 frames each, 64x48, 5 classes in horizontal bands).
fn pst900_root(data: &std::path::Path) {
    use rtf_data::pngio::write_png_u8;
    let (w, h) = (64, 48);
    for split in ["train", "test"] {
        for k in 0..4u8 {
            let file = |folder: &str| data.join(split).join(folder).join(format!("f{k}.png"));
            let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i % 253) as u8 ^ k).collect();
            write_png_u8(&file("rgb"), w, h, 3, &rgb).unwrap();
            let thermal: Vec<u8> = (0..w * h).map(|i| (i % 256) as u8).collect();
            write_png_u8(&file("thermal"), w, h, 1, &thermal).unwrap();
            let ids: Vec<u8> = (0..w * h).map(|i| ((i / w) * 5 / h) as u8).collect();
            write_png_u8(&file("labels"), w, h, 1, &ids).unwrap();
        }
    }
}

/// Fine-tuning onto a new class set (issue 26 §4): a 9-class MF run's weights start a
/// 5-class PST900 run under `--reset-head` (stderr names the tensors that start fresh);
/// without it the error names the head's tensors and suggests the flag.
#[test]
fn nine_class_weights_fine_tune_onto_five_classes_with_reset_head() {
    let tmp = tempfile::tempdir().unwrap();
    let (mf, pst) = (tmp.path().join("mf"), tmp.path().join("pst900"));
    synth_mf(&mf, "8", "1", "64x48");
    pst900_root(&pst);
    let first = tmp.path().join("mf-run");
    ok(&short_train(
        &mf,
        &first,
        "1",
        &["--model", "mfnet", "--val-split", "none"],
    ));
    let nine = first.join("final.safetensors");
    let init = ["--model", "mfnet", "--init", s(&nine)];

    let refused = tmp.path().join("refused");
    let err = fails(&short_train(&pst, &refused, "1", &init));
    assert!(
        err.contains("decode1.conv.weight") && err.contains("--reset-head"),
        "{err}"
    );
    assert!(
        !refused.exists(),
        "nothing written for weights that do not fit"
    );

    let run = tmp.path().join("tuned");
    let mut args = init.to_vec();
    args.push("--reset-head");
    let out = rtf(&short_train(&pst, &run, "1", &args));
    let printed = text(&out);
    assert!(out.status.success(), "{printed}");
    assert!(
        printed.contains("init: 222 of 228 tensors loaded from"),
        "{printed}"
    );
    assert!(
        printed.contains("start fresh (--reset-head): decode1.bn.bias, decode1.bn.running_mean"),
        "{printed}"
    );
    let config = json_file(&run.join("config.json"));
    assert_eq!(config["network"]["init_reset_head"], true, "{config}");
    assert_eq!(config["network"]["model"]["num_classes"], 5, "{config}");
}

/// A PST900 root (train and test only, 5 classes) trains without validation, says so, and
/// its weights have 5 outputs that `rtf eval` scores by class name.
#[test]
fn a_five_class_pst900_root_trains_without_val_and_evaluates_by_class_name() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, run) = (tmp.path().join("pst900"), tmp.path().join("run"));
    pst900_root(&data);
    let out = rtf(&short_train(&data, &run, "1", &["--model", "mfnet"]));
    let printed = text(&out);
    assert!(out.status.success(), "{printed}");
    assert!(printed.contains("PST900 layout; 5 classes"), "{printed}");
    assert!(printed.contains("validation skipped"), "{printed}");
    let config = json_file(&run.join("config.json"));
    assert_eq!(config["network"]["model"]["num_classes"], 5, "{config}");
    let weights = run.join("final.safetensors");
    let table = ok(&[
        "eval",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--data",
        s(&data),
        "--split",
        "test",
    ]);
    assert!(
        table.contains("hand_drill") && table.contains("survivor"),
        "{table}"
    );
    // predict paints in the dataset's palette and writes ids of its 5 classes.
    let predicted = tmp.path().join("pred");
    let (rgb, thermal) = (
        data.join("test/rgb/f0.png"),
        data.join("test/thermal/f0.png"),
    );
    ok(&[
        "predict",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--out",
        s(&predicted),
        "--classes",
        s(&data),
        "--rgb",
        s(&rgb),
        "--thermal",
        s(&thermal),
    ]);
    let ids = rtf_data::pngio::read_png(&predicted.join("f0.png")).unwrap();
    let rtf_data::pngio::Samples::U8(ids) = ids.samples else {
        panic!("8-bit ids")
    };
    assert!(ids.iter().all(|&id| id < 5), "ids of the 5 PST900 classes");
    let colors = rtf_data::pngio::read_png(&predicted.join("f0_color.png")).unwrap();
    let rtf_data::pngio::Samples::U8(colors) = colors.samples else {
        panic!("8-bit colours")
    };
    let palette = rtf_data::layouts::pst900::CLASSES.map(|(_, c)| c);
    for (pixel, &id) in colors.chunks_exact(3).zip(&ids) {
        assert_eq!(pixel, palette[id as usize], "PST900 palette");
    }
    // Validation: none without a val split; every 2nd training frame with holdout:2.
    let held = tmp.path().join("held");
    let holdout = ["--model", "mfnet", "--val-split", "holdout:2"];
    let out = rtf(&short_train(&data, &held, "1", &holdout));
    let printed = text(&out);
    assert!(out.status.success(), "{printed}");
    assert!(
        printed.contains("1 in 2 frames of `train`, held out"),
        "{printed}"
    );
    let first_epoch = |run: &std::path::Path| {
        rtf_run::log::read(&run.join("log.jsonl"))
            .unwrap()
            .remove(0)
    };
    assert!(
        first_epoch(&run).val_miou.is_none(),
        "no validation without val"
    );
    let record = first_epoch(&held);
    assert!(
        record.val_miou.is_some(),
        "validated on the held-out part: {record:?}"
    );
    let err = fails(&[
        "train",
        "--data",
        s(&data),
        "--out",
        s(&tmp.path().join("r2")),
        "--val-split",
        "val",
    ]);
    assert!(
        err.contains("no split `val`") && err.contains("train, test"),
        "{err}"
    );
}
