//! Where a run folder stands when `rtf train --resume` is asked to continue it: finished (and
//! nothing to do), or with epochs left: interrupted, or finished and extended by `--epochs`.
//! A single run is extended in place; a multi-stage run is extended in the stage the resume
//! continues (the first unfinished one) and the stages after it, or, once every stage is done,
//! in its last stage: earlier stages are teachers or starting weights of later ones, so
//! changing one would silently leave the later stages trained from other weights.
//! The exactness of a continuation (the same weights as an uninterrupted run) is the
//! trainer's ([`crate::trainer::train_distributed`]).

use std::path::{Path, PathBuf};

use crate::checkpoint::{self, TrainState};
use crate::config::RunConfig;
use crate::error::TrainError;
use crate::run::{CHECKPOINT_FILE, FINAL_FILE};

/// A run (or stage) folder's progress: its checkpoint's state, None before the first checkpoint.
pub fn saved_state(dir: &Path) -> Result<Option<TrainState>, TrainError> {
    let path = dir.join(CHECKPOINT_FILE);
    match path.is_file() {
        true => Ok(Some(checkpoint::read_state(&path)?)),
        false => Ok(None),
    }
}

/// Whether the run in `dir` has trained all of its `epochs`: its final weights exist and its
/// checkpoint is at an epoch's end at or beyond `epochs`. Final weights without a checkpoint
/// (deleted by hand) count as finished: there is nothing to continue from.
pub fn is_finished(dir: &Path, epochs: usize) -> Result<bool, TrainError> {
    if !dir.join(FINAL_FILE).is_file() {
        return Ok(false);
    }
    Ok(saved_state(dir)?.is_none_or(|s| s.partial.is_none() && s.epochs_done >= epochs))
}

/// A finished run: what `--resume` reports instead of training.
#[derive(Debug, Clone, PartialEq)]
pub struct Finished {
    /// The stage that finished last (multi-stage runs).
    pub stage: Option<String>,
    pub epochs_done: usize,
    pub epochs: usize,
    /// The run's final weights.
    pub weights: PathBuf,
}

impl std::fmt::Display for Finished {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "nothing to do: finished at epoch {} of {}",
            self.epochs_done, self.epochs
        )?;
        match &self.stage {
            Some(stage) => write!(f, " (last stage {stage})"),
            None => Ok(()),
        }
    }
}

/// `Some` when resuming `run` in `run_dir` would train nothing: every stage has done exactly
/// its epochs. A run asked for fewer epochs than it has done is not finished (the trainer
/// refuses it with its own error).
pub fn finished(run: &RunConfig, run_dir: &Path) -> Result<Option<Finished>, TrainError> {
    let stages = run.stages();
    let mut last = None;
    for (name, cfg) in &stages {
        let dir = run_dir.join(name);
        if !is_finished(&dir, cfg.schedule.epochs)? {
            return Ok(None);
        }
        last = Some((name, saved_state(&dir)?, cfg.schedule.epochs));
    }
    let Some((name, state, epochs)) = last else {
        return Ok(None);
    };
    let epochs_done = state.map_or(epochs, |s| s.epochs_done);
    Ok((epochs_done == epochs).then(|| Finished {
        stage: (!name.is_empty()).then(|| name.to_string()),
        epochs_done,
        epochs,
        weights: run_dir.join(FINAL_FILE),
    }))
}

/// Sets the epochs of the part of `run` a resume continues to `epochs` (`--epochs`): a single
/// run; in a multi-stage run the first unfinished stage and those after it, or the last stage
/// when every stage is done. Refuses to end a stage before the epochs it has done.
pub fn extend(run: &mut RunConfig, run_dir: &Path, epochs: usize) -> Result<(), TrainError> {
    let pipeline = match run {
        RunConfig::Single(single) => {
            single.schedule.epochs = epochs;
            return Ok(());
        }
        RunConfig::Pipeline(pipeline) => pipeline,
    };
    let mut first = pipeline.stages.len().saturating_sub(1);
    for (i, stage) in pipeline.stages.iter().enumerate() {
        if !is_finished(&run_dir.join(&stage.name), stage.config.schedule.epochs)? {
            first = i;
            break;
        }
    }
    for stage in &mut pipeline.stages[first..] {
        let done = saved_state(&run_dir.join(&stage.name))?.map_or(0, |s| s.epochs_done);
        if epochs < done {
            return Err(TrainError::Config(format!(
                "{}: stage {} has done {done} epochs; --epochs {epochs} would end it before \
                 where it stands",
                run_dir.display(),
                stage.name
            )));
        }
        stage.config.schedule.epochs = epochs;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{PipelineConfig, StageConfig, TrainConfig};

    /// A multi-stage run interrupted in its second stage: `--epochs` sets that stage's epochs
    /// and those of the stages after it; the finished first stage keeps its own.
    #[test]
    fn extending_an_interrupted_pipeline_sets_the_interrupted_stage_and_those_after() {
        let dir = tempfile::tempdir().unwrap();
        let stage = |name: &str, epochs| StageConfig {
            name: name.into(),
            config: TrainConfig::mfnet_paper("data".into()).with(|c| c.schedule.epochs = epochs),
        };
        let mut run = RunConfig::Pipeline(PipelineConfig {
            recipe: None,
            stages: vec![stage("a", 2), stage("b", 2), stage("c", 2)],
        });
        // Stage a finished (final weights, no checkpoint left); b was interrupted before its
        // first checkpoint; c has not started.
        std::fs::create_dir_all(dir.path().join("a")).unwrap();
        std::fs::write(dir.path().join("a").join(FINAL_FILE), b"").unwrap();
        extend(&mut run, dir.path(), 5).unwrap();
        let epochs: Vec<usize> = run
            .stages()
            .iter()
            .map(|(_, c)| c.schedule.epochs)
            .collect();
        assert_eq!(epochs, [2, 5, 5]);
        assert_eq!(finished(&run, dir.path()).unwrap(), None);
    }
}
