//! A dataset root opened once: its layout recognised (dataset.yaml first, then MF, BDD,
//! Freiburg Thermal, MSRS, PST900, FMB), and for a described layout its description read, into
//! one [`Dataset`] that the commands and the training phases take. Before it, each user
//! (fingerprint, data check, the trainer, every command) recognised the root again and
//! dispatched on the layout itself.
//!
//! This module only routes: how a layout maps a folder to frames and a class set stays in the
//! layout's own file ([`crate::mf`], [`crate::freiburg`], [`crate::layouts`] with
//! [`crate::described`], [`crate::bdd`]).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rtf_core::ClassSet;

use crate::described::{DescribedDataset, DescribedSplit};
use crate::description::{DatasetDescription, LayoutKind, DESCRIPTION_FILE};
use crate::freiburg::{FreiburgPreprocess, FreiburgSplit};
use crate::mf::MfDataset;
use crate::trained_on::TrainedOn;
use crate::{DataError, FrameSource};

/// The layouts rtf recognises by their roots: the schema's (rtf-config; a fingerprint records
/// one).
pub use rtf_config::data::DatasetFormat;

/// The described layout `format` is, if it is one.
fn described_kind(format: DatasetFormat) -> Option<LayoutKind> {
    match format {
        DatasetFormat::Plain => Some(LayoutKind::Plain),
        DatasetFormat::Msrs => Some(LayoutKind::Msrs),
        DatasetFormat::Pst900 => Some(LayoutKind::Pst900),
        DatasetFormat::Fmb => Some(LayoutKind::Fmb),
        DatasetFormat::Mf | DatasetFormat::Freiburg | DatasetFormat::Bdd => None,
    }
}

impl From<LayoutKind> for DatasetFormat {
    fn from(kind: LayoutKind) -> Self {
        match kind {
            LayoutKind::Plain => Self::Plain,
            LayoutKind::Msrs => Self::Msrs,
            LayoutKind::Pst900 => Self::Pst900,
            LayoutKind::Fmb => Self::Fmb,
        }
    }
}

/// What a root that is no dataset is told.
pub const NOT_A_DATASET: &str = "not a dataset root: expected dataset.yaml (plain layout), images/ + labels/ (MF), fl_rgb/ or ImagesRGB/ folders (Freiburg Thermal), or {train,test}/ with vi+ir (MSRS), rgb+thermal (PST900) or Visible+Infrared (FMB)";

/// The dataset root a user's path names: the folder itself, or the folder of a `dataset.yaml`
/// given as the file (`--data sets/thermal/dataset.yaml`). Commands take it at the edge, so a
/// run records, fingerprints and reopens the folder however it was named.
pub fn root_of(path: &Path) -> PathBuf {
    if is_description_file(path) {
        return match path.parent() {
            Some(parent) if !parent.as_os_str().is_empty() => parent.to_path_buf(),
            _ => PathBuf::from("."),
        };
    }
    path.to_path_buf()
}

/// Whether `path` is a plain layout's `dataset.yaml`, given as the file.
fn is_description_file(path: &Path) -> bool {
    path.is_file() && path.file_name().is_some_and(|n| n == DESCRIPTION_FILE)
}

/// [`root_of`] as a command-line value parser (`--data`, `rtf data check DIR`).
pub fn parse_root(arg: &str) -> Result<PathBuf, std::convert::Infallible> {
    Ok(root_of(Path::new(arg)))
}

/// Recognises a dataset root by its layout. A dataset.yaml wins over every built-in layout.
pub fn recognise(root: &Path) -> Option<DatasetFormat> {
    if root.join(DESCRIPTION_FILE).is_file() {
        return Some(DatasetFormat::Plain);
    }
    if root.join("images").is_dir() && root.join("labels").is_dir() {
        // BDD keeps its images in per-split folders; MF keeps PNGs directly in images/. An
        // images/ of folders only (a set recorded as sequences) is neither.
        if !bdd_splits(root).is_empty() {
            return Some(DatasetFormat::Bdd);
        }
        if !only_folders(&root.join("images")) {
            return Some(DatasetFormat::Mf);
        }
    }
    let mut found = Vec::new();
    for name in ["fl_rgb", "ImagesRGB"] {
        let _ = find_dir(root, name, 6, &mut found);
    }
    if !found.is_empty() {
        return Some(DatasetFormat::Freiburg);
    }
    crate::layouts::recognise(root).map(DatasetFormat::from)
}

