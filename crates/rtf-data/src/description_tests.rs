//! Tests of [`super`] (dataset.yaml), and the plain-layout fixture other modules' tests use.

use super::*;
use crate::testutil::*;

/// The issue's example, verbatim.
pub(crate) const EXAMPLE: &str =
    "classes:                      # id = label value; colour for palettes and colour-coded labels
  - {id: 0, name: background, color: [0, 0, 0]}
  - {id: 1, name: pedestrian, color: [220, 20, 60]}
ignore_id: 255                # optional
thermal:
  range: [21800, 25000]       # 16-bit raw counts mapped linearly to [0, 1], clipped
";

/// A plain-layout root: dataset.yaml and `{train,val}/{rgb,thermal,labels}/NAME.png`.
pub(crate) fn plain_root(yaml: &str) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let folders = RgbtFolders {
        rgb: "rgb",
        thermal: "thermal",
        labels: "labels",
    };
    for split in ["train", "val"] {
        let d = dir.path().join(split);
        for name in ["a", "b"] {
            let raw = ThermalFixture::Raw16 { base: 21800 };
            write_rgbt_frame(&d, &folders, name, (4, 3), raw, 2);
        }
    }
    write(&dir.path().join(DESCRIPTION_FILE), yaml.as_bytes());
    dir
}

fn parse_in(root: &Path, yaml: &str) -> Result<DatasetDescription, DataError> {
    parse_description(yaml, &root.join(DESCRIPTION_FILE))
}

/// The error text, which must name dataset.yaml and `line`.
fn refused(yaml: &str, line: usize) -> String {
    let dir = plain_root(EXAMPLE);
    let text = parse_in(dir.path(), yaml).unwrap_err().to_string();
    assert!(text.contains("dataset.yaml"), "{text}");
    assert!(text.contains(&format!("line {line}")), "{text}");
    text
}

#[test]
fn the_issue_example_describes_the_plain_layout() {
    let dir = plain_root(EXAMPLE);
    let d = read_description(&dir.path().join(DESCRIPTION_FILE)).unwrap();
    assert_eq!(d.layout, LayoutKind::Plain);
    assert_eq!(d.class_set.names(), ["background", "pedestrian"]);
    assert_eq!(d.class_set.ignore_id, Some(255));
    assert_eq!(d.class_set.color(1), [220, 20, 60]);
    assert_eq!(
        d.thermal,
        ThermalNormalisation::Range {
            lo: 21800.0,
            hi: 25000.0,
            map: None
        }
    );
    assert_eq!(d.split_names(), vec!["train", "val"]);
    assert_eq!(d.night, NightRule::None);
    let train = d.split("train").unwrap();
    assert_eq!(
        train.rgb.path(&vec![("name".into(), "a".into())]),
        dir.path().join("train/rgb/a.png")
    );
    assert!(train.labels.is_some());
}

#[test]
fn colours_are_rgb_lists_or_hex_and_a_bad_hex_names_its_line() {
    let dir = plain_root(EXAMPLE);
    let hex = EXAMPLE.replace("[220, 20, 60]", "\"#DC143c\"");
    let d = parse_in(dir.path(), &hex).unwrap();
    assert_eq!(d.class_set.color(1), [220, 20, 60]);
    for bad in [
        "\"#DC143\"",
        "\"DC143C\"",
        "\"#GG0000\"",
        "[1, 2]",
        "[1, 2, 3, 4]",
        "[1, 2, 300]",
    ] {
        let text = refused(&EXAMPLE.replace("[220, 20, 60]", bad), 3);
        assert!(
            text.contains("colour") || text.contains("invalid"),
            "{bad}: {text}"
        );
    }
}

