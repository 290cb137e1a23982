//! The RGB-T layouts rtf recognises by their roots, besides MF, Freiburg Thermal and BDD
//! ([`crate::dataset::recognise`]). Each maps a folder to frames and a class set as a
//! [`DatasetDescription`]; each file says where its layout comes from.
//!
//! - plain: `ROOT/dataset.yaml` ([`crate::description`]) — checked first, so a description
//!   beside any of the layouts below overrides the built-in reading.
//! - MSRS: `{train,test}/{vi,ir,Label}` ([`msrs`]).
//! - PST900: `{train,test}/{rgb,thermal,labels}` ([`pst900`]).
//! - FMB: `{train,test}/{Visible,Infrared,Label}` ([`fmb`]).

pub mod fmb;
pub mod msrs;
pub mod pst900;

use std::path::{Path, PathBuf};

use rtf_core::{ClassInfo, ClassSet};

use crate::description::{
    read_description, DatasetDescription, FilePattern, LabelEncoding, LayoutKind, NightRule,
    SplitSpec, DESCRIPTION_FILE,
};
use crate::images::Format;
use crate::thermal::ThermalNormalisation;
use crate::DataError;

/// The layout of `root`, if it is one of this module's.
pub fn recognise(root: &Path) -> Option<LayoutKind> {
    if root.join(DESCRIPTION_FILE).is_file() {
        Some(LayoutKind::Plain)
    } else if msrs::matches(root) {
        Some(LayoutKind::Msrs)
    } else if pst900::matches(root) {
        Some(LayoutKind::Pst900)
    } else if fmb::matches(root) {
        Some(LayoutKind::Fmb)
    } else {
        None
    }
}

/// The description of `root` in its layout: dataset.yaml read and checked, or the built-in
/// one. `None` when the root is none of this module's layouts.
pub fn describe(root: &Path) -> Option<Result<DatasetDescription, DataError>> {
    Some(describe_as(root, recognise(root)?))
}

/// The description of `root` read as the layout `kind` (already recognised).
pub fn describe_as(root: &Path, kind: LayoutKind) -> Result<DatasetDescription, DataError> {
    match kind {
        LayoutKind::Plain => read_description(&root.join(DESCRIPTION_FILE)),
        LayoutKind::Msrs => Ok(msrs::describe(root)),
        LayoutKind::Pst900 => Ok(pst900::describe(root)),
        LayoutKind::Fmb => Ok(fmb::describe(root)),
    }
}

/// The folders of a built-in layout: split `s` has `s/<rgb>`, `s/<thermal>` and, when present,
/// `s/<labels>`.
pub(crate) struct Folders {
    pub rgb: &'static str,
    pub thermal: &'static str,
    pub labels: &'static str,
}

impl Folders {
    /// Whether `dir` has the RGB and thermal folders.
    pub fn present_in(&self, dir: &Path) -> bool {
        dir.join(self.rgb).is_dir() && dir.join(self.thermal).is_dir()
    }

    /// Whether `root/train` or `root/test` has the RGB and thermal folders (the public sets
    /// ship these two splits).
    pub fn in_train_or_test(&self, root: &Path) -> bool {
        ["train", "test"]
            .iter()
            .any(|s| self.present_in(&root.join(s)))
    }

    /// The splits among `names` that have the RGB and thermal folders.
    pub fn splits(&self, root: &Path, names: &[&str]) -> Vec<SplitSpec> {
        names
            .iter()
            .map(|name| (name, root.join(name)))
            .filter(|(_, dir)| self.present_in(dir))
            .map(|(name, dir)| self.split(name, &dir))
            .collect()
    }

    pub fn split(&self, name: &str, dir: &Path) -> SplitSpec {
        let labels = dir.join(self.labels);
        SplitSpec {
            name: name.to_string(),
            rgb: FilePattern::folder(dir.join(self.rgb), Format::RGB),
            thermal: FilePattern::folder(dir.join(self.thermal), Format::THERMAL),
            labels: labels
                .is_dir()
                .then(|| FilePattern::folder(labels, Format::LABEL)),
            lists: Vec::new(),
        }
    }
}

/// A class set from a table of (name, colour), ids in table order.
pub(crate) fn class_table(
    name: &str,
    table: &[(&str, [u8; 3])],
    ignore_id: Option<u8>,
) -> ClassSet {
    ClassSet {
        name: name.to_string(),
        classes: table
            .iter()
            .enumerate()
            .map(|(id, (n, color))| ClassInfo {
                id: id as u8,
                name: n.to_string(),
                color: *color,
            })
            .collect(),
        ignore_id,
        label_values: None,
    }
}

/// A built-in layout's description: id-coded labels, 8-bit thermal.
pub(crate) fn built_in(
    root: &Path,
    layout: LayoutKind,
    class_set: ClassSet,
    splits: Vec<SplitSpec>,
    night: NightRule,
) -> DatasetDescription {
    DatasetDescription {
        root: root.to_path_buf(),
        origin: PathBuf::from(root),
        layout,
        class_set,
        labels: LabelEncoding::Ids,
        ignore_color: None,
        thermal: ThermalNormalisation::Byte,
        splits,
        night,
        unmatched_lines: Default::default(),
    }
}