/// Whether `dir` holds folders and no file (hidden entries aside).
fn only_folders(dir: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return false;
    };
    let visible: Vec<std::fs::DirEntry> = entries
        .flatten()
        .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    !visible.is_empty() && visible.iter().all(|e| e.path().is_dir())
}

/// Sub-folders of `images/` that have a matching `labels/` folder (BDD splits).
pub(crate) fn bdd_splits(root: &Path) -> Vec<String> {
    let mut out: Vec<String> = std::fs::read_dir(root.join("images"))
        .map(|rd| {
            rd.flatten()
                .map(|e| e.path())
                .filter(|p| p.is_dir())
                .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                .filter(|n| root.join("labels").join(n).is_dir())
                .collect()
        })
        .unwrap_or_default();
    out.sort();
    out
}

fn find_dir(root: &Path, name: &str, depth: usize, out: &mut Vec<PathBuf>) -> std::io::Result<()> {
    for e in std::fs::read_dir(root)? {
        let p = e?.path();
        if p.is_dir() {
            if p.file_name().is_some_and(|n| n == name) {
                out.push(p);
                return Ok(());
            } else if depth > 0 {
                find_dir(&p, name, depth - 1, out)?;
            }
        }
    }
    Ok(())
}

/// How a layout's frames are read: MF, Freiburg Thermal and BDD by their own readers (opened
/// when a split is asked for, so that `rtf data check` lists their problems), the others
/// through their description (read when the root is opened).
#[derive(Debug, Clone)]
pub enum Layout {
    Mf,
    Freiburg,
    Bdd,
    Described(Box<DatasetDescription>),
}

/// The kind of root a training run records, and which frames it reads: the schema's
/// (rtf-config).
pub use rtf_config::data::{RecordedKind, TrainingChoice};

/// A training run's frames: the training frames (labelled ones when the procedure reads
/// labels) and the validation frames, if any.
pub struct TrainingFrames {
    pub train: Arc<dyn FrameSource>,
    pub val: Option<Arc<dyn FrameSource>>,
}

/// A dataset root, recognised once (module docs).
#[derive(Debug, Clone)]
pub struct Dataset {
    root: PathBuf,
    layout: Layout,
}

/// Opens `root`: its layout recognised, its description read (described layouts). A root of
/// no known layout is an error naming it ([`NOT_A_DATASET`]).
pub fn open(root: &Path) -> Result<Dataset, DataError> {
    let format = recognise(root).ok_or_else(|| not_a_dataset(root))?;
    Dataset::open_as(root, format)
}

/// Opens `root` for `purpose` ("a training", "an evaluation"): MF, Freiburg Thermal or a
/// described layout (dataset.yaml, MSRS, PST900, FMB); anything else (BDD's night frames are
/// read only beside a Freiburg root) is an error naming the root and the layouts rtf reads.
pub fn open_for(root: &Path, purpose: &str) -> Result<Dataset, DataError> {
    let format = match recognise(root) {
        Some(format @ (DatasetFormat::Mf | DatasetFormat::Freiburg)) => format,
        Some(format) if format.is_described() => format,
        None if root.is_file() => return Err(not_a_dataset(root)),
        other => {
            let found = other.map_or("no known layout".to_string(), |f| format!("{f:?} layout"));
            return Err(DataError::Layout {
                root: root.to_path_buf(),
                message: format!(
                    "not {purpose} dataset rtf can read ({found}; expected dataset.yaml, or the \
                     MF, Freiburg Thermal, MSRS, PST900 or FMB layout, see `rtf data check`)"
                ),
            });
        }
    };
    Dataset::open_as(root, format)
}

fn not_a_dataset(root: &Path) -> DataError {
    let message = if is_description_file(root) {
        format!("a file, not a folder: give the folder that holds {DESCRIPTION_FILE}")
    } else if root.is_file() {
        format!("a file, not a folder: {NOT_A_DATASET} (a plain layout's file must be named {DESCRIPTION_FILE})")
    } else {
        NOT_A_DATASET.into()
    };
    DataError::Layout {
        root: root.to_path_buf(),
        message,
    }
}

