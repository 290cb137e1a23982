//! The runs a report shows, read through the one run-folder type (rtf-run's `RunFolder`, its
//! configuration typed by rtf-config's schema): a run folder, or each stage of a multi-stage
//! run (`RUN/<stage>/`), with its epochs, what the page uses of its configuration and the
//! settings it records.

use std::path::{Path, PathBuf};

use rtf_config::train::DatasetConfig;
use rtf_models::{Modality, ModelConfig};
use rtf_run::{EpochRecord, RunFolder, Weights, LOG_FILE};

use crate::error::ReportError;

/// What the page uses of a run's configuration: the network (built for the prediction grid),
/// its inputs, the frame size it trained at, and its dataset with the validation split.
pub(crate) struct Training {
    pub model: ModelConfig,
    pub inputs: Modality,
    pub resize: Option<(usize, usize)>,
    pub dataset_root: PathBuf,
    /// None: Freiburg Thermal's validation (its test layout), or no validation.
    pub val_split: Option<String>,
}

/// A run folder or one stage of it.
pub(crate) struct Run {
    pub label: String,
    pub folder: RunFolder,
    /// What the page uses of its configuration; None without a `config.json`, or one this
    /// build does not read (a note says why; its recorded settings are still shown).
    pub config: Option<Training>,
    /// The settings its `config.json` records, as (`a.b.c`, value) rows.
    pub settings: Vec<(String, String)>,
    pub log: Vec<EpochRecord>,
}

impl Run {
    pub fn dir(&self) -> &Path {
        self.folder.dir()
    }

    pub fn weights(&self) -> Weights {
        self.folder.weights()
    }

    /// The network's family as the configuration names it (`mfnet`, `rtfnet`, …); `?` when
    /// the configuration cannot be read.
    pub fn network(&self) -> &'static str {
        self.config
            .as_ref()
            .map_or("?", |c| network_family(&c.model))
    }
}

fn network_family(model: &ModelConfig) -> &'static str {
    match model {
        ModelConfig::Mfnet(_) => "mfnet",
        ModelConfig::Rtfnet(_) => "rtfnet",
        ModelConfig::Heatnet(_) => "heatnet",
        ModelConfig::Baseline(_) => "baseline",
        ModelConfig::Cmx(_) => "cmx",
    }
}

/// What the page uses of the training configuration of `folder` (none for a multi-stage
/// run's own folder), or None with a note saying why.
fn training(folder: &RunFolder, notes: &mut Vec<String>) -> Option<Training> {
    if !folder.has_config() || !folder.stage_names().is_empty() {
        return None;
    }
    match typed(folder) {
        Ok(training) => Some(training),
        Err(e) => {
            notes.push(format!("report: {e}; its settings are shown as recorded"));
            None
        }
    }
}

/// What the page uses of the training configuration of `folder`.
fn typed(folder: &RunFolder) -> Result<Training, String> {
    let config = folder.training().map_err(|e| e.to_string())?;
    let dataset = &config.data.dataset;
    let val_split = match dataset {
        DatasetConfig::Freiburg { .. } => None,
        DatasetConfig::Mf { val_split, .. } | DatasetConfig::Described { val_split, .. } => {
            val_split.clone()
        }
    };
    Ok(Training {
        model: config.network.model,
        inputs: config.network.inputs,
        resize: config.data.resize,
        dataset_root: dataset.root().to_path_buf(),
        val_split,
    })
}

fn part(label: String, folder: RunFolder, log: Vec<EpochRecord>, notes: &mut Vec<String>) -> Run {
    Run {
        label,
        config: training(&folder, notes),
        settings: folder.settings(),
        log,
        folder,
    }
}

/// The run at `dir` and, for a multi-stage run, each stage its `config.json` lists.
pub(crate) fn load_runs(dir: &Path, notes: &mut Vec<String>) -> Result<Vec<Run>, ReportError> {
    let folder = RunFolder::open(dir)?;
    let label = dir.file_name().map_or_else(
        || dir.display().to_string(),
        |n| n.to_string_lossy().to_string(),
    );
    let mut runs = Vec::new();
    if folder.has_log() || folder.stage_names().is_empty() {
        // A folder without log.jsonl is no run (yet): the error names the log.
        let log = folder.epochs()?;
        if !folder.has_config() {
            return Err(ReportError::input(
                folder.config_path(),
                "missing (written by `rtf train`)",
            ));
        }
        runs.push(part(label.clone(), folder.clone(), log, notes));
    }
    for stage in folder.stage_names() {
        let log = dir.join(stage).join(LOG_FILE);
        if !log.exists() {
            return Err(ReportError::input(
                log,
                format!(
                    "stage `{stage}` listed in {} has no log",
                    folder.config_path().display()
                ),
            ));
        }
        let stage_folder = folder.stage(stage)?;
        let log = stage_folder.epochs()?;
        runs.push(part(format!("{label} / {stage}"), stage_folder, log, notes));
    }
    Ok(runs)
}

/// The files of `runs` the report reads.
pub(crate) fn inputs(runs: &[Run]) -> impl Iterator<Item = PathBuf> + '_ {
    runs.iter()
        .flat_map(|r| [r.folder.config_path(), r.folder.log_path()])
}
