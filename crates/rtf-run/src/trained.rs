//! A run folder with its configuration checked ([`TrainedRun`]): what `--resume`,
//! `--teacher RUN` and `rtf export` read. Its configuration is rtf-config's [`RunConfig`]
//! (one training, or the stages of a multi-stage run; a flat `config.json` of the builds
//! before the sections reads too), checked as a new run's is. The class set it records or its
//! dataset holds is rtf-train's `folder::class_set` (it opens the dataset).

use std::path::Path;

use rtf_config::train::TrainConfig;
use rtf_config::RunConfig;

use crate::error::RunError;
use crate::folder::RunFolder;

/// A run folder with its configuration, checked.
#[derive(Debug, Clone)]
pub struct TrainedRun {
    folder: RunFolder,
    config: RunConfig,
}

/// Reads the configuration of an existing run (for `--resume`), checked.
pub fn read_config(dir: &Path) -> Result<RunConfig, RunError> {
    Ok(TrainedRun::open(dir)?.into_config())
}

impl TrainedRun {
    /// Opens the run folder `dir` and reads its configuration, checked as a new run's is.
    pub fn open(dir: &Path) -> Result<Self, RunError> {
        let folder = RunFolder::open(dir)?;
        let config = folder.config()?;
        config.validate().map_err(|e| RunError::Config {
            path: folder.config_path(),
            message: format!("invalid value: {e}"),
        })?;
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
}
