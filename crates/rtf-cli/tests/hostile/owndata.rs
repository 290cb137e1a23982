//! Own data (issue 26): a plain-layout root described by dataset.yaml, broken one way per
//! case, through `rtf data check` (and `rtf train` where the reader differs).

use std::path::{Path, PathBuf};

use crate::common::*;
use crate::verdict::{case, Case};
use crate::Fixture;

/// The description every case starts from: three classes, 8-bit thermal, `train` and `test`.
pub const YAML: &str = "classes:
  - {id: 0, name: background, color: [0, 0, 0]}
  - {id: 1, name: pedestrian, color: [220, 20, 60]}
  - {id: 2, name: vehicle, color: [0, 0, 142]}
ignore_id: 255
";

/// One frame's three files at `root/split/{rgb,thermal,labels}/name.png`, 32×32; labels
/// cycle through `0..classes`.
pub fn write_frame(root: &Path, split: &str, name: &str, classes: u8) {
    for folder in ["rgb", "thermal", "labels"] {
        std::fs::create_dir_all(root.join(split).join(folder)).unwrap();
    }
    let file = |folder: &str| root.join(split).join(folder).join(format!("{name}.png"));
    image::RgbImage::from_fn(32, 32, |x, y| {
        image::Rgb([(x * 8) as u8, (y * 8) as u8, 90])
    })
    .save(file("rgb"))
    .unwrap();
    image::GrayImage::from_fn(32, 32, |x, _| image::Luma([(x * 7) as u8]))
        .save(file("thermal"))
        .unwrap();
    image::GrayImage::from_fn(32, 32, |x, y| {
        image::Luma([((x / 8 + y / 8) % classes as u32) as u8])
    })
    .save(file("labels"))
    .unwrap();
}

/// A plain-layout root with `yaml` as dataset.yaml and four frames in `train` and `test`.
pub fn plain_root(root: &Path, yaml: &str, classes: u8) -> PathBuf {
    for split in ["train", "test"] {
        for i in 0..4 {
            write_frame(root, split, &format!("f{i}"), classes);
        }
    }
    std::fs::write(root.join("dataset.yaml"), yaml).unwrap();
    root.to_path_buf()
}

fn label(root: &Path, name: &str) -> PathBuf {
    root.join("train/labels").join(format!("{name}.png"))
}

/// A root whose dataset.yaml is `yaml` (the frames intact).
fn described(f: &Fixture, name: &str, yaml: &str) -> PathBuf {
    plain_root(&f.t.join(name), yaml, 3)
}

/// A root with the usual dataset.yaml whose frames `mutate` changes.
fn damaged(f: &Fixture, name: &str, mutate: &dyn Fn(&Path)) -> PathBuf {
    let root = plain_root(&f.t.join(name), YAML, 3);
    mutate(&root);
    root
}

fn check(name: &str, root: &Path, must: &[&str]) -> Case {
    case(
        &format!("own data: {name}"),
        &["data", "check", s(root)],
        must,
    )
}

fn train(f: &Fixture, name: &str, root: &Path, must: &[&str]) -> Case {
    let out = f.t.join(format!("{name}-run").replace(' ', "_"));
    let args = short_train(root, &out, "2", &["--val-split", "none"]);
    let weights = out.join("final.safetensors");
    case(&format!("own data: train, {name}"), &args, must).intact(move || !weights.exists())
}

/// dataset.yaml itself: keys, classes, paths.
fn description_cases(f: &Fixture) -> Vec<Case> {
    let unknown = described(f, "od_unknown", &format!("{YAML}clases: []\n"));
    let dup_id = YAML.replace("id: 2, name: vehicle", "id: 1, name: vehicle");
    let dup_name = YAML.replace("name: vehicle", "name: pedestrian");
    let gap = YAML.replace("id: 2,", "id: 3,");
    let ignore = YAML.replace("ignore_id: 255", "ignore_id: 2");
    let escape =
        format!("{YAML}splits:\n  train: {{rgb: ../elsewhere/rgb, thermal: train/thermal}}\n");
    let absolute = format!("{YAML}splits:\n  train: {{rgb: /tmp/rgb, thermal: train/thermal}}\n");
    let both = format!("{YAML}thermal: {{range: [0, 255], min_max: true}}\n");
    vec![
        check("unknown key", &unknown, &["dataset.yaml", "clases"]),
        train(f, "unknown key", &unknown, &["dataset.yaml", "clases"]),
        check(
            "duplicate class ids",
            &described(f, "od_dupid", &dup_id),
            &["dataset.yaml", "line 4"],
        ),
        check(
            "duplicate class names",
            &described(f, "od_dupname", &dup_name),
            &["dataset.yaml", "pedestrian"],
        ),
        check(
            "a label value that is neither a class id nor ignored",
            &described(f, "od_gap", &gap),
            &["labels", "label id 2", "label values 0, 1, 3"],
        ),
        check(
            "ignore id is a class id",
            &described(f, "od_ignore", &ignore),
            &["dataset.yaml", "ignore_id"],
        ),
        check(
            "path escaping the root (..)",
            &described(f, "od_escape", &escape),
            &["dataset.yaml", "../elsewhere/rgb"],
        ),
        check(
            "absolute path",
            &described(f, "od_abs", &absolute),
            &["dataset.yaml", "/tmp/rgb"],
        ),
        check(
            "two thermal rules",
            &described(f, "od_rules", &both),
            &["dataset.yaml", "min_max"],
        ),
    ]
}