#[test]
fn named_field_patterns_need_the_same_fields_in_every_partner() {
    let dir = plain_root(EXAMPLE);
    let split = |rgb: &str, thermal: &str| {
        format!("{EXAMPLE}splits:\n  train: {{rgb: \"{rgb}\", thermal: \"{thermal}\"}}\n")
    };
    let ok = split(
        "train/rgb/{seq}_eo-{n}.jpg",
        "train/thermal/{seq}_thermal-{n}.tiff",
    );
    let d = parse_in(dir.path(), &ok).unwrap();
    assert_eq!(d.split("train").unwrap().thermal.fields(), ["seq", "n"]);
    for (yaml, says) in [
        (
            split("train/rgb/{seq}_eo-{n}.jpg", "train/thermal/{seq}.tiff"),
            "has fields {seq} but the RGB pattern has {n}, {seq}",
        ),
        (
            split("train/{seq}/x-{n}.jpg", "train/thermal/{n}.tiff"),
            "has fields {n} but the RGB pattern has {n}, {seq}",
        ),
        (
            split("train/{seq}/x-{n}.jpg", "train/thermal/{seq}/{n}.txt"),
            "must end in one of .png, .jpg, .jpeg, .tif, .tiff, .npy",
        ),
        (
            split("train/rgb/{seq}_{seq}.jpg", "train/thermal/{seq}.tiff"),
            "used twice",
        ),
    ] {
        let text = refused(&yaml, 8);
        assert!(text.contains(says), "{text}");
    }
}

#[test]
fn unknown_keys_are_refused_with_their_line() {
    let text = refused(&EXAMPLE.replace("ignore_id: 255", "ignore_idd: 255"), 4);
    assert!(text.contains("ignore_idd"), "{text}");
    let text = refused(&EXAMPLE.replace("name: pedestrian", "nam: pedestrian"), 3);
    assert!(text.contains("nam"), "{text}");
}

#[test]
fn duplicate_class_ids_and_names_are_refused_with_the_line() {
    let text = refused(
        &EXAMPLE.replace("{id: 1, name: pedestrian", "{id: 0, name: pedestrian"),
        3,
    );
    assert!(text.contains("class id 0 is given twice"), "{text}");
    let text = refused(&EXAMPLE.replace("name: pedestrian", "name: background"), 3);
    assert!(text.contains("'background' is given twice"), "{text}");
    let ignored_twice = EXAMPLE.replace("ignore_id: 255", "ignore_id: [255, 255]");
    assert!(refused(&ignored_twice, 4).contains("ignore_id 255 is given twice"));
    let ignored_class = EXAMPLE.replace("ignore_id: 255", "ignore_id: [1, 255]");
    assert!(refused(&ignored_class, 4).contains("ignore_id 1 is also a class id"));
}

#[test]
fn ids_as_the_dataset_has_them_map_to_outputs_in_the_list_order() {
    let dir = plain_root(EXAMPLE);
    // 0..N-1 listed out of order: the ids are the outputs, as before.
    let swapped = EXAMPLE
        .replace("{id: 0, name: background", "{id: 9, name: background")
        .replace("{id: 1, name: pedestrian", "{id: 0, name: pedestrian")
        .replace("{id: 9, name: background", "{id: 1, name: background");
    let d = parse_in(dir.path(), &swapped).unwrap();
    assert_eq!(d.class_set.names(), ["pedestrian", "background"]);
    assert_eq!(d.class_set.label_values, None);
    // Ids from 1 with 0 ignored (and 255): outputs follow the list, values recorded.
    let from_one = EXAMPLE
        .replace("{id: 1, name: pedestrian", "{id: 7, name: pedestrian")
        .replace("{id: 0, name: background", "{id: 1, name: background")
        .replace("ignore_id: 255", "ignore_id: [0, 255]");
    let d = parse_in(dir.path(), &from_one).unwrap();
    assert_eq!(d.class_set.names(), ["background", "pedestrian"]);
    let values = d.class_set.label_values.as_ref().unwrap();
    assert_eq!(
        (values.classes.as_slice(), values.ignored.as_slice()),
        (&[1u8, 7][..], &[0u8, 255][..])
    );
    assert_eq!(d.class_set.ignore_id, Some(255));
    assert_eq!(
        (d.class_set.label_value(0), d.class_set.label_value(1)),
        (1, 7)
    );
}