impl Dataset {
    /// Opens `root` as the layout `format` ([`recognise`]'s answer).
    pub fn open_as(root: &Path, format: DatasetFormat) -> Result<Self, DataError> {
        let layout = match (format, described_kind(format)) {
            (_, Some(kind)) => {
                Layout::Described(Box::new(crate::layouts::describe_as(root, kind)?))
            }
            (DatasetFormat::Mf, _) => Layout::Mf,
            (DatasetFormat::Freiburg, _) => Layout::Freiburg,
            _ => Layout::Bdd,
        };
        Ok(Self {
            root: root.to_path_buf(),
            layout,
        })
    }

    /// Opens `root` as the kind a run recorded.
    pub fn open_recorded(root: &Path, kind: RecordedKind) -> Result<Self, DataError> {
        match kind {
            RecordedKind::Mf => Self::open_as(root, DatasetFormat::Mf),
            RecordedKind::Freiburg => Self::open_as(root, DatasetFormat::Freiburg),
            RecordedKind::Described => {
                let description =
                    crate::layouts::describe(root).ok_or_else(|| not_a_dataset(root))??;
                Ok(Self {
                    root: root.to_path_buf(),
                    layout: Layout::Described(Box::new(description)),
                })
            }
        }
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    pub fn format(&self) -> DatasetFormat {
        match &self.layout {
            Layout::Mf => DatasetFormat::Mf,
            Layout::Freiburg => DatasetFormat::Freiburg,
            Layout::Bdd => DatasetFormat::Bdd,
            Layout::Described(d) => d.layout.into(),
        }
    }

    /// The layout's name as rtf prints it ("MF", "PST900", …).
    pub fn layout_name(&self) -> &'static str {
        self.format().name()
    }

    /// The description a described layout reads its frames through.
    pub fn description(&self) -> Option<&DatasetDescription> {
        match &self.layout {
            Layout::Described(d) => Some(d),
            _ => None,
        }
    }

    /// The file that decides the class set: a dataset.yaml, else the root.
    pub fn origin(&self) -> &Path {
        self.description().map_or(&self.root, |d| &d.origin)
    }

    /// The classes the layout's labels hold.
    pub fn class_set(&self) -> ClassSet {
        self.trained_on().classes
    }

    /// The class set and thermal rule weights trained on this dataset record.
    pub fn trained_on(&self) -> TrainedOn {
        match &self.layout {
            Layout::Mf => TrainedOn::mf(),
            Layout::Freiburg | Layout::Bdd => TrainedOn::freiburg(),
            Layout::Described(d) => crate::trained_on::of(d),
        }
    }

    /// Whether validation also scores HeatNet's convention (Freiburg Thermal).
    pub fn scores_heatnet(&self) -> bool {
        matches!(self.layout, Layout::Freiburg)
    }

    /// The splits [`Self::split`] reads, sorted as the layout lists them.
    pub fn split_names(&self) -> Result<Vec<String>, DataError> {
        Ok(match &self.layout {
            Layout::Mf => MfDataset::open(&self.root)?.split_names().to_vec(),
            Layout::Freiburg => vec!["test".into(), "train".into()],
            Layout::Bdd => crate::bdd::lists(&self.root),
            Layout::Described(d) => d.split_names().into_iter().map(String::from).collect(),
        })
    }

    /// What `rtf` announces on stderr about a described root (nothing about a dataset is
    /// inferred silently): its layout, classes and thermal rule. None for MF and Freiburg,
    /// whose layout fixes them.
    pub fn announcement(&self) -> Option<String> {
        let d = self.description()?;
        Some(format!(
            "{}: {} layout; {} classes ({}); thermal {}",
            self.root.display(),
            d.layout.name(),
            d.class_set.len(),
            d.class_set.names().join(", "),
            d.thermal.describe()
        ))
    }

