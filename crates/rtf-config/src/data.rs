//! The dataset a run reads, as data: which kind of root and which frames ([`RecordedKind`],
//! [`TrainingChoice`]), the layouts rtf recognises ([`DatasetFormat`]), Freiburg Thermal's
//! preprocessing, the augmentation, the thermal rule, a dataset's fingerprint, and what a
//! network was trained on ([`TrainedOn`]). rtf-data opens, reads and fingerprints datasets
//! with these values.

use rtf_core::ClassSet;
use serde::{Deserialize, Serialize};

mod augment;
mod fingerprint;
mod thermal;

pub use augment::{AugmentConfig, ScaleCrop};
pub use fingerprint::{Fingerprint, SplitFingerprint, ALGORITHM};
pub use thermal::{TemperatureMap, TemperatureUnit, ThermalNormalisation};

/// The layouts rtf recognises by their roots.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DatasetFormat {
    Mf,
    Freiburg,
    /// BDD100K night as HeatNet reads it: `<list>.txt`, `images/<split>/`, `labels/<split>/`.
    Bdd,
    /// `ROOT/dataset.yaml` and the folders it names (rtf-data's `description`).
    Plain,
    /// MSRS: `{train,test}/{vi,ir,Label}` (rtf-data's `layouts::msrs`).
    Msrs,
    /// PST900: `{train,test}/{rgb,thermal,labels}` (`layouts::pst900`).
    Pst900,
    /// FMB: `{train,test}/{Visible,Infrared,Label}` (`layouts::fmb`).
    Fmb,
}

impl DatasetFormat {
    /// Whether frames of this layout are read through a dataset description (dataset.yaml or
    /// a built-in layout's).
    pub fn is_described(self) -> bool {
        matches!(self, Self::Plain | Self::Msrs | Self::Pst900 | Self::Fmb)
    }

    /// The layout's name as `rtf data check` prints it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Mf => "MF",
            Self::Freiburg => "Freiburg Thermal",
            Self::Bdd => "BDD100K night",
            Self::Plain => "plain (dataset.yaml)",
            Self::Msrs => "MSRS",
            Self::Pst900 => "PST900",
            Self::Fmb => "FMB",
        }
    }
}

/// The kind of root a training run records (the `format` of [`crate::train::DatasetConfig`]):
/// opening a root as its recorded kind reads it as the run started, without recognising it
/// again.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordedKind {
    Mf,
    Freiburg,
    /// dataset.yaml, MSRS, PST900 or FMB (recognised among these).
    Described,
}

/// Which frames a training run reads ([`crate::train::DatasetConfig`], field by field).
#[derive(Debug, Clone)]
pub struct TrainingChoice {
    pub kind: RecordedKind,
    pub train_split: String,
    /// A split, `holdout:N` (described layouts), or None: no validation.
    pub val_split: Option<String>,
    /// Freiburg Thermal: the preprocessing of the training and of the validation frames.
    pub preprocess: (FreiburgPreprocess, FreiburgPreprocess),
}

/// The reference preprocessing (HeatNet code), each step configurable.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FreiburgPreprocess {
    /// Raw IR counts clipped to [lo, hi] and scaled to [0, 1]. Reference: (21800, 25000).
    pub ir_clip: (u16, u16),
    /// (width, height) both modalities are resized to (RGB/IR bilinear, labels nearest).
    /// Reference: (960, 320).
    pub resize: Option<(usize, usize)>,
    /// Columns kept after resizing, [start, end). Reference: 150..850 for training (then a
    /// random 320×640 window, see `AugmentConfig::window`), 148..852 for testing.
    pub columns: Option<(usize, usize)>,
}

impl FreiburgPreprocess {
    pub fn reference_train() -> Self {
        Self {
            ir_clip: (21800, 25000),
            resize: Some((960, 320)),
            columns: Some((150, 850)),
        }
    }
    pub fn reference_test() -> Self {
        Self {
            columns: Some((148, 852)),
            ..Self::reference_train()
        }
    }
    /// Native size, only the IR clip.
    pub fn native() -> Self {
        Self {
            ir_clip: (21800, 25000),
            resize: None,
            columns: None,
        }
    }
}

impl Default for FreiburgPreprocess {
    fn default() -> Self {
        Self::reference_test()
    }
}

/// Metadata key of the weights' [`TrainedOn`] (JSON).
pub const WEIGHTS_KEY: &str = "rtf.data";

/// The class set and thermal rule a network was trained with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainedOn {
    pub classes: ClassSet,
    /// How thermal became [0, 1]; None where the layout fixes it (MF: byte / 255; Freiburg:
    /// its preprocessing's clip).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thermal: Option<ThermalNormalisation>,
}

impl TrainedOn {
    /// What weights trained on MF record: its 9 classes, thermal as byte / 255.
    pub fn mf() -> Self {
        Self {
            classes: ClassSet::mf(),
            thermal: Some(ThermalNormalisation::Byte),
        }
    }

    /// What weights trained on Freiburg Thermal (or BDD, read with its classes) record: its 13
    /// classes; the thermal rule is the preprocessing's clip.
    pub fn freiburg() -> Self {
        Self {
            classes: ClassSet::freiburg(),
            thermal: None,
        }
    }

    /// The metadata entry for a weights file.
    pub fn metadata_entry(&self) -> (String, String) {
        let json = serde_json::to_string(self).expect("a class set serialises");
        (WEIGHTS_KEY.to_string(), json)
    }
}
