//! A dataset recorded as driving sequences (issue 59), end to end through dataset.yaml alone:
//! fields in folders (`images/{set}/{video}/visible/{frame}.jpg`), thermal as grey JPEG stored
//! in three channels, labels named by all fields (`labels/{set}_{video}_{frame}.png`), the
//! release's per-condition list files (lines are label file names), 19 classes with void 19
//! and class 0 road. Made from six real MSRS scenes (../shared/data/msrs-samples, RGB and
//! thermal, scaled to 64×48), labels banded from the thermal; says so and passes without the
//! shared data. Checked, trained, evaluated (day and night from the lists, one mIoU: class 0
//! is a class) and predicted by split, outputs in the set's ids and colours under the frames'
//! names (two sequences' `I00050` apart), and no file of the set changed.

use std::path::{Path, PathBuf};

mod common;
use common::*;

const W: u32 = 64;
const H: u32 = 48;

/// Cityscapes' 19 train classes and colours; void = 19.
const CLASSES: [(&str, [u8; 3]); 19] = [
    ("road", [128, 64, 128]),
    ("sidewalk", [244, 35, 232]),
    ("building", [70, 70, 70]),
    ("wall", [102, 102, 156]),
    ("fence", [190, 153, 153]),
    ("pole", [153, 153, 153]),
    ("traffic light", [250, 170, 30]),
    ("traffic sign", [220, 220, 0]),
    ("vegetation", [107, 142, 35]),
    ("terrain", [152, 251, 152]),
    ("sky", [70, 130, 180]),
    ("person", [220, 20, 60]),
    ("rider", [255, 0, 0]),
    ("car", [0, 0, 142]),
    ("truck", [0, 0, 70]),
    ("bus", [0, 60, 100]),
    ("train", [0, 80, 100]),
    ("motorcycle", [0, 0, 230]),
    ("bicycle", [119, 11, 32]),
];

/// (MSRS scene, set, video, frame, split, condition): two sequences share `I00050`.
const SCENES: [(&str, &str, &str, &str, &str, &str); 6] = [
    ("00055D", "set00", "V000", "I00050", "train", "day"),
    ("00107D", "set00", "V000", "I00051", "train", "day"),
    ("00004N", "set00", "V001", "I00050", "train", "night"),
    ("00032N", "set00", "V001", "I00051", "train", "night"),
    ("00135D", "set01", "V000", "I00050", "test", "day"),
    ("00695N", "set01", "V001", "I00050", "test", "night"),
];

fn msrs() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/msrs-samples")
}

fn yaml() -> String {
    let classes: String = CLASSES
        .iter()
        .enumerate()
        .map(|(i, (n, c))| format!("  - {{id: {i}, name: {n}, color: {c:?}}}\n"))
        .collect();
    let split = |name: &str| {
        format!(
            "  {name}:\n    rgb: \"images/{{set}}/{{video}}/visible/{{frame}}.jpg\"\n    thermal: \"images/{{set}}/{{video}}/lwir/{{frame}}.jpg\"\n    labels: \"labels/{{set}}_{{video}}_{{frame}}.png\"\n    list: [{name}_day.txt, {name}_night.txt]\n"
        )
    };
    format!(
        "name: kaist-like\nclasses:\n{classes}ignore_id: 19\nsplits:\n{}{}day: {{list: [train_day.txt, test_day.txt]}}\nnight: {{list: [train_night.txt, test_night.txt]}}\n",
        split("train"),
        split("test")
    )
}

fn scaled(path: &Path) -> image::DynamicImage {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    img.resize_exact(W, H, image::imageops::FilterType::Triangle)
}

/// Writes the sequence-layout root from the real scenes.
fn sequence_set(root: &Path) {
    let mut lists: std::collections::BTreeMap<String, String> = Default::default();
    for (scene, set, video, frame, split, condition) in SCENES {
        let seq = root.join("images").join(set).join(video);
        let rgb = scaled(&msrs().join("vi").join(format!("{scene}.png"))).to_rgb8();
        let grey = scaled(&msrs().join("ir").join(format!("{scene}.png"))).to_luma8();
        for (folder, img) in [
            ("visible", rgb),
            (
                "lwir",
                image::DynamicImage::ImageLuma8(grey.clone()).to_rgb8(),
            ),
        ] {
            let path = seq.join(folder).join(format!("{frame}.jpg"));
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            img.save_with_format(&path, image::ImageFormat::Jpeg)
                .unwrap();
        }
        // Ids 0-18 banded by the thermal, the first row void (19).
        let ids: Vec<u8> = (grey.pixels().enumerate())
            .map(|(i, p)| {
                if i < W as usize {
                    19
                } else {
                    (p.0[0] as u16 * 19 / 256) as u8
                }
            })
            .collect();
        let label = format!("{set}_{video}_{frame}.png");
        let path = root.join("labels").join(&label);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        rtf_data::pngio::write_png_u8(&path, W as usize, H as usize, 1, &ids).unwrap();
        lists
            .entry(format!("{split}_{condition}.txt"))
            .or_default()
            .push_str(&(label + "\n"));
    }
    for (file, text) in lists {
        std::fs::write(root.join(file), text).unwrap();
    }
    std::fs::write(root.join("dataset.yaml"), yaml()).unwrap();
}

/// A temporary folder holding the set as `kaist/`; None (said) without the shared data.
fn sequence_tmp() -> Option<(tempfile::TempDir, PathBuf)> {
    if !msrs().is_dir() {
        eprintln!("notice: no ../shared/data/msrs-samples; the sequence-layout test is skipped");
        return None;
    }
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("kaist");
    sequence_set(&data);
    Some((tmp, data))
}

