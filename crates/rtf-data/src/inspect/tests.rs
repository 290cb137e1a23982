use super::*;
use crate::fingerprint::fingerprint;
use crate::synth::{generate, SynthConfig, SynthFormat};
use crate::testutil::*;

#[test]
fn clean_synthetic_datasets_pass() {
    for format in [SynthFormat::Mf, SynthFormat::Freiburg] {
        let dir = tempfile::tempdir().unwrap();
        generate(
            dir.path(),
            &SynthConfig {
                count: 8,
                width: 64,
                height: 48,
                format,
                ..SynthConfig::default()
            },
        )
        .unwrap();
        let report = check(dir.path());
        assert!(report.is_ok(), "{format:?}: {:?}", report.problems);
        assert_eq!(report.frames, 8);
    }
}

#[test]
fn check_reports_every_problem_with_file_names() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    mf_dataset(
        root,
        &["00001D", "00002N", "00003D", "00004N", "00005D"],
        8,
        6,
    );
    // 1: truncated image; 2: label with an id out of range; 3: RGB (3-channel) image;
    // 4: label missing; 5: 16-bit label; plus a duplicate and a missing split entry and
    // a frame in no split.
    let img1 = std::fs::read(root.join("images/00001D.png")).unwrap();
    write(&root.join("images/00001D.png"), &img1[..img1.len() / 2]);
    write(&root.join("labels/00002N.png"), &png_u8(8, 6, 1, &[12; 48]));
    write(&root.join("images/00003D.png"), &png_u8(8, 6, 3, &[1; 144]));
    std::fs::remove_file(root.join("labels/00004N.png")).unwrap();
    write(&root.join("labels/00005D.png"), &png_u16(8, 6, 1, &[1; 48]));
    write(
        &root.join("train.txt"),
        b"00001D\n00002N\n00003D\n00004N\n00002N\n00009D\n",
    );
    write(&root.join("images/00006N.png"), &png_u8(8, 6, 4, &[1; 192]));
    write(&root.join("labels/00006N.png"), &png_u8(8, 6, 1, &[1; 48]));
    let report = check(root);
    let text: Vec<String> = report.problems.iter().map(|p| p.to_string()).collect();
    let has = |needle: &[&str]| text.iter().any(|t| needle.iter().all(|n| t.contains(n)));
    assert!(
        has(&["images/00001D.png", "not a readable PNG"]),
        "{text:#?}"
    );
    assert!(has(&["labels/00002N.png", "label id 12"]), "{text:#?}");
    assert!(
        has(&["images/00003D.png", "expected 4 channel"]),
        "{text:#?}"
    );
    assert!(has(&["labels/00004N.png", "missing"]), "{text:#?}");
    assert!(has(&["labels/00005D.png", "16-bit"]), "{text:#?}");
    assert!(
        has(&["train.txt", "line 5", "duplicates line 2"]),
        "{text:#?}"
    );
    assert!(has(&["train.txt", "line 6", "00009D"]), "{text:#?}");
    assert!(has(&["images/00006N.png", "in no split"]), "{text:#?}");
    assert_eq!(report.frames, 5, "every pair with both files was decoded");
}

#[test]
fn bdd_roots_are_recognised_checked_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    write(&root.join("images/val/a.png"), &png_u8(4, 2, 3, &[50; 24]));
    write(
        &root.join("labels/val/a_train_id.png"),
        &png_u8(4, 2, 1, &[0, 0, 11, 11, 13, 13, 255, 255]),
    );
    write(&root.join("bdd_night.txt"), b"a\n");
    assert_eq!(detect_format(root), Some(DatasetFormat::Bdd));
    assert!(check(root).is_ok(), "{:?}", check(root).problems);
    let s = stats(root).unwrap();
    assert_eq!((s.splits[0].frames, s.splits[0].night), (1, 1));
    assert_eq!(
        (
            s.classes[0].pixels,
            s.classes[9].pixels,
            s.classes[10].pixels,
            s.ignored_pixels
        ),
        (2, 2, 2, 2)
    );
    write(&root.join("bdd_night.txt"), b"a\nb\na\n");
    let text: Vec<String> = check(root).problems.iter().map(|p| p.to_string()).collect();
    assert!(
        text.iter()
            .any(|t| t.contains("line 2") && t.contains("'b'")),
        "{text:?}"
    );
    assert!(
        text.iter()
            .any(|t| t.contains("line 3") && t.contains("duplicates line 1")),
        "{text:?}"
    );
}

#[test]
fn stats_count_frames_and_class_shares() {
    let dir = tempfile::tempdir().unwrap();
    generate(
        dir.path(),
        &SynthConfig {
            count: 16,
            width: 64,
            height: 48,
            ..SynthConfig::default()
        },
    )
    .unwrap();
    let s = stats(dir.path()).unwrap();
    let train = s.splits.iter().find(|x| x.name == "train").unwrap();
    assert_eq!((train.frames, train.day, train.night), (8, 4, 4));
    assert_eq!(s.labelled_frames, 16);
    let total: f64 = s.classes.iter().map(|c| c.share).sum();
    assert!((total - 1.0).abs() < 1e-9);
    let pixels: u64 = s.classes.iter().map(|c| c.pixels).sum();
    assert_eq!(pixels, 16 * 64 * 48);
    assert!(
        s.classes[0].share > 0.5,
        "unlabeled is the majority, as in MF"
    );
}

