//! A run folder read back typed: rtf-run's [`RunFolder`] (its files, stages, epochs and
//! weights) with its configuration as this crate's [`RunConfig`]: one training, or the stages
//! of a multi-stage run. A flat `config.json` of the builds before the sections reads too
//! ([`crate::config`]'s legacy layout). `--resume`, `--teacher RUN`, `rtf export` and
//! `rtf report` read run folders through here.

use std::path::Path;

use rtf_core::ClassSet;

use crate::config::{RunConfig, TrainConfig};
use crate::error::TrainError;
use crate::run::run_error;

pub use rtf_run::{EpochRecord, RunFolder, Weights};

/// A run folder with its configuration, checked.
#[derive(Debug, Clone)]
pub struct TrainedRun {
    folder: RunFolder,
    config: RunConfig,
}

/// The configuration of a run folder as recorded (not checked): a multi-stage run's stages,
/// else one training (sectioned, or the flat layout of older builds).
pub fn run_config(folder: &RunFolder) -> Result<RunConfig, TrainError> {
    Ok(match folder.stage_names().is_empty() {
        true => RunConfig::Single(Box::new(folder.config()?)),
        false => RunConfig::Pipeline(folder.config()?),
    })
}

/// Reads the configuration of an existing run (for `--resume`), checked.
pub fn read_config(dir: &Path) -> Result<RunConfig, TrainError> {
    Ok(TrainedRun::open(dir)?.into_config())
}

impl TrainedRun {
    /// Opens the run folder `dir` and reads its configuration, checked as a new run's is.
    pub fn open(dir: &Path) -> Result<Self, TrainError> {
        let folder = RunFolder::open(dir)?;
        let config = run_config(&folder)?;
        config
            .validate()
            .map_err(|e| run_error(&folder.config_path(), format!("invalid value: {e}")))?;
        Ok(TrainedRun { folder, config })
    }

    pub fn folder(&self) -> &RunFolder {
        &self.folder
    }

    pub fn config(&self) -> &RunConfig {
        &self.config
    }

    pub fn into_config(self) -> RunConfig {
        self.config
    }

    /// The training the run ends with (a multi-stage run's last stage).
    pub fn last_training(&self) -> &TrainConfig {
        self.config.stages().last().expect("checked: a stage").1
    }

    /// The class set the run's final network was trained on: the one its configuration
    /// records (a described dataset's, since it was recorded), else its dataset's as it reads
    /// now; None when neither can be read.
    pub fn class_set(&self) -> Option<ClassSet> {
        let dataset = &self.last_training().data.dataset;
        if let Some(recorded) = dataset.recorded() {
            return Some(recorded.classes.clone());
        }
        rtf_data::Dataset::open_recorded(dataset.root(), dataset.choice().kind)
            .ok()
            .map(|d| d.class_set())
    }
}

/// What weights were trained on, for an export's metadata: the weights' `record` (class set
/// and thermal rule), else the class set of the run folder they sit in, else MF's or
/// Freiburg's names when `classes` is their count (said as an assumption).
pub fn export_labels(
    record: Option<rtf_data::TrainedOn>,
    weights: &Path,
    classes: i64,
) -> rtf_models::io::export::Labels {
    let thermal = record
        .as_ref()
        .and_then(|t| t.thermal.as_ref())
        .map(|t| t.describe());
    let (classes, from) = match record {
        Some(t) => (Some(t.classes), "the weights' record".to_string()),
        None => match class_set_of_run(weights, classes) {
            Some((set, from)) => (Some(set), from),
            None => (None, "unknown".to_string()),
        },
    };
    rtf_models::io::export::Labels {
        classes,
        from,
        thermal,
    }
}

/// The class set of weights without a record, and where it comes from: the dataset of the run
/// folder the weights sit in (the classes its config.json records, else its dataset's: a
/// dataset.yaml's own names), else MF's or Freiburg's names when the class count is theirs
/// (said as an assumption), else none.
fn class_set_of_run(weights: &Path, classes: i64) -> Option<(ClassSet, String)> {
    let dir = weights.parent()?;
    // `--weights final.safetensors` inside the run folder: the folder is the current one.
    let folder = match dir.as_os_str().is_empty() {
        true => Path::new("."),
        false => dir,
    };
    let run_classes = TrainedRun::open(folder)
        .ok()
        .and_then(|run| run.class_set());
    if let Some(set) = run_classes.filter(|set| set.len() as i64 == classes) {
        let config_path = dir.join(rtf_run::CONFIG_FILE);
        return Some((
            set,
            format!("the run's dataset ({})", config_path.display()),
        ));
    }
    [ClassSet::mf(), ClassSet::freiburg()]
        .into_iter()
        .find(|set| set.len() as i64 == classes)
        .map(|set| {
            let from = format!(
                "assumed from the class count: {}'s {classes} classes",
                set.name
            );
            (set, from)
        })
}
