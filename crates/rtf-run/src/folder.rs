//! [`RunFolder`]: a run folder opened once. Its configuration document is read when it opens
//! (and the stages a multi-stage run lists in it); its log and weights when asked for.

use std::path::{Path, PathBuf};

use rtf_config::train::{PipelineConfig, TrainConfig};
use rtf_config::RunConfig;
use serde::Deserialize;
use serde_json::Value;

use crate::error::RunError;
use crate::files::{BEST_FILE, CONFIG_FILE, FINAL_FILE, LOG_FILE};
use crate::record::EpochRecord;

/// A run folder, or a stage's folder of a multi-stage run.
#[derive(Debug, Clone)]
pub struct RunFolder {
    dir: PathBuf,
    /// `config.json` as recorded; None when the folder has none (yet).
    document: Option<Value>,
    /// The stages a multi-stage run's `config.json` lists, in order (empty: one training).
    stages: Vec<String>,
}

/// The part of a configuration that says whether it is a multi-stage run, and its stages.
#[derive(Deserialize)]
struct Layout {
    #[serde(default)]
    stages: Option<Vec<StageName>>,
}

#[derive(Deserialize)]
struct StageName {
    name: String,
}

/// The student's weights a run folder holds.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Weights {
    /// `best.safetensors`: the best validation score's.
    pub best: Option<PathBuf>,
    /// `final.safetensors`: the last epoch's (a multi-stage run: its last stage's).
    pub last: Option<PathBuf>,
}

impl Weights {
    /// The weights files in `dir` (a folder that may not exist: none).
    pub fn of(dir: &Path) -> Self {
        let file = |name: &str| Some(dir.join(name)).filter(|p| p.is_file());
        Weights {
            best: file(BEST_FILE),
            last: file(FINAL_FILE),
        }
    }

    /// The weights picked on validation where the run validated, else the final ones.
    pub fn selected(&self) -> Option<&Path> {
        self.best.as_deref().or(self.last.as_deref())
    }
}

fn read_document(path: &Path) -> Result<Option<Value>, RunError> {
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => {
            return Err(RunError::Io {
                path: path.to_path_buf(),
                source,
            })
        }
    };
    serde_json::from_str(&text)
        .map(Some)
        .map_err(|e| RunError::Config {
            path: path.to_path_buf(),
            message: format!("not valid JSON: {e}"),
        })
}

