//! PST900 (Shivakumar et al., "PST900: RGB-Thermal Calibration, Dataset and Segmentation
//! Network", ICRA 2020; github.com/ShreyasSkandanS/pst900_thermal_rgb): subterranean scenes.
//! Layout: `{train,test}/rgb/NAME.png` (RGB, 8-bit), `{train,test}/thermal/NAME.png` (FLIR's
//! 8-bit AGC output), `{train,test}/labels/NAME.png` (8-bit ids 0..4), the same NAME in every
//! folder. The release's `thermal_raw/` (16-bit) and `depth/` are not read: describe them in a
//! dataset.yaml to train on raw counts. No day/night.
//!
//! Classes: background, fire_extinguisher, backpack, hand_drill, survivor (paper, Table I).
//! Colours: the release's visualisation draws fire extinguishers red and survivors white; the
//! others are rtf's choice.

use std::path::Path;

use super::{built_in, class_table, Folders};
use crate::description::{DatasetDescription, LayoutKind, NightRule};

const FOLDERS: Folders = Folders {
    rgb: "rgb",
    thermal: "thermal",
    labels: "labels",
};

pub const CLASSES: [(&str, [u8; 3]); 5] = [
    ("background", [0, 0, 0]),
    ("fire_extinguisher", [255, 0, 0]),
    ("backpack", [0, 0, 255]),
    ("hand_drill", [0, 255, 0]),
    ("survivor", [255, 255, 255]),
];

pub fn matches(root: &Path) -> bool {
    FOLDERS.in_train_or_test(root)
}

pub fn describe(root: &Path) -> DatasetDescription {
    let splits = FOLDERS.splits(root, &["train", "test"]);
    let classes = class_table("pst900", &CLASSES, None);
    built_in(root, LayoutKind::Pst900, classes, splits, NightRule::None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layouts::recognise;
    use crate::testutil::*;
    use crate::{DataError, DescribedDataset, FrameSource};

    const PST: RgbtFolders = RgbtFolders {
        rgb: "rgb",
        thermal: "thermal",
        labels: "labels",
    };
    const NAME: &str = "31_bag1a_rect_rgb_frame0000000007";

    /// The release's layout: `{train,test}/{rgb,thermal,labels}` (plus `thermal_raw/` and
    /// `depth/`, not read), one NAME across folders, 8-bit AGC thermal, ids 0..4.
    fn pst_fixture(root: &Path) {
        for split in ["train", "test"] {
            let dir = root.join(split);
            write_rgbt_frame(&dir, &PST, NAME, (10, 4), ThermalFixture::Grey8, 5);
            let raw = RgbtFolders {
                rgb: "depth",
                thermal: "thermal_raw",
                labels: "",
            };
            write_rgbt_frame(
                &dir,
                &raw,
                NAME,
                (10, 4),
                ThermalFixture::Raw16 { base: 20000 },
                5,
            );
        }
    }

    #[test]
    fn pst900_root_reads_its_five_classes() {
        let dir = tempfile::tempdir().unwrap();
        pst_fixture(dir.path());
        assert_eq!(recognise(dir.path()), Some(LayoutKind::Pst900));
        let d = describe(dir.path());
        let names = d.class_set.names();
        assert_eq!(
            names,
            [
                "background",
                "fire_extinguisher",
                "backpack",
                "hand_drill",
                "survivor"
            ]
        );
        let test = DescribedDataset::new(d).split("test").unwrap();
        let f = test.load(0).unwrap();
        assert_eq!(f.daytime, None);
        assert_eq!(f.label.unwrap(), ids(10, 4, 5));
        assert_eq!(
            f.thermal[3],
            3.0 / 255.0,
            "8-bit thermal/, not thermal_raw/"
        );
    }

    #[test]
    fn a_label_id_outside_the_five_classes_names_the_file_and_id() {
        let dir = tempfile::tempdir().unwrap();
        pst_fixture(dir.path());
        let label = dir.path().join("train/labels").join(format!("{NAME}.png"));
        write(&label, &png_u8(10, 4, 1, &ids(10, 4, 7)));
        let train = DescribedDataset::new(describe(dir.path()))
            .split("train")
            .unwrap();
        let err = train.load(0).unwrap_err();
        assert!(
            matches!(err, DataError::LabelOutOfRange { id: 5, .. }),
            "{err}"
        );
        let text = err.to_string();
        assert!(
            text.contains(&label.display().to_string()) && text.contains("id 5"),
            "{text}"
        );
    }
}
