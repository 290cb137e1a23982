//! A dataset as public RGB-T releases ship it (issue 43), end to end through the commands with
//! no file renamed or converted: RGB as JPEG, thermal as LZW-compressed 16-bit TIFF of raw
//! counts, file names that differ per modality (`color/{seq}_eo-{n}.jpg`,
//! `thermal16/{seq}_thermal-{n}.tiff`, `annotations/{seq}_mask-{n}.png`), the dataset's own
//! split files (paths, two per line, commas or tabs), label ids from 1 with 0 ignored, class
//! colours in hex. The fixture is the
//! worked example of docs/src/bring-your-data.md, generated here in that exact form.

use std::path::Path;

mod common;
use common::*;

const W: u32 = 64;
const H: u32 = 48;

pub const DATASET_YAML: &str = "name: roads
classes:
  - {id: 1, name: background, color: \"#000000\"}
  - {id: 2, name: person, color: \"#DC143C\"}
  - {id: 3, name: car, color: \"#00008E\"}
ignore_id: 0
thermal:
  range: [21800, 25000]
splits:
  train:
    rgb: \"color/{seq}_eo-{n}.jpg\"
    thermal: \"thermal16/{seq}_thermal-{n}.tiff\"
    labels: \"annotations/{seq}_mask-{n}.png\"
    list: splits/train.txt
  test:
    rgb: \"color/{seq}_eo-{n}.jpg\"
    thermal: \"thermal16/{seq}_thermal-{n}.tiff\"
    labels: \"annotations/{seq}_mask-{n}.png\"
    list: splits/test.txt
";

/// One frame: a JPEG, a 16-bit LZW TIFF and an id PNG with three horizontal class bands.
fn write_frame(root: &Path, seq: &str, n: u32) {
    use rtf_data::tiffio::{encode_grey, GreyPlane, TiffCompression};
    let (w, h) = (W as usize, H as usize);
    let file = |dir: &str, name: String| {
        let path = root.join(dir).join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        path
    };
    let rgb: Vec<u8> = (0..w * h * 3)
        .map(|i| ((i / 3) % 200) as u8 + n as u8)
        .collect();
    image::save_buffer(
        file("color", format!("{seq}_eo-{n}.jpg")),
        &rgb,
        W,
        H,
        image::ExtendedColorType::Rgb8,
    )
    .unwrap();
    let counts: Vec<u16> = (0..w * h).map(|i| 21800 + (i % 3200) as u16).collect();
    let tiff = encode_grey(W, H, GreyPlane::U16(&counts), TiffCompression::Lzw).unwrap();
    std::fs::write(file("thermal16", format!("{seq}_thermal-{n}.tiff")), tiff).unwrap();
    // Ids 1-3 in horizontal bands, the first row 0 (unlabelled: ignored).
    let ids: Vec<u8> = (0..w * h)
        .map(|i| if i < w { 0 } else { (i / w * 3 / h) as u8 + 1 })
        .collect();
    let label = file("annotations", format!("{seq}_mask-{n}.png"));
    rtf_data::pngio::write_png_u8(&label, w, h, 1, &ids).unwrap();
}

/// The worked example's root: sequences `day_a` (frames 1-3) and `night_b` (1-2).
fn roads(root: &Path) {
    for (seq, n) in [
        ("day_a", 1),
        ("day_a", 2),
        ("day_a", 3),
        ("night_b", 1),
        ("night_b", 2),
    ] {
        write_frame(root, seq, n);
    }
    std::fs::write(root.join("dataset.yaml"), DATASET_YAML).unwrap();
    std::fs::create_dir_all(root.join("splits")).unwrap();
    std::fs::write(
        root.join("splits/train.txt"),
        "color/day_a_eo-1.jpg,annotations/day_a_mask-1.png\n\
         color/day_a_eo-2.jpg,annotations/day_a_mask-2.png\n\
         color/night_b_eo-1.jpg,annotations/night_b_mask-1.png\n",
    )
    .unwrap();
    std::fs::write(
        root.join("splits/test.txt"),
        "color/day_a_eo-3.jpg\tthermal16/day_a_thermal-3.tiff\nnight_b/2\n",
    )
    .unwrap();
}

#[test]
fn a_dataset_as_distributed_checks_trains_evaluates_predicts_and_reports_unconverted() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("roads");
    roads(&data);
    let before = files_of(&data);
    let check = ok(&["data", "check", s(&data)]);
    assert!(
        check.contains("roads") && check.contains("person"),
        "{check}"
    );
    let run = tmp.path().join("run");
    let trained = rtf(&short_train(
        &data,
        &run,
        "1",
        &["--model", "mfnet", "--val-split", "none"],
    ));
    let printed = text(&trained);
    assert!(trained.status.success(), "{printed}");
    assert!(printed.contains("background, person, car"), "{printed}");
    let weights = run.join("final.safetensors");
    let json = tmp.path().join("eval.json");
    ok(&[
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
    let scores = json_file(&json);
    assert_eq!(
        scores["class_names"],
        serde_json::json!(["background", "person", "car"])
    );
    assert_eq!(scores["frames"], 2, "{scores}");
    let pred = tmp.path().join("pred");
    ok(&[
        "predict",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--out",
        s(&pred),
        "--rgb",
        s(&data.join("color/day_a_eo-3.jpg")),
        "--thermal",
        s(&data.join("thermal16/day_a_thermal-3.tiff")),
    ]);
    let ids = image::open(pred.join("day_a_eo-3.png")).unwrap().to_luma8();
    assert!(
        ids.pixels().all(|p| (1..=3).contains(&p.0[0])),
        "the dataset's ids, 1-3"
    );
    let colour = image::open(pred.join("day_a_eo-3_color.png"))
        .unwrap()
        .to_rgb8();
    let palette = [[0u8, 0, 0], [220, 20, 60], [0, 0, 142]];
    assert!(
        colour.pixels().all(|p| palette.contains(&p.0)),
        "the hex palette"
    );
    let html = tmp.path().join("report.html");
    ok(&["report", s(&run), "--eval", s(&json), "--out", s(&html)]);
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(
        page.contains("person") && page.contains("car"),
        "the report names the classes"
    );
    assert_eq!(files_of(&data), before, "nothing written into the dataset");
}

#[test]
fn bad_list_lines_and_patterns_stop_before_a_run_folder_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("roads");
    roads(&data);
    let run = tmp.path().join("run");
    let train = |run: &Path| fails(&short_train(&data, run, "1", &["--model", "mfnet"]));
    std::fs::write(
        data.join("splits/train.txt"),
        "color/day_a_eo-1.jpg,annotations/day_a_mask-2.png\n",
    )
    .unwrap();
    let err = train(&run);
    assert!(
        err.contains("train.txt") && err.contains("line 1") && err.contains("day_a/2"),
        "{err}"
    );
    assert!(!run.exists(), "no run folder");
    std::fs::write(
        data.join("splits/train.txt"),
        "day_a/1\nrgb/x.jpg thermal/x.tiff\n",
    )
    .unwrap();
    let err = train(&run);
    assert!(
        err.contains("line 2") && err.contains("matches none"),
        "{err}"
    );
    std::fs::write(data.join("splits/train.txt"), "day_a/1\n").unwrap();
    let yaml = DATASET_YAML.replace("\"thermal16/{seq}_thermal-{n}.tiff\"\n    labels: \"annotations/{seq}_mask-{n}.png\"\n    list: splits/train.txt", "\"thermal16/{seq}.tiff\"\n    list: splits/train.txt");
    std::fs::write(data.join("dataset.yaml"), yaml).unwrap();
    let err = train(&run);
    assert!(
        err.contains("dataset.yaml") && err.contains("{seq}"),
        "{err}"
    );
    std::fs::write(
        data.join("dataset.yaml"),
        DATASET_YAML.replace("#DC143C", "#DC143"),
    )
    .unwrap();
    let err = train(&run);
    assert!(
        err.contains("dataset.yaml") && err.contains("#DC143"),
        "{err}"
    );
    assert!(!run.exists(), "no run folder");
}