#[test]
fn contradictions_are_refused_with_the_line() {
    let both = EXAMPLE.replace(
        "range: [21800, 25000]",
        "range: [21800, 25000]\n  min_max: true",
    );
    let text = refused(&both, 7);
    assert!(
        text.contains("one of range, min_max and percentile"),
        "{text}"
    );
    let text = refused(&EXAMPLE.replace("[21800, 25000]", "[25000, 21800]"), 6);
    assert!(text.contains("low end"), "{text}");
    let text = refused(&EXAMPLE.replace("ignore_id: 255", "ignore_id: 1"), 4);
    assert!(text.contains("also a class id"), "{text}");
    let colour = format!("{EXAMPLE}ignore_color: [1, 1, 1]\n");
    let text = refused(&colour, 7);
    assert!(
        text.contains("no effect with label_encoding: ids"),
        "{text}"
    );
    let temp = EXAMPLE.replace(
        "  range: [21800, 25000]",
        "  min_max: true\n  to_temperature: {scale: 0.04, offset: -273.15, unit: celsius}",
    );
    let text = refused(&temp, 7);
    assert!(text.contains("to_temperature"), "{text}");
    let same_colour = EXAMPLE.replace("[220, 20, 60]", "[0, 0, 0]") + "label_encoding: colors\n";
    let text = refused(&same_colour, 3);
    assert!(text.contains("distinct colours"), "{text}");
}

#[test]
fn a_path_outside_the_dataset_or_a_typo_is_refused_with_the_line() {
    let splits = "splits:\n  train: {rgb: ../train/rgb, thermal: train/thermal}\n";
    let text = refused(&format!("{EXAMPLE}{splits}"), 8);
    assert!(text.contains("points outside the dataset folder"), "{text}");
    let splits = "splits:\n  train: {rgb: train/rgbb, thermal: train/thermal}\n";
    let text = refused(&format!("{EXAMPLE}{splits}"), 8);
    assert!(
        text.contains("train/rgbb") && text.contains("no such folder"),
        "{text}"
    );
    let night = "night: {list: nights.txt}\n";
    let text = refused(&format!("{EXAMPLE}{night}"), 7);
    assert!(text.contains("no such file"), "{text}");
}

#[test]
fn patterns_split_lists_and_night_rules_resolve() {
    let dir = plain_root(EXAMPLE);
    write(&dir.path().join("lists/train.txt"), b"a\n");
    write(&dir.path().join("night.txt"), b"b\n");
    let yaml = format!(
        "{EXAMPLE}splits:\n  train: {{rgb: \"train/rgb/{{name}}.png\", thermal: train/thermal, list: lists/train.txt}}\nnight: {{list: night.txt}}\n"
    );
    let d = parse_in(dir.path(), &yaml).unwrap();
    let train = d.split("train").unwrap();
    assert_eq!(
        train.rgb.path(&vec![("name".into(), "x".into())]),
        dir.path().join("train/rgb/x.png")
    );
    assert_eq!(train.labels, None);
    assert_eq!(train.lists, [dir.path().join("lists/train.txt")]);
    let night = vec![dir.path().join("night.txt")];
    assert_eq!(d.night, NightRule::Lists { day: vec![], night });
    let yaml = EXAMPLE.replace("  range: [21800, 25000]", "  percentile: [1, 99]")
        + "night: {suffix: _n}\n";
    let d = parse_in(dir.path(), &yaml).unwrap();
    assert_eq!(
        d.thermal,
        ThermalNormalisation::Percentile { lo: 1.0, hi: 99.0 }
    );
    assert_eq!(d.night, NightRule::Suffix("_n".into()));
}
