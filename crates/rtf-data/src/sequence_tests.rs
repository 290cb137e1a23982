//! A dataset recorded as driving sequences, read as shipped through dataset.yaml: fields in
//! folders (`images/{set}/{video}/visible/{frame}.jpg`), thermal as grey JPEG in three
//! channels, labels named by all fields (`labels/{set}_{video}_{frame}.png`), splits as unions
//! of the release's per-condition lists, whose lines are label file names.

use std::path::Path;

use rtf_core::Daytime;

use crate::description::{read_description, DESCRIPTION_FILE};
use crate::testutil::*;
use crate::{DataError, DescribedDataset, DescribedSplit, FrameSource};

const FRAMES: [(&str, &str, &str); 5] = [
    ("set00", "V000", "I00001"),
    ("set00", "V000", "I00002"),
    ("set00", "V001", "I00001"),
    ("set01", "V000", "I00001"),
    ("set01", "V000", "I00002"),
];

/// 19 classes, void 19, the sequence patterns; `extra` appended.
pub(crate) fn sequence_yaml(extra: &str) -> String {
    let classes: String = (0..19)
        .map(|i| {
            format!(
                "  - {{id: {i}, name: c{i}, color: [{i}, {}, 0]}}\n",
                200 - i
            )
        })
        .collect();
    let split = |lists: &str| {
        format!("{{rgb: \"images/{{set}}/{{video}}/visible/{{frame}}.jpg\", thermal: \"images/{{set}}/{{video}}/lwir/{{frame}}.jpg\", labels: \"labels/{{set}}_{{video}}_{{frame}}.png\", list: {lists}}}")
    };
    format!(
        "classes:\n{classes}ignore_id: 19\nsplits:\n  train: {}\n  test: {}\nday: {{list: [train_day.txt, test_day.txt]}}\nnight: {{list: [train_night.txt, test_night.txt]}}\n{extra}",
        split("[train_day.txt, train_night.txt]"),
        split("[test_day.txt, test_night.txt]"),
    )
}

/// The tree: five frames of 8×6, the lists (train: set00, V001 at night; test: set01, one
/// frame by night, one by day).
pub(crate) fn sequence_root(extra: &str) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (8, 6);
    for (k, (set, video, frame)) in FRAMES.iter().enumerate() {
        let seq = dir.path().join("images").join(set).join(video);
        write(
            &seq.join(format!("visible/{frame}.jpg")),
            &jpeg_rgb(w, h, &rgb(w, h, k as u8)),
        );
        let grey: Vec<u8> = (0..w * h).flat_map(|i| [(i * 5) as u8; 3]).collect();
        write(
            &seq.join(format!("lwir/{frame}.jpg")),
            &jpeg_rgb(w, h, &grey),
        );
        let label: Vec<u8> = (0..w * h).map(|i| (i % 20) as u8).collect();
        let name = format!("labels/{set}_{video}_{frame}.png");
        write(&dir.path().join(name), &png_u8(w, h, 1, &label));
    }
    let lists = [
        (
            "train_day.txt",
            "set00_V000_I00001.png\nset00_V000_I00002.png\n",
        ),
        ("train_night.txt", "set00_V001_I00001.png\n"),
        ("test_day.txt", "set01_V000_I00002.png\n"),
        ("test_night.txt", "set01_V000_I00001.png\n"),
    ];
    for (file, text) in lists {
        write(&dir.path().join(file), text.as_bytes());
    }
    write(
        &dir.path().join(DESCRIPTION_FILE),
        sequence_yaml(extra).as_bytes(),
    );
    dir
}

fn open(root: &Path, split: &str) -> Result<DescribedSplit, DataError> {
    let d = read_description(&root.join(DESCRIPTION_FILE))?;
    DescribedDataset::new(d).split(split)
}

fn rewrite(root: &Path, file: &str, text: &str) {
    write(&root.join(file), text.as_bytes());
}

fn names_and_conditions(split: &DescribedSplit) -> Vec<(String, Option<Daytime>)> {
    (0..split.len())
        .map(|i| (split.frame_name(i).to_string(), split.daytime(i)))
        .collect()
}

#[test]
fn a_sequence_set_is_read_as_shipped() {
    let dir = sequence_root("");
    let train = open(dir.path(), "train").unwrap();
    let got = names_and_conditions(&train);
    let want = [
        ("set00/V000/I00001", Daytime::Day),
        ("set00/V000/I00002", Daytime::Day),
        ("set00/V001/I00001", Daytime::Night),
    ];
    let want: Vec<(String, Option<Daytime>)> = want
        .iter()
        .map(|(n, d)| (n.to_string(), Some(*d)))
        .collect();
    assert_eq!(got, want);
    let test = open(dir.path(), "test").unwrap();
    let got = names_and_conditions(&test);
    let want = [
        ("set01/V000/I00002".to_string(), Some(Daytime::Day)),
        ("set01/V000/I00001".to_string(), Some(Daytime::Night)),
    ];
    assert_eq!(got, want, "the union of the lists, in list order");
    let frame = train.load(2).unwrap();
    assert_eq!((frame.width, frame.height), (8, 6));
    // Grey JPEG in three channels: the channels' mean, within JPEG's error of the grey.
    let worst = (frame.thermal.iter().enumerate())
        .map(|(i, &t)| (t * 255.0 - ((i * 5) % 256) as f32).abs())
        .fold(0.0f32, f32::max);
    assert!(worst <= 12.0, "{worst}");
    let label = frame.label.unwrap();
    assert_eq!(label[19], 19, "void stays the ignore id");
    assert_eq!(label[18], 18);
}