/// The frames a valid dataset.yaml points at.
fn frame_cases(f: &Fixture) -> Vec<Case> {
    let outside = damaged(f, "od_label", &|r| {
        image::GrayImage::from_pixel(32, 32, image::Luma([7]))
            .save(label(r, "f1"))
            .unwrap();
    });
    let partner = damaged(f, "od_partner", &|r| {
        std::fs::remove_file(r.join("train/thermal/f2.png")).unwrap();
    });
    let sizes = damaged(f, "od_sizes", &|r| {
        image::GrayImage::new(16, 16)
            .save(r.join("train/thermal/f0.png"))
            .unwrap();
    });
    let deep = |r: &Path| {
        let t = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_pixel(
            32,
            32,
            image::Luma([22000]),
        );
        t.save(r.join("train/thermal/f3.png")).unwrap();
    };
    let sixteen = damaged(f, "od_16bit", &deep);
    let list_yaml = format!(
        "{YAML}splits:\n  train: {{rgb: train/rgb, thermal: train/thermal, labels: train/labels, list: train.txt}}\n"
    );
    let listed = described(f, "od_list", &list_yaml);
    std::fs::write(listed.join("train.txt"), "f0\nf1\nghost\n").unwrap();
    vec![
        check(
            "label id outside the class list",
            &outside,
            &["f1.png", "7"],
        ),
        train(
            f,
            "label id outside the class list",
            &outside,
            &["f1.png", "7"],
        ),
        check("RGB without its thermal partner", &partner, &["f2.png"]),
        check("partners of different sizes", &sizes, &["f0.png", "16x16"]),
        check(
            "16-bit thermal without a rule",
            &sixteen,
            &["f3.png", "16-bit"],
        ),
        train(
            f,
            "16-bit thermal without a rule",
            &sixteen,
            &["f3.png", "16-bit"],
        ),
        check(
            "split list naming a missing file",
            &listed,
            &["train.txt", "ghost"],
        ),
    ]
}

/// `label_encoding: colors`: a pixel whose colour is not in the palette.
fn colour_cases(f: &Fixture) -> Vec<Case> {
    let yaml = format!("{YAML}label_encoding: colors\n");
    let paint = |r: &Path, odd: bool| {
        for split in ["train", "test"] {
            for i in 0..4 {
                let path = r.join(split).join("labels").join(format!("f{i}.png"));
                let colour = if odd && split == "train" && i == 2 {
                    [1, 2, 3]
                } else {
                    [220, 20, 60]
                };
                image::RgbImage::from_pixel(32, 32, image::Rgb(colour))
                    .save(path)
                    .unwrap();
            }
        }
    };
    let odd = described(f, "od_colour", &yaml);
    paint(&odd, true);
    let same = described(
        f,
        "od_samecolour",
        &format!(
            "{}label_encoding: colors\n",
            YAML.replace("[0, 0, 142]", "[220, 20, 60]")
        ),
    );
    paint(&same, false);
    vec![
        check("colour not in the palette", &odd, &["f2.png", "1, 2, 3"]),
        check(
            "two classes of one colour",
            &same,
            &["dataset.yaml", "220, 20, 60"],
        ),
    ]
}

pub fn cases(f: &Fixture) -> Vec<Case> {
    let mut all = description_cases(f);
    all.extend(frame_cases(f));
    all.extend(colour_cases(f));
    all
}