impl RunFolder {
    /// Opens the run folder `dir`: reads its `config.json` (if any; not JSON is an error) and
    /// the stages it lists.
    pub fn open(dir: &Path) -> Result<Self, RunError> {
        if !dir.is_dir() {
            return Err(RunError::Folder {
                path: dir.to_path_buf(),
                message: "not a run folder (no such directory)".into(),
            });
        }
        let path = dir.join(CONFIG_FILE);
        let document = read_document(&path)?;
        let stages = match &document {
            None => Vec::new(),
            Some(doc) => Layout::deserialize(doc)
                .map_err(|e| RunError::Config {
                    path: path.clone(),
                    message: format!("`stages` is not a list of named stages: {e}"),
                })?
                .stages
                .unwrap_or_default()
                .into_iter()
                .map(|s| s.name)
                .collect(),
        };
        Ok(RunFolder {
            dir: dir.to_path_buf(),
            document,
            stages,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn config_path(&self) -> PathBuf {
        self.dir.join(CONFIG_FILE)
    }

    pub fn log_path(&self) -> PathBuf {
        self.dir.join(LOG_FILE)
    }

    /// Whether the folder has a `config.json`.
    pub fn has_config(&self) -> bool {
        self.document.is_some()
    }

    /// Whether the folder has a `log.jsonl` (none before the first epoch has ended).
    pub fn has_log(&self) -> bool {
        self.log_path().is_file()
    }

    /// The stages of a multi-stage run, by name (their folders are `dir/<name>/`); empty for
    /// one training.
    pub fn stage_names(&self) -> &[String] {
        &self.stages
    }

    /// The folder of stage `name`.
    pub fn stage(&self, name: &str) -> Result<RunFolder, RunError> {
        RunFolder::open(&self.dir.join(name))
    }

    /// `config.json` as recorded (a JSON document); None when the folder has none (yet).
    pub fn document(&self) -> Option<&Value> {
        self.document.as_ref()
    }

    /// The configuration as recorded, typed (rtf-config's schema; not checked: see
    /// [`crate::TrainedRun`]): a multi-stage run's stages, else one training (sectioned, or
    /// the flat layout of older builds). Errors name `config.json`.
    pub fn config(&self) -> Result<RunConfig, RunError> {
        Ok(match self.stages.is_empty() {
            true => RunConfig::Single(Box::new(self.parse::<TrainConfig>()?)),
            false => RunConfig::Pipeline(self.parse::<PipelineConfig>()?),
        })
    }

    /// One training's configuration as recorded (a stage's folder, or a run of one stage);
    /// a multi-stage run's own folder is an error naming its `config.json`.
    pub fn training(&self) -> Result<TrainConfig, RunError> {
        match self.config()? {
            RunConfig::Single(config) => Ok(*config),
            RunConfig::Pipeline(_) => Err(RunError::Config {
                path: self.config_path(),
                message: "a multi-stage run: its stages' folders hold their trainings".into(),
            }),
        }
    }

    fn parse<T: serde::de::DeserializeOwned>(&self) -> Result<T, RunError> {
        let path = self.config_path();
        let document = self.document.as_ref().ok_or_else(|| RunError::Config {
            path: path.clone(),
            message: "missing (written by `rtf train`)".into(),
        })?;
        T::deserialize(document).map_err(|e| RunError::Config {
            path,
            message: format!("not a training configuration rtf reads: {e}"),
        })
    }

    /// Every setting `config.json` records, as (`a.b.c`, JSON text) rows in key order (what
    /// the file says, in its own layout; `null`s left out, lists of more than 8 items
    /// summarised); none without a `config.json`.
    pub fn settings(&self) -> Vec<(String, String)> {
        let mut rows = Vec::new();
        if let Some(document) = &self.document {
            crate::settings::flatten("", document, &mut rows);
        }
        rows
    }

    /// The epochs of `log.jsonl`, in order. A folder without a log is not (yet) a run with
    /// epochs: an error naming the folder and the log.
    pub fn epochs(&self) -> Result<Vec<EpochRecord>, RunError> {
        let path = self.log_path();
        if !path.exists() {
            return Err(RunError::Folder {
                path: self.dir.clone(),
                message: format!(
                    "not a run folder: {} is missing (written by `rtf train`)",
                    path.display()
                ),
            });
        }
        crate::log::read(&path)
    }

    /// The last epoch of `log.jsonl`; None without a log or before the first epoch.
    pub fn last_epoch(&self) -> Result<Option<EpochRecord>, RunError> {
        match self.has_log() {
            true => Ok(self.epochs()?.pop()),
            false => Ok(None),
        }
    }

    /// The student's weights the folder holds.
    pub fn weights(&self) -> Weights {
        Weights::of(&self.dir)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(epoch: usize) -> String {
        format!(
            r#"{{"epoch":{epoch},"lr":0.01,"train_loss":1.0,"images":2,"seconds":1.0,"images_per_s":2.0,"data_wait_fraction":0.0,"val_miou":null,"val_macc":null}}"#
        )
    }

    /// A multi-stage run: its config lists the stages, each stage is a run folder of its own
    /// with its log and weights; the run's final weights are the last stage's.
    #[test]
    fn a_multi_stage_folder_lists_its_stages_and_each_reads_as_a_run() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let config = r#"{"recipe": "r", "stages": [{"name": "teacher", "config": {}},
            {"name": "student", "config": {}}]}"#;
        std::fs::write(dir.join(CONFIG_FILE), config).unwrap();
        std::fs::write(dir.join(FINAL_FILE), b"w").unwrap();
        for (stage, epochs) in [("teacher", 2), ("student", 1)] {
            std::fs::create_dir_all(dir.join(stage)).unwrap();
            let log: String = (0..epochs).map(|e| line(e) + "\n").collect();
            std::fs::write(dir.join(stage).join(LOG_FILE), log).unwrap();
        }
        std::fs::write(dir.join("teacher").join(BEST_FILE), b"w").unwrap();
        let run = RunFolder::open(dir).unwrap();
        assert_eq!(run.stage_names(), ["teacher", "student"]);
        assert!(run.has_config() && !run.has_log());
        assert_eq!(run.last_epoch().unwrap(), None);
        let teacher = run.stage("teacher").unwrap();
        assert_eq!(teacher.epochs().unwrap().len(), 2);
        assert!(!teacher.has_config() && teacher.stage_names().is_empty());
        assert_eq!(
            teacher.weights().selected(),
            Some(&*dir.join("teacher/best.safetensors"))
        );
        let student = run.stage("student").unwrap();
        assert_eq!(student.last_epoch().unwrap().map(|r| r.epoch), Some(0));
        assert_eq!(student.weights(), Weights::default());
        assert_eq!(run.weights().selected(), Some(&*dir.join(FINAL_FILE)));
    }

    #[test]
    fn missing_and_unreadable_files_are_errors_naming_them() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let err = RunFolder::open(&dir.join("nowhere"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("nowhere") && err.contains("no such directory"),
            "{err}"
        );
        let empty = RunFolder::open(dir).unwrap();
        let err = empty.epochs().unwrap_err().to_string();
        assert!(err.contains("log.jsonl is missing"), "{err}");
        let err = empty.config().unwrap_err().to_string();
        assert!(err.contains("config.json: missing"), "{err}");
        assert!(empty.settings().is_empty());
        std::fs::write(dir.join(CONFIG_FILE), b"{\"model\": [").unwrap();
        let err = RunFolder::open(dir).unwrap_err().to_string();
        assert!(err.contains("config.json: not valid JSON"), "{err}");
        std::fs::write(dir.join(CONFIG_FILE), br#"{"stages": [1, 2]}"#).unwrap();
        let err = RunFolder::open(dir).unwrap_err().to_string();
        assert!(err.contains("config.json: `stages`"), "{err}");
    }

    /// The configuration reads typed, and its settings are what the file says; a renamed
    /// field is an error naming the file and the field.
    #[test]
    fn the_configuration_reads_typed_and_as_recorded_settings() {
        let tmp = tempfile::tempdir().unwrap();
        let config = TrainConfig::mfnet_paper("/data/mf".into());
        let text = serde_json::to_string(&config).unwrap();
        std::fs::write(tmp.path().join(CONFIG_FILE), &text).unwrap();
        let run = RunFolder::open(tmp.path()).unwrap();
        assert_eq!(run.training().unwrap(), config);
        assert!(run
            .settings()
            .contains(&("schedule.epochs".into(), "80".into())));
        let renamed = text.replace("\"epochs\"", "\"epoch\"");
        std::fs::write(tmp.path().join(CONFIG_FILE), renamed).unwrap();
        let renamed = RunFolder::open(tmp.path()).unwrap();
        let err = renamed.config().unwrap_err().to_string();
        assert!(
            err.contains("config.json") && err.contains("`epoch`"),
            "{err}"
        );
    }

    /// A multi-stage run's own folder holds no training of its own.
    #[test]
    fn a_multi_stage_configuration_reads_as_its_stages() {
        let tmp = tempfile::tempdir().unwrap();
        let stage = TrainConfig::mfnet_paper("/data/mf".into());
        let pipeline = RunConfig::Pipeline(PipelineConfig {
            recipe: None,
            stages: vec![rtf_config::train::StageConfig {
                name: "only".into(),
                config: stage,
            }],
        });
        let text = serde_json::to_string(&pipeline).unwrap();
        std::fs::write(tmp.path().join(CONFIG_FILE), text).unwrap();
        let run = RunFolder::open(tmp.path()).unwrap();
        assert_eq!(run.config().unwrap(), pipeline);
        let err = run.training().unwrap_err().to_string();
        assert!(err.contains("multi-stage"), "{err}");
    }
}