#[test]
fn a_split_without_lists_walks_the_folders() {
    let dir = sequence_root("");
    let yaml = sequence_yaml("").replace(", list: [test_day.txt, test_night.txt]", "");
    rewrite(dir.path(), DESCRIPTION_FILE, &yaml);
    let all = open(dir.path(), "test").unwrap();
    let names: Vec<&str> = (0..all.len()).map(|i| all.frame_name(i)).collect();
    assert_eq!(names.len(), 5);
    assert_eq!(names[2], "set00/V001/I00001");
    assert_eq!(all.daytime(2), Some(Daytime::Night));
}

#[test]
fn a_condition_line_naming_no_frame_names_the_list_and_line() {
    let dir = sequence_root("");
    rewrite(
        dir.path(),
        "train_night.txt",
        "set00_V001_I00001.png\nset09_V000_I00001.png\n",
    );
    // Opening test (the list is not one of its split lists) and train (it is).
    for (split, says) in [("test", "no frame of the dataset"), ("train", "is missing")] {
        let text = open(dir.path(), split).unwrap_err().to_string();
        assert!(
            text.contains("train_night.txt") && text.contains("line 2") && text.contains(says),
            "{text}"
        );
    }
    // A night list in another naming (the frames' names without their folders' fields).
    rewrite(dir.path(), "train_night.txt", "V001_I00001\n");
    let text = open(dir.path(), "test").unwrap_err().to_string();
    assert!(
        text.contains("train_night.txt") && text.contains("line 1"),
        "{text}"
    );
    // Asked for: skipped with a warning that counts them.
    let dir = sequence_root("unmatched_lines: warn\n");
    rewrite(
        dir.path(),
        "train_night.txt",
        "set00_V001_I00001.png\nset09_V000_I00001.png\n",
    );
    let train = open(dir.path(), "train").unwrap();
    assert_eq!(train.len(), 3);
    let warned = train.warnings().join("\n");
    assert!(warned.contains("train_night.txt: 1 line(s)"), "{warned}");
}

#[test]
fn a_line_naming_two_frames_or_a_frame_both_day_and_night_is_an_error() {
    let dir = sequence_root("");
    rewrite(dir.path(), "test_night.txt", "I00001.jpg\n");
    let text = open(dir.path(), "test").unwrap_err().to_string();
    assert!(
        text.contains("test_night.txt")
            && text.contains("line 1")
            && text.contains("names 3 frames"),
        "{text}"
    );
    let dir = sequence_root("");
    rewrite(
        dir.path(),
        "test_day.txt",
        "set01_V000_I00002.png\nset01_V000_I00001.png\n",
    );
    let text = open(dir.path(), "test").unwrap_err().to_string();
    assert!(
        text.contains("set01/V000/I00001") && text.contains("one condition"),
        "{text}"
    );
}

#[test]
fn a_split_line_naming_a_missing_frame_or_two_frames_names_the_list_and_line() {
    let dir = sequence_root("");
    rewrite(
        dir.path(),
        "train_day.txt",
        "set00_V000_I00001.png\nset00_V000_I00009.png\n",
    );
    let text = open(dir.path(), "train").unwrap_err().to_string();
    assert!(
        text.contains("train_day.txt, line 2") && text.contains("I00009"),
        "{text}"
    );
    rewrite(dir.path(), "train_day.txt", "V000/visible/I00001.jpg\n");
    let text = open(dir.path(), "train").unwrap_err().to_string();
    assert!(
        text.contains("train_day.txt") && text.contains("names 2 frames"),
        "{text}"
    );
}

#[test]
fn a_file_matching_two_roles_patterns_is_an_error() {
    let dir = sequence_root("");
    let yaml = sequence_yaml("")
        .replace("images/{set}/{video}/lwir/{frame}.jpg", "images/{set}/{video}/visible/{frame}_ir.jpg")
        .replace(", list: [test_day.txt, test_night.txt]", "")
        .replace("day: {list: [train_day.txt, test_day.txt]}\nnight: {list: [train_night.txt, test_night.txt]}\n", "");
    rewrite(dir.path(), DESCRIPTION_FILE, &yaml);
    let ir = dir.path().join("images/set00/V000/visible/I00001_ir.jpg");
    std::fs::copy(dir.path().join("images/set00/V000/lwir/I00001.jpg"), &ir).unwrap();
    let text = open(dir.path(), "test").unwrap_err().to_string();
    assert!(
        text.contains("I00001_ir.jpg") && text.contains("both the RGB and the thermal pattern"),
        "{text}"
    );
}
