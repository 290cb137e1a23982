//! MSRS (Tang et al., "PIAFusion", Information Fusion 2022; the "Multi-Spectral Road
//! Scenarios" release, github.com/Linfeng-Tang/MSRS): the MF dataset (spec §1) re-registered,
//! misaligned pairs dropped, thermal contrast-enhanced. Layout: `{train,test}/vi/NAME.png`
//! (RGB, 8-bit), `{train,test}/ir/NAME.png` (8-bit grey), `{train,test}/Label/NAME.png`
//! (8-bit class ids, MF's 9 classes). Names keep MF's `D`/`N` suffix (day/night).
//!
//! A root holding `vi/` and `ir/` directly (one split of the release, as
//! `../shared/data/msrs-samples`) is read as one split named `all`.

use std::path::Path;

use rtf_core::ClassSet;

use super::{built_in, Folders};
use crate::description::{DatasetDescription, LayoutKind, NightRule};

const FOLDERS: Folders = Folders {
    rgb: "vi",
    thermal: "ir",
    labels: "Label",
};

pub fn matches(root: &Path) -> bool {
    FOLDERS.in_train_or_test(root) || FOLDERS.present_in(root)
}

pub fn describe(root: &Path) -> DatasetDescription {
    let mut splits = FOLDERS.splits(root, &["train", "test"]);
    if splits.is_empty() {
        splits.push(FOLDERS.split("all", root));
    }
    let mut classes = ClassSet::mf();
    classes.name = "msrs".into();
    built_in(
        root,
        LayoutKind::Msrs,
        classes,
        splits,
        NightRule::Suffix("N".into()),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layouts::recognise;
    use crate::testutil::*;
    use crate::{DescribedDataset, FrameSource};
    use rtf_core::Daytime;

    const MSRS: RgbtFolders = RgbtFolders {
        rgb: "vi",
        thermal: "ir",
        labels: "Label",
    };

    /// The release's layout: `{train,test}/{vi,ir,Label}/NAME.png`, MF names with D/N,
    /// 8-bit RGB, 8-bit grey thermal, 8-bit ids 0..8.
    fn msrs_fixture(root: &Path) {
        for (split, names) in [
            ("train", ["00001D", "00002N"]),
            ("test", ["00004N", "00005D"]),
        ] {
            for name in names {
                write_rgbt_frame(
                    &root.join(split),
                    &MSRS,
                    name,
                    (8, 6),
                    ThermalFixture::Grey8,
                    9,
                );
            }
        }
    }

    #[test]
    fn msrs_root_reads_mf_classes_day_night_and_byte_thermal() {
        let dir = tempfile::tempdir().unwrap();
        msrs_fixture(dir.path());
        assert_eq!(recognise(dir.path()), Some(LayoutKind::Msrs));
        let d = describe(dir.path());
        assert_eq!(d.class_set.len(), 9);
        assert_eq!(d.class_set.names(), ClassSet::mf().names());
        assert_eq!(d.split_names(), vec!["train", "test"]);
        let train = DescribedDataset::new(d).split("train").unwrap();
        assert_eq!(train.len(), 2);
        assert_eq!(train.daytime(0), Some(Daytime::Day));
        assert_eq!(train.daytime(1), Some(Daytime::Night));
        let f = train.load(1).unwrap();
        assert_eq!((f.width, f.height, f.name.as_str()), (8, 6, "00002N"));
        assert_eq!(f.thermal[7], 7.0 / 255.0);
        assert_eq!(f.label.unwrap(), ids(8, 6, 9));
        assert_eq!(&f.rgb[..], &rgb(8, 6, 6)[..]);
    }

    #[test]
    fn a_flat_vi_ir_folder_is_one_unlabelled_split() {
        let dir = tempfile::tempdir().unwrap();
        let flat = RgbtFolders { labels: "", ..MSRS };
        write_rgbt_frame(
            dir.path(),
            &flat,
            "00004N",
            (8, 6),
            ThermalFixture::Grey8,
            9,
        );
        let d = describe(dir.path());
        assert_eq!(d.split_names(), vec!["all"]);
        let all = DescribedDataset::new(d).split("all").unwrap();
        assert!(!all.labelled());
        assert_eq!(all.load(0).unwrap().label, None);
    }

    /// The 48 real MSRS test scenes of ../shared/data/msrs-samples (README there): a flat
    /// vi/ + ir/ folder, 640×480, 24 day and 24 night by the D/N suffix, grey thermal.
    #[test]
    fn the_real_msrs_samples_read_as_one_split_of_48_frames() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/msrs-samples");
        assert_eq!(recognise(&root), Some(LayoutKind::Msrs));
        let all = DescribedDataset::new(describe(&root)).split("all").unwrap();
        assert_eq!(all.len(), 48);
        let night = (0..48)
            .filter(|&i| all.daytime(i) == Some(Daytime::Night))
            .count();
        assert_eq!(night, 24);
        let f = all.load(0).unwrap();
        assert_eq!((f.width, f.height, f.label.is_none()), (640, 480, true));
        let mean = f.thermal.iter().sum::<f32>() / f.thermal.len() as f32;
        let spread = f.thermal.iter().fold(0f32, |m, &t| m.max((t - mean).abs()));
        assert!(
            mean > 0.02 && mean < 0.98 && spread > 0.1,
            "thermal mean {mean}, spread {spread}"
        );
    }
}