    /// The frames of split `name` (Freiburg: `test` or `train`, with the reference test
    /// preprocessing); with `labels`, a split without labels is refused.
    pub fn split(&self, name: &str, labels: bool) -> Result<Arc<dyn FrameSource>, DataError> {
        Ok(match &self.layout {
            Layout::Mf => {
                let mf = MfDataset::open(&self.root)?;
                Arc::new(match labels {
                    true => mf.split(name)?,
                    false => mf.split_images_only(name)?,
                })
            }
            Layout::Freiburg => {
                let pre = FreiburgPreprocess::reference_test();
                Arc::new(FreiburgSplit::named_part(&self.root, name, pre, labels)?)
            }
            Layout::Bdd => {
                Err(self.error("rtf reads BDD only in `rtf data check` and `rtf data stats`"))?
            }
            Layout::Described(d) => Arc::new(self.described_split(d, name, labels)?),
        })
    }

    fn described_split(
        &self,
        description: &DatasetDescription,
        name: &str,
        labels: bool,
    ) -> Result<DescribedSplit, DataError> {
        let split = DescribedDataset::new(description.clone()).split(name)?;
        // What the user asked to have skipped (unmatched_lines: warn) is said, counted.
        for warning in split.warnings() {
            eprintln!("warning: {warning}");
        }
        if labels && !split.labelled() {
            return Err(self.error(&format!(
                "the `{}` split has no labels to evaluate against",
                split.name()
            )));
        }
        Ok(split)
    }

    /// The frames a training run reads (labelled ones when `labels`): the training split and
    /// the validation frames `choice` names.
    pub fn training(
        &self,
        choice: &TrainingChoice,
        labels: bool,
    ) -> Result<TrainingFrames, DataError> {
        let (train, val) = (choice.train_split.as_str(), choice.val_split.as_deref());
        Ok(match &self.layout {
            Layout::Mf => frames(MfDataset::open(&self.root)?.training_splits(train, val, labels)?),
            Layout::Freiburg => {
                let (pre_train, pre_val) = &choice.preprocess;
                let validate = val.is_some();
                frames(FreiburgSplit::training_parts(
                    &self.root,
                    (pre_train, pre_val),
                    validate,
                    labels,
                )?)
            }
            Layout::Bdd => {
                Err(self.error("rtf does not train on BDD (it holds no training split)"))?
            }
            Layout::Described(d) => {
                frames(DescribedDataset::new((**d).clone()).training_splits(train, val)?)
            }
        })
    }

    /// An error about this root.
    fn error(&self, message: &str) -> DataError {
        DataError::Layout {
            root: self.root.clone(),
            message: message.to_string(),
        }
    }
}

