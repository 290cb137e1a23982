//! Data as distributed (issue 43): broken JPEG and TIFF files, TIFF layouts rtf does not read,
//! named-field patterns and list files gone wrong, a hex colour that is not one, float thermal
//! without a rule — each refused naming the file (and line), before a run folder is written.
//! And outputs that would land on the data: predict into a dataset's label folder, eval's JSON
//! over a label, a run folder in the dataset's root — refused, the data intact.

use std::path::{Path, PathBuf};

use rtf_data::tiffio::{encode_grey, GreyPlane, TiffCompression};

use crate::common::*;
use crate::owndata::{plain_root, YAML};
use crate::verdict::{case, Case};
use crate::Fixture;

const PATTERNS: &str = "splits:
  train: {rgb: \"color/{seq}_eo-{n}.jpg\", thermal: \"ir/{seq}_ir-{n}.tiff\", list: train.txt}
";

/// `root`: two frames of sequence `s` as JPEG + 16-bit TIFF, listed in `train.txt` by paths.
fn distributed_root(f: &Fixture, name: &str, yaml_extra: &str) -> PathBuf {
    let root = f.t.join(name);
    for dir in ["color", "ir"] {
        std::fs::create_dir_all(root.join(dir)).unwrap();
    }
    for n in 1..=2 {
        image::RgbImage::from_fn(32, 32, |x, y| {
            image::Rgb([(x * 8) as u8, (y * 8) as u8, 90])
        })
        .save(root.join(format!("color/s_eo-{n}.jpg")))
        .unwrap();
        let counts: Vec<u16> = (0..32 * 32).map(|i| 21800 + i as u16).collect();
        let tiff = encode_grey(32, 32, GreyPlane::U16(&counts), TiffCompression::Lzw).unwrap();
        std::fs::write(root.join(format!("ir/s_ir-{n}.tiff")), tiff).unwrap();
    }
    let yaml = format!("{YAML}thermal: {{range: [21800, 25000]}}\n{PATTERNS}{yaml_extra}");
    std::fs::write(root.join("dataset.yaml"), yaml).unwrap();
    std::fs::write(
        root.join("train.txt"),
        "color/s_eo-1.jpg,ir/s_ir-1.tiff\ns/2\n",
    )
    .unwrap();
    root
}

fn check(name: &str, root: &Path, must: &[&str]) -> Case {
    case(
        &format!("as distributed: {name}"),
        &["data", "check", s(root)],
        must,
    )
}

fn train(f: &Fixture, name: &str, root: &Path, must: &[&str]) -> Case {
    let out = f.t.join(format!("{name}-run").replace(' ', "_"));
    let args = short_train(root, &out, "1", &["--val-split", "none"]);
    let written = out.join("config.json");
    case(&format!("as distributed: train, {name}"), &args, must).intact(move || !written.exists())
}

/// Files broken one way each.
fn file_cases(f: &Fixture) -> Vec<Case> {
    let truncated = distributed_root(f, "ad_jpeg", "");
    let jpeg = truncated.join("color/s_eo-2.jpg");
    let bytes = std::fs::read(&jpeg).unwrap();
    std::fs::write(&jpeg, &bytes[..bytes.len() / 3]).unwrap();
    let twelve = distributed_root(f, "ad_tiff12", "");
    std::fs::write(twelve.join("ir/s_ir-2.tiff"), twelve_bit_tiff()).unwrap();
    let float = distributed_root(f, "ad_float", "");
    let temps = vec![21.5f32; 32 * 32];
    let tiff = encode_grey(32, 32, GreyPlane::F32(&temps), TiffCompression::None).unwrap();
    std::fs::write(float.join("ir/s_ir-1.tiff"), tiff).unwrap();
    let yaml = std::fs::read_to_string(float.join("dataset.yaml")).unwrap();
    std::fs::write(
        float.join("dataset.yaml"),
        yaml.replace("thermal: {range: [21800, 25000]}\n", ""),
    )
    .unwrap();
    let renamed = distributed_root(f, "ad_renamed", "");
    let png = rtf_data::pngio::encode_png_u8(32, 32, 3, &[7; 32 * 32 * 3]).unwrap();
    std::fs::write(renamed.join("color/s_eo-1.jpg"), png).unwrap();
    vec![
        check("truncated JPEG", &truncated, &["s_eo-2.jpg", "JPEG"]),
        train(f, "truncated JPEG", &truncated, &["s_eo-2.jpg", "JPEG"]),
        check("12-bit packed TIFF", &twelve, &["s_ir-2.tiff", "12-bit"]),
        check(
            "float thermal without a rule",
            &float,
            &["s_ir-1.tiff", "needs a rule"],
        ),
        train(
            f,
            "float thermal without a rule",
            &float,
            &["s_ir-1.tiff", "needs a rule"],
        ),
        check("a PNG named .jpg", &renamed, &["s_eo-1.jpg", "Png"]),
    ]
}

/// A 2 × 2 grey TIFF of 12-bit packed samples.
fn twelve_bit_tiff() -> Vec<u8> {
    rtf_data::tiffio::raw_grey_tiff(2, 2, 12, &[0x12, 0x34, 0x56, 0x78, 0x9a, 0xbc])
}

/// dataset.yaml patterns and the list file gone wrong.
fn description_cases(f: &Fixture) -> Vec<Case> {
    let with_yaml = |name: &str, from: &str, to: &str| {
        let root = distributed_root(f, name, "");
        let yaml = std::fs::read_to_string(root.join("dataset.yaml")).unwrap();
        std::fs::write(root.join("dataset.yaml"), yaml.replace(from, to)).unwrap();
        root
    };
    let twice = with_yaml("ad_twice", "{seq}_eo-{n}.jpg", "{seq}_eo-{seq}.jpg");
    let missing = with_yaml("ad_missing", "{seq}_ir-{n}.tiff", "{seq}_ir.tiff");
    let hex = with_yaml("ad_hex", "[220, 20, 60]", "\"#DC14\"");
    let listed = distributed_root(f, "ad_list", "");
    std::fs::write(
        listed.join("train.txt"),
        "color/s_eo-1.jpg\ncolor/s_eo-2.jpg,ir/s_ir-1.tiff\n",
    )
    .unwrap();
    let count = distributed_root(f, "ad_count", "");
    std::fs::write(count.join("train.txt"), "s/1 s/1 s/1 s/1\n").unwrap();
    vec![
        check(
            "a field used twice in a pattern",
            &twice,
            &["dataset.yaml", "used twice"],
        ),
        check(
            "a field missing from a partner's pattern",
            &missing,
            &["dataset.yaml", "{n}"],
        ),
        check(
            "a hex colour that is not one",
            &hex,
            &["dataset.yaml", "#DC14"],
        ),
        check(
            "list line naming two frames",
            &listed,
            &["train.txt", "line 2", "s/2", "s/1"],
        ),
        train(
            f,
            "list line naming two frames",
            &listed,
            &["train.txt", "line 2"],
        ),
        check(
            "list line with four entries",
            &count,
            &["train.txt", "line 1", "4 entries"],
        ),
        check(
            "a folder pattern with one frame twice",
            &folder_twice(f),
            &["same frame"],
        ),
    ]
}

/// A plain root whose train/rgb has f0.png and f0.jpg (two files of one frame).
fn folder_twice(f: &Fixture) -> PathBuf {
    let root = plain_root(&f.t.join("ad_folder_twice"), YAML, 3);
    image::RgbImage::new(32, 32)
        .save(root.join("train/rgb/f0.jpg"))
        .unwrap();
    root
}

/// Outputs that would land on the data.
fn output_cases(f: &Fixture) -> Vec<Case> {
    let root = plain_root(&f.t.join("ad_outputs"), YAML, 3);
    let label = root.join("train/labels/f0.png");
    let original = std::fs::read(&label).unwrap();
    let unchanged = move |path: PathBuf, original: Vec<u8>| {
        move || std::fs::read(&path).map(|b| b == original).unwrap_or(false)
    };
    let labels_dir = root.join("train/labels");
    let (rgb, thermal) = (
        root.join("train/rgb/f0.png"),
        root.join("train/thermal/f0.png"),
    );
    let predict = [
        "predict",
        "--weights",
        s(&f.weights),
        "--out",
        s(&labels_dir),
        "--rgb",
        s(&rgb),
        "--thermal",
        s(&thermal),
    ];
    let json_over_label = root.join("train/labels/f1.png");
    let original_f1 = std::fs::read(&json_over_label).unwrap();
    let eval = [
        "eval",
        "--weights",
        s(&f.weights),
        "--data",
        s(&root),
        "--split",
        "train",
        "--json",
        s(&json_over_label),
    ];
    let config = root.join("config.json");
    vec![
        case(
            "outputs: predict into a dataset's label folder",
            &predict,
            &["f0.png", "not written by rtf", "--overwrite"],
        )
        .intact(unchanged(label.clone(), original)),
        case(
            "outputs: eval --json over a label of the split",
            &eval,
            &["f1.png", "file of the dataset"],
        )
        .intact(unchanged(json_over_label.clone(), original_f1)),
        case(
            "outputs: train --out the dataset's root",
            &short_train(&root, &root, "1", &[]),
            &["--out", "inside the dataset"],
        )
        .intact(move || !config.exists()),
    ]
}

pub fn cases(f: &Fixture) -> Vec<Case> {
    let mut all = file_cases(f);
    all.extend(description_cases(f));
    all.extend(output_cases(f));
    all
}
