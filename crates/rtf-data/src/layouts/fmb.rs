//! FMB (Liu et al., "Multi-interactive Feature Learning and a Full-time Multi-modality
//! Benchmark for Image Fusion and Segmentation", ICCV 2023; github.com/JinyuanLiu-CV/SegMiF):
//! street scenes, day and night (not marked in the names). Layout:
//! `{train,test}/Visible/NAME.png` (RGB), `{train,test}/Infrared/NAME.png` (8-bit grey, also
//! stored as grey RGB), `{train,test}/Label/NAME.png` (8-bit ids). 15 classes, id 0 the
//! background; 255 is ignored, as the field's readers (CMNeXt, Sigma) do. Colours: those
//! readers' palette.

use std::path::Path;

use super::{built_in, class_table, Folders};
use crate::description::{DatasetDescription, LayoutKind, NightRule};

const FOLDERS: Folders = Folders {
    rgb: "Visible",
    thermal: "Infrared",
    labels: "Label",
};

pub const CLASSES: [(&str, [u8; 3]); 15] = [
    ("background", [0, 0, 0]),
    ("road", [228, 228, 179]),
    ("sidewalk", [133, 57, 181]),
    ("building", [177, 162, 67]),
    ("lamp", [50, 178, 200]),
    ("sign", [199, 45, 132]),
    ("vegetation", [84, 172, 66]),
    ("sky", [79, 73, 179]),
    ("person", [166, 99, 76]),
    ("car", [253, 121, 66]),
    ("truck", [91, 165, 137]),
    ("bus", [152, 97, 155]),
    ("motorcycle", [140, 153, 105]),
    ("bicycle", [158, 215, 222]),
    ("pole", [90, 113, 135]),
];

/// The ignore id of FMB labels.
pub const IGNORE_ID: u8 = 255;

pub fn matches(root: &Path) -> bool {
    FOLDERS.in_train_or_test(root)
}

pub fn describe(root: &Path) -> DatasetDescription {
    let splits = FOLDERS.splits(root, &["train", "test"]);
    let classes = class_table("fmb", &CLASSES, Some(IGNORE_ID));
    built_in(root, LayoutKind::Fmb, classes, splits, NightRule::None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layouts::recognise;
    use crate::testutil::*;
    use crate::{DescribedDataset, FrameSource};

    const FMB: RgbtFolders = RgbtFolders {
        rgb: "Visible",
        thermal: "Infrared",
        labels: "Label",
    };

    /// The release's layout: `{train,test}/{Visible,Infrared,Label}/NAME.png`, thermal as grey
    /// RGB, ids 0..14 and 255 (ignored).
    #[test]
    fn fmb_root_reads_fifteen_classes_grey_rgb_thermal_and_ignore_255() {
        let dir = tempfile::tempdir().unwrap();
        for split in ["train", "test"] {
            let d = dir.path().join(split);
            write_rgbt_frame(&d, &FMB, "00017", (6, 5), ThermalFixture::GreyAsRgb8, 15);
        }
        let mut label = ids(6, 5, 15);
        label[0] = IGNORE_ID;
        write(
            &dir.path().join("train/Label/00017.png"),
            &png_u8(6, 5, 1, &label),
        );
        assert_eq!(recognise(dir.path()), Some(LayoutKind::Fmb));
        let d = describe(dir.path());
        assert_eq!(d.class_set.len(), 15);
        assert_eq!(d.class_set.ignore_id, Some(255));
        let train = DescribedDataset::new(d).split("train").unwrap();
        let f = train.load(0).unwrap();
        assert_eq!(f.label.unwrap(), label);
        assert_eq!(f.thermal[2], 2.0 / 255.0);
    }
}
