//! A set recorded as sequences (issue 59): fields in folders, JPEG thermal, per-condition
//! lists; broken one way per case, through `rtf data check` and `rtf predict`.

use std::path::{Path, PathBuf};

use crate::common::*;
use crate::verdict::{case, Case};
use crate::Fixture;

/// Two frames per sequence of `images/{set}/{video}/{visible,lwir}/{frame}.jpg`, labels
/// `labels/{set}_{video}_{frame}.png`, lists `day.txt` (V000) and `night.txt` (V001).
const YAML: &str = "classes:
  - {id: 0, name: road, color: [128, 64, 128]}
  - {id: 1, name: car, color: [0, 0, 142]}
ignore_id: 19
splits:
  train:
    rgb: \"images/{set}/{video}/visible/{frame}.jpg\"
    thermal: \"images/{set}/{video}/lwir/{frame}.jpg\"
    labels: \"labels/{set}_{video}_{frame}.png\"
    list: [day.txt, night.txt]
night: {list: night.txt}
";

fn sequence_root(root: &Path, yaml: &str) -> PathBuf {
    let (mut day, mut night) = (String::new(), String::new());
    for video in ["V000", "V001"] {
        for frame in ["I00001", "I00002"] {
            let seq = root.join("images/set00").join(video);
            for folder in ["visible", "lwir"] {
                std::fs::create_dir_all(seq.join(folder)).unwrap();
            }
            image::RgbImage::from_fn(32, 32, |x, y| {
                image::Rgb([(x * 8) as u8, (y * 8) as u8, 90])
            })
            .save(seq.join(format!("visible/{frame}.jpg")))
            .unwrap();
            image::RgbImage::from_fn(32, 32, |x, _| image::Rgb([(x * 7) as u8; 3]))
                .save(seq.join(format!("lwir/{frame}.jpg")))
                .unwrap();
            std::fs::create_dir_all(root.join("labels")).unwrap();
            let label = format!("set00_{video}_{frame}.png");
            image::GrayImage::from_fn(32, 32, |x, _| image::Luma([(x / 16) as u8]))
                .save(root.join("labels").join(&label))
                .unwrap();
            let list = if video == "V000" {
                &mut day
            } else {
                &mut night
            };
            list.push_str(&(label + "\n"));
        }
    }
    std::fs::write(root.join("day.txt"), day).unwrap();
    std::fs::write(root.join("night.txt"), night).unwrap();
    std::fs::write(root.join("dataset.yaml"), yaml).unwrap();
    root.to_path_buf()
}

fn check(name: &str, root: &Path, must: &[&str]) -> Case {
    case(
        &format!("sequences: {name}"),
        &["data", "check", s(root)],
        must,
    )
}

pub fn cases(f: &Fixture) -> Vec<Case> {
    let root = |name: &str, yaml: &str| sequence_root(&f.t.join(name), yaml);
    let partner = root(
        "sq_partner",
        &YAML.replace(
            "images/{set}/{video}/lwir/{frame}.jpg",
            "images/{set}/V000/lwir/{frame}.jpg",
        ),
    );
    let wide = root(
        "sq_wide",
        // The split walks its folders (no list), where the RGB pattern meets the thermal files.
        &YAML
            .replace(
                "images/{set}/{video}/lwir/{frame}.jpg",
                "images/{set}/{video}/visible/{frame}_ir.jpg",
            )
            .replace("    list: [day.txt, night.txt]\n", "")
            .replace("night: {list: night.txt}\n", ""),
    );
    std::fs::copy(
        wide.join("images/set00/V000/lwir/I00001.jpg"),
        wide.join("images/set00/V000/visible/I00001_ir.jpg"),
    )
    .unwrap();
    let ghost = root("sq_ghost", YAML);
    std::fs::write(
        ghost.join("night.txt"),
        "set00_V001_I00001.png\nV001_I00001\n",
    )
    .unwrap();
    let two = root("sq_two", YAML);
    std::fs::write(two.join("night.txt"), "I00001.jpg\n").unwrap();
    let colour = root("sq_colour", YAML);
    image::RgbImage::from_fn(32, 32, |x, _| {
        image::Rgb([(x * 7) as u8, 255 - (x * 7) as u8, 0])
    })
    .save(colour.join("images/set00/V001/lwir/I00002.jpg"))
    .unwrap();
    let void = root("sq_void", &YAML.replace("ignore_id: 19", "ignore_id: 1"));
    let a = f.t.join("sq_pairs/a");
    let b = f.t.join("sq_pairs/b");
    for dir in [&a, &b] {
        std::fs::create_dir_all(dir).unwrap();
        std::fs::copy(&f.good_image, dir.join("I00050.png")).unwrap();
    }
    let out = f.t.join("sq_pairs/out");
    let (first, second) = (a.join("I00050.png"), b.join("I00050.png"));
    let predict = [
        "predict",
        "--weights",
        s(&f.weights),
        "--out",
        s(&out),
        s(&first),
        s(&second),
    ];
    vec![
        check(
            "a folder field missing from a partner's pattern",
            &partner,
            &["dataset.yaml", "line 8", "{frame}"],
        ),
        check(
            "a field wide enough to take another role's files",
            &wide,
            &["I00001_ir.jpg", "both the RGB and the thermal pattern"],
        ),
        check(
            "a list line naming no frame",
            &ghost,
            &["night.txt", "line 2", "V001_I00001"],
        ),
        check(
            "a list line naming two frames",
            &two,
            &["night.txt", "line 1", "names 2 frames"],
        ),
        check(
            "a JPEG thermal whose channels are not grey",
            &colour,
            &["I00002.jpg", "differ"],
        ),
        check(
            "a void id that is also a class id",
            &void,
            &["dataset.yaml", "ignore_id 1 is also a class id"],
        ),
        case(
            "sequences: two inputs mapping to one output",
            &predict,
            &["I00050.png", "would both write"],
        ),
    ]
}