fn predict_args<'a>(weights: &'a Path, data: &'a Path, out: &'a Path) -> Vec<&'a str> {
    vec![
        "predict",
        "--model",
        "mfnet",
        "--weights",
        s(weights),
        "--data",
        s(data),
        "--split",
        "test",
        "--out",
        s(out),
    ]
}

#[test]
fn a_sequence_recorded_set_checks_trains_evaluates_and_predicts_by_split_as_shipped() {
    let Some((tmp, data)) = sequence_tmp() else {
        return;
    };
    let before = files_of(&data);
    let check = ok(&["data", "check", s(&data)]);
    assert!(
        check.contains("road") && check.contains("0 problem"),
        "{check}"
    );
    let stats = ok(&["data", "stats", s(&data), "--json"]);
    let stats: serde_json::Value = serde_json::from_str(&stats).unwrap();
    let day_night: Vec<(String, u64, u64)> = (stats["splits"].as_array().unwrap().iter())
        .map(|s| {
            (
                s["name"].as_str().unwrap().into(),
                s["day"].as_u64().unwrap(),
                s["night"].as_u64().unwrap(),
            )
        })
        .collect();
    assert!(
        day_night.contains(&("train".into(), 2, 2)) && day_night.contains(&("test".into(), 1, 1)),
        "{stats}"
    );
    let run = tmp.path().join("run");
    ok(&short_train(
        &data,
        &run,
        "1",
        &["--model", "mfnet", "--val-split", "none"],
    ));
    let weights = run.join("final.safetensors");
    let json = tmp.path().join("eval.json");
    let printed = ok(&[
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
        s(&json),
    ]);
    assert!(
        !printed.contains("MFNet paper"),
        "class 0 is road: {printed}"
    );
    assert!(
        printed.contains("day:") && printed.contains("night:"),
        "{printed}"
    );
    let scores = json_file(&json);
    assert_eq!(scores["frames"], 2, "{scores}");
    assert!(scores["miou_mfnet"].is_null(), "{scores}");
    assert!(
        scores["day"]["miou"].is_number() && scores["night"]["miou"].is_number(),
        "{scores}"
    );
    let pred = tmp.path().join("pred");
    ok(&predict_args(&weights, &data, &pred));
    let palette: Vec<[u8; 3]> = CLASSES.iter().map(|(_, c)| *c).collect();
    for video in ["V000", "V001"] {
        let stem = pred.join("set01").join(video).join("I00050");
        let ids = image::open(stem.with_extension("png")).unwrap().to_luma8();
        assert!(ids.pixels().all(|p| p.0[0] < 19), "the set's ids 0-18");
        let colour = image::open(pred.join(format!("set01/{video}/I00050_color.png")))
            .unwrap()
            .to_rgb8();
        assert!(
            colour.pixels().all(|p| palette.contains(&p.0)),
            "the set's colours"
        );
    }
    // Several pairs in one call; two named alike would write one output: refused first.
    let pair = |video: &str, frame: &str, folder: &str| {
        data.join(format!("images/set00/{video}/{folder}/{frame}.jpg"))
    };
    let (rgb_a, th_a) = (
        pair("V000", "I00050", "visible"),
        pair("V000", "I00050", "lwir"),
    );
    let (rgb_b, th_b) = (
        pair("V001", "I00050", "visible"),
        pair("V001", "I00050", "lwir"),
    );
    let (rgb_c, th_c) = (
        pair("V000", "I00051", "visible"),
        pair("V000", "I00051", "lwir"),
    );
    let pairs = tmp.path().join("pairs");
    let with = |b: &Path, tb: &Path| {
        let mut args = vec!["predict", "--model", "mfnet", "--weights", s(&weights)];
        args.extend([
            "--out",
            s(&pairs),
            "--rgb",
            s(&rgb_a),
            "--thermal",
            s(&th_a),
        ]);
        args.extend(["--rgb", s(b), "--thermal", s(tb)]);
        args.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let args = with(&rgb_b, &th_b);
    let err = fails(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(err.contains("would both write") && !pairs.exists(), "{err}");
    let args = with(&rgb_c, &th_c);
    ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(pairs.join("I00050.png").is_file() && pairs.join("I00051_color.png").is_file());
    let inside = data.join("pred");
    let err = fails(&predict_args(&weights, &data, &inside));
    assert!(
        err.contains("inside the dataset") && !inside.exists(),
        "{err}"
    );
    assert_eq!(files_of(&data), before, "no file of the set changed");
}

#[test]
fn a_night_list_in_another_naming_stops_the_commands_naming_the_list_and_line() {
    let Some((_tmp, data)) = sequence_tmp() else {
        return;
    };
    std::fs::write(
        data.join("test_night.txt"),
        "set01_V001_I00050.png\nset07_V000_I00050.png\n",
    )
    .unwrap();
    for args in [
        vec!["data", "stats", s(&data)],
        vec!["data", "check", s(&data)],
    ] {
        let out = rtf(&args);
        let said = text(&out);
        assert!(!out.status.success(), "{said}");
        assert!(
            said.contains("test_night.txt") && said.contains("line 2"),
            "{said}"
        );
        for line in said.lines().filter(|l| l.contains("test_night.txt")) {
            assert_eq!(
                line.matches("test_night.txt").count(),
                1,
                "named once: {line}"
            );
        }
    }
    std::fs::remove_file(data.join("dataset.yaml")).unwrap();
    let out = rtf(&["data", "check", s(&data)]);
    let err = text(&out);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("no layout rtf knows") && err.contains("MF: images/ holds folders"),
        "{err}"
    );
    assert!(
        err.contains("labels: \"labels/{set}_{v}_{frame}.png\""),
        "{err}"
    );
    assert!(!err.contains(".png.png"), "{err}");
}