/// A layout's (training, validation) pair as frame sources.
fn frames<S: FrameSource + 'static>((train, val): (S, Option<S>)) -> TrainingFrames {
    TrainingFrames {
        train: Arc::new(train),
        val: val.map(|v| Arc::new(v) as Arc<dyn FrameSource>),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::description::tests::{plain_root, EXAMPLE};
    use crate::synth::{generate, SynthConfig, SynthFormat};
    use crate::testutil::{mf_dataset, write_rgbt_frame, RgbtFolders, ThermalFixture};

    /// The schema's view of the layouts (described or not) is the readers': every described
    /// format is a layout kind and back, and the others are none.
    #[test]
    fn described_formats_are_exactly_the_layout_kinds() {
        use DatasetFormat::*;
        for format in [Mf, Freiburg, Bdd, Plain, Msrs, Pst900, Fmb] {
            let kind = described_kind(format);
            assert_eq!(format.is_described(), kind.is_some(), "{format:?}");
            if let Some(kind) = kind {
                assert_eq!(DatasetFormat::from(kind), format);
            }
        }
    }

    /// `{train,test}/<folders>/a.png` with ids below `classes`.
    fn built_in_root(root: &Path, folders: &RgbtFolders, classes: u8) {
        for split in ["train", "test"] {
            let dir = root.join(split);
            write_rgbt_frame(&dir, folders, "a", (4, 3), ThermalFixture::Grey8, classes);
        }
    }

    fn opened(root: &Path) -> (DatasetFormat, ClassSet, Vec<String>) {
        let dataset = open(root).unwrap();
        let names = dataset.split_names().unwrap();
        (dataset.format(), dataset.class_set(), names)
    }

    #[test]
    fn each_layout_opens_to_its_kind_classes_and_splits() {
        let mf = tempfile::tempdir().unwrap();
        mf_dataset(mf.path(), &["00001D", "00002N"], 4, 3);
        let (format, classes, splits) = opened(mf.path());
        assert_eq!(
            (format, classes, splits),
            (DatasetFormat::Mf, ClassSet::mf(), vec!["train".to_string()])
        );

        let fr = tempfile::tempdir().unwrap();
        let cfg = SynthConfig {
            count: 8,
            width: 64,
            height: 48,
            format: SynthFormat::Freiburg,
            ..SynthConfig::default()
        };
        generate(fr.path(), &cfg).unwrap();
        let (format, classes, splits) = opened(fr.path());
        assert_eq!(
            (format, classes),
            (DatasetFormat::Freiburg, ClassSet::freiburg())
        );
        assert_eq!(splits, ["test", "train"]);

        let plain = plain_root(EXAMPLE);
        let (format, classes, splits) = opened(plain.path());
        assert_eq!(format, DatasetFormat::Plain);
        assert_eq!(classes.names(), ["background", "pedestrian"]);
        assert_eq!(splits, ["train", "val"]);

        for (format, rgb, thermal, labels, classes) in [
            (DatasetFormat::Msrs, "vi", "ir", "Label", 9),
            (DatasetFormat::Pst900, "rgb", "thermal", "labels", 5),
            (DatasetFormat::Fmb, "Visible", "Infrared", "Label", 15),
        ] {
            let dir = tempfile::tempdir().unwrap();
            let folders = RgbtFolders {
                rgb,
                thermal,
                labels,
            };
            built_in_root(dir.path(), &folders, classes as u8);
            let (found, class_set, mut splits) = opened(dir.path());
            splits.sort();
            assert_eq!(found, format);
            assert_eq!(class_set.len(), classes);
            assert_eq!(splits, ["test", "train"], "{format:?}");
        }
    }

    #[test]
    fn a_root_of_no_layout_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let err = open(dir.path()).unwrap_err().to_string();
        assert!(err.ends_with(NOT_A_DATASET), "{err}");
    }

    /// A dataset.yaml given as the file names its folder; any other path is kept, and a file
    /// that is not one is refused as a file.
    #[test]
    fn a_dataset_yaml_file_names_its_folder() {
        let plain = plain_root(EXAMPLE);
        let yaml = plain.path().join(DESCRIPTION_FILE);
        assert_eq!(root_of(&yaml), plain.path());
        assert_eq!(root_of(plain.path()), plain.path());
        assert_eq!(
            open(&root_of(&yaml)).unwrap().format(),
            DatasetFormat::Plain
        );
        let missing = plain.path().join("missing").join(DESCRIPTION_FILE);
        assert_eq!(root_of(&missing), missing);

        let other = plain.path().join("notes.yaml");
        std::fs::write(&other, "x: 1").unwrap();
        assert_eq!(root_of(&other), other);
        let err = open(&other).unwrap_err().to_string();
        assert!(
            err.contains("a file, not a folder") && err.contains(NOT_A_DATASET),
            "{err}"
        );
        // A library caller that skips root_of is told to give the folder.
        let err = open_for(&yaml, "a training").unwrap_err().to_string();
        assert!(
            err.contains("give the folder that holds dataset.yaml"),
            "{err}"
        );
        let err = open(&yaml).unwrap_err().to_string();
        assert!(
            err.contains("give the folder that holds dataset.yaml"),
            "{err}"
        );
    }

    #[test]
    fn described_splits_and_holdout_route_through_the_description() {
        let plain = plain_root(EXAMPLE);
        let dataset = open(plain.path()).unwrap();
        assert!(dataset
            .announcement()
            .unwrap()
            .contains("plain (dataset.yaml) layout; 2 classes"));
        let choice = TrainingChoice {
            kind: RecordedKind::Described,
            train_split: "train".into(),
            val_split: Some("holdout:2".into()),
            preprocess: (FreiburgPreprocess::native(), FreiburgPreprocess::native()),
        };
        let frames = dataset.training(&choice, true).unwrap();
        assert_eq!((frames.train.len(), frames.val.unwrap().len()), (1, 1));
        assert_eq!(dataset.split("val", true).unwrap().len(), 2);
        let recorded = Dataset::open_recorded(plain.path(), RecordedKind::Described).unwrap();
        assert_eq!(recorded.trained_on(), dataset.trained_on());
    }
}
