//! `rtf train` as one library call, so that the command and the Python package's `rtf.train`
//! run the same steps: make the run's configuration (a new run from a recipe, config and
//! flags, or a resume of a run folder), say when a resume has nothing to do, settle the bf16
//! kernels ([`crate::kernels`]), and train one stage or every stage of a pipeline, reporting
//! steps and epochs to a [`Progress`] and stopping cleanly on a stop flag (Ctrl-C).
//!
//! The caller keeps what only a process decides: signal handlers, the allocator, joining a
//! data-parallel job, and what to print.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use rtf_core::{refused, Refusal};

use crate::checkpoint::TrainState;
use crate::ddp::Ddp;
use crate::plan::RunPlan;
use crate::progress::Progress;
use crate::resume::Finished;
use crate::setup::{NewRun, SetupError};
use crate::{RunConfig, TrainError};

/// What was asked: a new run into `out`, or the run in `dir` continued (`epochs`: extended or
/// shortened to that many, `--epochs` with `--resume`).
#[derive(Debug, Clone)]
pub enum Request {
    New { run: Box<NewRun>, out: PathBuf },
    Resume { dir: PathBuf, epochs: Option<usize> },
}

/// A run about to train: its configuration (checked), its folder, and whether it continues.
#[derive(Debug, Clone)]
pub struct Plan {
    pub cfg: RunConfig,
    pub run_dir: PathBuf,
    pub resume: bool,
    /// A new run's dataset root as its setup opened it: a single training's run plan takes it
    /// rather than opening the root again ([`RunPlan::resolve_opened`]).
    opened: Option<rtf_data::Dataset>,
}

/// How a call to [`Plan::train`] ended.
#[derive(Debug, Clone)]
pub enum Ended {
    /// Every epoch is done: the run's final weights.
    Trained(PathBuf),
    /// Stopped by the stop flag; the checkpoint of the step it stopped at is written.
    Interrupted {
        /// The stage that was interrupted (multi-stage runs).
        stage: Option<String>,
        state: Box<TrainState>,
    },
}

impl Plan {
    /// The run `request` asks for. A new run's folder is refused inside its dataset.
    pub fn new(request: &Request) -> Result<Self, SetupError> {
        match request {
            Request::Resume { dir, epochs } => {
                let mut cfg = crate::folder::read_config(dir)?;
                if let Some(epochs) = epochs {
                    crate::resume::extend(&mut cfg, dir, *epochs)?;
                }
                cfg.validate()?;
                Ok(Self {
                    cfg,
                    run_dir: dir.clone(),
                    resume: true,
                    opened: None,
                })
            }
            Request::New { run, out } => {
                if let Some(data) = &run.data {
                    check_run_folder(out, data)?;
                }
                let (cfg, opened) = crate::setup::new_run_opened(run)?;
                Ok(Self {
                    cfg,
                    run_dir: out.clone(),
                    resume: false,
                    opened,
                })
            }
        }
    }

    /// `Some` for a resume with nothing left to train (every stage has done its epochs).
    pub fn finished(&self) -> Result<Option<Finished>, TrainError> {
        match self.resume {
            true => crate::resume::finished(&self.cfg, &self.run_dir),
            false => Ok(None),
        }
    }

    /// Trains the run, every stage of a pipeline in order, until done or `stop` is set.
    pub fn train(
        &self,
        progress: &mut dyn Progress,
        stop: &AtomicBool,
        ddp: Option<Arc<Ddp>>,
    ) -> Result<Ended, TrainError> {
        match &self.cfg {
            RunConfig::Single(single) => {
                let plan = RunPlan::resolve_opened(single, self.opened.clone())?;
                let outcome = crate::trainer::train_planned(
                    plan,
                    &self.run_dir,
                    self.resume,
                    progress,
                    stop,
                    ddp,
                )?;
                Ok(match outcome.final_weights {
                    Some(path) => Ended::Trained(path),
                    None => Ended::Interrupted {
                        stage: None,
                        state: Box::new(outcome.state),
                    },
                })
            }
            RunConfig::Pipeline(pipeline) => {
                let outcome = crate::pipeline::run_pipeline_observed(
                    pipeline,
                    &self.run_dir,
                    self.resume,
                    progress,
                    stop,
                    ddp,
                )?;
                match (outcome.final_weights, outcome.interrupted) {
                    (Some(path), _) => Ok(Ended::Trained(path)),
                    (None, Some((stage, o))) => Ok(Ended::Interrupted {
                        stage: Some(stage),
                        state: Box::new(o.state),
                    }),
                    (None, None) => Err(TrainError::Config(
                        "the run stopped without final weights".into(),
                    )),
                }
            }
        }
    }
}

/// Refuses a training run folder that is, or is inside, the dataset root it trains on.
pub fn check_run_folder(out: &Path, data: &Path) -> Result<(), Refusal> {
    // A dataset.yaml given as --data: its folder is the root.
    let data = match data.is_file() {
        true => data.parent().unwrap_or(Path::new(".")),
        false => data,
    };
    let (run, root) = (rtf_core::resolved(out), rtf_core::resolved(data));
    if data.is_dir() && run.starts_with(&root) {
        return Err(refused(format!(
            "--out {}: a run folder inside the dataset {} it trains on would mix the run's files \
             with the data; choose a folder outside it (nothing was written)",
            out.display(),
            data.display()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_folder_is_never_the_dataset_or_inside_it() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("data");
        std::fs::create_dir_all(&root).unwrap();
        assert!(check_run_folder(&root, &root).is_err());
        assert!(check_run_folder(&root.join("runs/a"), &root).is_err());
        check_run_folder(&dir.path().join("runs/a"), &root).unwrap();
    }
}