#[test]
fn odd_sized_frames_and_directories_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    mf_dataset(root, &["00001D", "00002N", "00003D"], 8, 6);
    // One frame of another size, image and label consistent: decodes, but cannot batch.
    write(
        &root.join("images/00004N.png"),
        &png_u8(10, 6, 4, &rgba(10, 6, 9)),
    );
    write(&root.join("labels/00004N.png"), &png_u8(10, 6, 1, &[1; 60]));
    write(&root.join("train.txt"), b"00001D\n00002N\n00003D\n00004N\n");
    // A split "file" that is a directory, and an image path that is a directory.
    std::fs::create_dir_all(root.join("val.txt")).unwrap();
    std::fs::create_dir_all(root.join("images/00005D.png")).unwrap();
    let report = check(root);
    let text: Vec<String> = report.problems.iter().map(|p| p.to_string()).collect();
    let has = |needle: &[&str]| text.iter().any(|t| needle.iter().all(|n| t.contains(n)));
    assert!(
        has(&[
            "images/00004N.png",
            "is 10x6",
            "3 of 4 frames are 8x6",
            "--resize"
        ]),
        "{text:#?}"
    );
    assert!(
        has(&["val.txt", "is a directory", "split file"]),
        "{text:#?}"
    );
    assert!(
        has(&["images/00005D.png", "is a directory", "PNG"]),
        "{text:#?}"
    );
    assert!(
        !text.iter().any(|t| t.contains("no split files")),
        "no misleading message: {text:#?}"
    );
}

#[test]
fn frames_shared_between_splits_and_duplicates_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    mf_dataset(root, &["00001D", "00002N", "00003D", "00004N"], 8, 6);
    // 00004N is a byte copy of 00001D under another name.
    std::fs::copy(
        root.join("images/00001D.png"),
        root.join("images/00004N.png"),
    )
    .unwrap();
    write(&root.join("train.txt"), b"00001D\n00002N\n");
    // test: 00002N leaks by name, 00004N by content; test_day is a subset of test.
    write(&root.join("test.txt"), b"00002N\n00003D\n00004N\n");
    write(&root.join("test_day.txt"), b"00003D\n");
    let report = check(root);
    let text: Vec<String> = report.problems.iter().map(|p| p.to_string()).collect();
    let has = |needle: &[&str]| text.iter().any(|t| needle.iter().all(|n| t.contains(n)));
    assert!(
        has(&["images/00004N.png", "same bytes as", "00001D.png"]),
        "{text:#?}"
    );
    assert!(
        has(&["test.txt", "line 1", "'00002N' is also in split 'train'"]),
        "{text:#?}"
    );
    assert!(
        has(&[
            "test.txt",
            "line 3",
            "'00004N' has the same content as '00001D'"
        ]),
        "{text:#?}"
    );
    assert!(
        !text.iter().any(|t| t.contains("test_day")),
        "a subset split is no leak: {text:#?}"
    );
}

#[test]
fn check_and_stats_name_a_described_layout_and_its_classes() {
    let dir = tempfile::tempdir().unwrap();
    let pst = RgbtFolders {
        rgb: "rgb",
        thermal: "thermal",
        labels: "labels",
    };
    for (split, name) in [("train", "f1"), ("test", "f2")] {
        let d = dir.path().join(split);
        write_rgbt_frame(&d, &pst, name, (5, 2), ThermalFixture::Grey8, 5);
    }
    let report = check(dir.path());
    assert!(report.is_ok(), "{:?}", report.problems);
    assert_eq!(report.format, Some(DatasetFormat::Pst900));
    assert_eq!(report.frames, 2);
    assert_eq!(report.class_set.as_ref().unwrap().names()[4], "survivor");
    assert_eq!(report.thermal.as_deref(), Some("8-bit / 255"));
    let s = stats(dir.path()).unwrap();
    assert_eq!(s.labelled_frames, 2);
    // ids(5, 2, 5) = 0,0,0,1,1,1,2,2,2,3: per frame 3+3+3+1+0 pixels.
    let pixels: Vec<(&str, u64)> = s
        .classes
        .iter()
        .map(|c| (c.name.as_str(), c.pixels))
        .collect();
    assert_eq!(
        pixels,
        [
            ("background", 6),
            ("fire_extinguisher", 6),
            ("backpack", 6),
            ("hand_drill", 2),
            ("survivor", 0)
        ]
    );
    // A label id outside the class list is a problem naming the file and the id.
    let label = dir.path().join("test/labels/f2.png");
    write(&label, &png_u8(5, 2, 1, &[9; 10]));
    let report = check(dir.path());
    assert_eq!(report.problems.len(), 1, "{:?}", report.problems);
    assert_eq!(report.problems[0].path, label);
    assert!(
        report.problems[0].message.contains("label id 9"),
        "{}",
        report.problems[0]
    );
    assert_eq!(fingerprint(dir.path()).unwrap().splits.len(), 2);
}
