//! Runs of several stages (HeatNet's teachers, two-stage training, distillation): each stage is
//! an ordinary run folder `RUN/<stage>/` trained by [`crate::trainer`]; a later stage's
//! references to earlier ones are resolved to their weights when it starts; a resumed run skips
//! the stages that finished and resumes the one that was interrupted. When the last stage is
//! done its `best`/`final` weights are copied to `RUN/`.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use rtf_run::write::{refuse_existing_run, OwnedFolder};

use crate::config::{PipelineConfig, RunConfig, StageConfig, TeacherRef, TrainConfig, WeightsRef};
use crate::ddp::Ddp;
use crate::error::TrainError;
use crate::progress::{Epochs, InStage, Progress};
use crate::run::{self as rundir, run_error, BEST_FILE, CONFIG_FILE, FINAL_FILE};
use crate::trainer::{self, EpochRecord, TrainOutcome};

#[derive(Debug, Clone)]
pub struct PipelineOutcome {
    pub run_dir: PathBuf,
    /// `RUN/final.safetensors` once every stage is done; None when interrupted.
    pub final_weights: Option<PathBuf>,
    /// The stage that was interrupted, with its outcome.
    pub interrupted: Option<(String, TrainOutcome)>,
    /// Stages trained by this call (finished earlier ones are skipped).
    pub trained: Vec<String>,
}

/// The weights of a finished stage a teacher uses: best on validation, else final.
pub fn stage_weights(stage_dir: &Path) -> PathBuf {
    let best = stage_dir.join(BEST_FILE);
    match best.is_file() {
        true => best,
        false => stage_dir.join(FINAL_FILE),
    }
}

/// `cfg` with its stage references replaced by the files of the stages under `run_dir`.
pub fn resolve(
    cfg: &TrainConfig,
    run_dir: &Path,
    stages: &[StageConfig],
) -> Result<TrainConfig, TrainError> {
    let mut cfg = cfg.clone();
    let find = |name: &str| {
        stages
            .iter()
            .find(|s| s.name == name)
            .ok_or_else(|| TrainError::Config(format!("no stage named `{name}`")))
    };
    for teacher in cfg.learning.procedure.teachers_mut() {
        if let TeacherRef::Stage(name) = teacher {
            let stage = find(name)?;
            *teacher = TeacherRef::Weights {
                path: stage_weights(&run_dir.join(&stage.name)),
                model: stage.config.network.model.clone(),
                inputs: stage.config.network.inputs,
            };
        }
    }
    if let Some(WeightsRef::Stage(name)) = &cfg.network.init_from {
        let stage = find(name)?;
        cfg.network.init_from = Some(WeightsRef::File(run_dir.join(&stage.name).join(FINAL_FILE)));
    }
    Ok(cfg)
}

/// Trains every stage of `cfg` in order into `run_dir`.
pub fn run_pipeline(
    cfg: &PipelineConfig,
    run_dir: &Path,
    resume: bool,
    on_epoch: &mut dyn FnMut(&str, &EpochRecord),
    stop: &AtomicBool,
) -> Result<PipelineOutcome, TrainError> {
    run_pipeline_distributed(cfg, run_dir, resume, on_epoch, stop, None)
}

/// [`run_pipeline`] as one rank of a data-parallel job: every stage is trained data-parallel
/// ([`trainer::train_distributed`]); rank 0 alone writes the run folder, and the other ranks
/// read it (which stages are done, the earlier stages' weights a later one starts from or
/// learns from), so on several machines it must be on a shared filesystem. Barriers around
/// each stage keep those reads and rank 0's writes apart.
pub fn run_pipeline_distributed(
    cfg: &PipelineConfig,
    run_dir: &Path,
    resume: bool,
    on_epoch: &mut dyn FnMut(&str, &EpochRecord),
    stop: &AtomicBool,
    ddp: Option<Arc<Ddp>>,
) -> Result<PipelineOutcome, TrainError> {
    let mut epochs = Epochs(|stage: &str, r: &EpochRecord| on_epoch(stage, r));
    run_pipeline_observed(cfg, run_dir, resume, &mut epochs, stop, ddp)
}

/// [`run_pipeline_distributed`] reporting every step and epoch of every stage to `progress`.
pub fn run_pipeline_observed(
    cfg: &PipelineConfig,
    run_dir: &Path,
    resume: bool,
    progress: &mut dyn Progress,
    stop: &AtomicBool,
    ddp: Option<Arc<Ddp>>,
) -> Result<PipelineOutcome, TrainError> {
    let lock = open_run_folder(cfg, run_dir, resume, ddp.as_deref())?;
    let mut trained = Vec::new();
    for stage in &cfg.stages {
        let Some(outcome) = train_stage(cfg, stage, run_dir, progress, stop, ddp.clone())? else {
            continue;
        };
        trained.push(stage.name.clone());
        if outcome.final_weights.is_none() {
            return Ok(PipelineOutcome {
                run_dir: run_dir.to_path_buf(),
                final_weights: None,
                interrupted: Some((stage.name.clone(), outcome)),
                trained,
            });
        }
    }
    if ddp.as_ref().is_none_or(|d| d.is_root()) {
        copy_last_stage_weights(cfg, run_dir)?;
    }
    drop(lock);
    Ok(PipelineOutcome {
        run_dir: run_dir.to_path_buf(),
        final_weights: Some(run_dir.join(FINAL_FILE)),
        interrupted: None,
        trained,
    })
}

fn barrier(ddp: Option<&Ddp>) -> Result<(), TrainError> {
    match ddp {
        Some(d) => Ok(d.barrier()?),
        None => Ok(()),
    }
}

/// Checks the pipeline and the folder; rank 0 owns the folder (its lock) and writes the
/// pipeline's `config.json`.
fn open_run_folder(
    cfg: &PipelineConfig,
    run_dir: &Path,
    resume: bool,
    ddp: Option<&Ddp>,
) -> Result<Option<OwnedFolder>, TrainError> {
    let run = RunConfig::Pipeline(cfg.clone());
    run.validate()?;
    if !resume {
        refuse_existing_run(run_dir)?;
    }
    // Teachers given as files are checked before any stage trains, so a bad one is refused
    // now, not after the stages before it; each stage's run plan checks its teachers again
    // when it opens (a header read each), since a file may change while earlier stages train.
    for stage in &cfg.stages {
        let learning = &stage.config.learning;
        crate::procedure::check_teachers(&learning.procedure, &stage.config.network.model)?;
    }
    if resume {
        check_stage_folders(cfg, run_dir)?;
    }
    // Every rank has looked at the folder before rank 0 writes to it.
    barrier(ddp)?;
    if !ddp.is_none_or(|d| d.is_root()) {
        return Ok(None);
    }
    let owned = OwnedFolder::open(run_dir)?;
    owned.write_config(&run)?;
    Ok(Some(owned))
}

/// A resumed run whose stage has no folder while a later stage has started is refused:
/// training the earlier stage again would leave the later one half learnt from weights that
/// are gone (a mixed run).
fn check_stage_folders(cfg: &PipelineConfig, run_dir: &Path) -> Result<(), TrainError> {
    let started: Vec<bool> = cfg
        .stages
        .iter()
        .map(|s| rundir::holds_run(&run_dir.join(&s.name)))
        .collect();
    let Some(missing) = started.iter().position(|s| !s) else {
        return Ok(());
    };
    match started[missing..].iter().position(|s| *s) {
        None => Ok(()),
        Some(later) => Err(run_error(
            &run_dir.join(&cfg.stages[missing].name),
            format!(
                "stage {} holds no run, but stage {} after it has started: restore the \
                 stage's folder, or remove the folders from stage {} on to train them again",
                cfg.stages[missing].name,
                cfg.stages[missing + later].name,
                cfg.stages[missing].name
            ),
        )),
    }
}

/// Trains one stage (resumes it if it started, extends it if asked for more epochs); None
/// when it is finished.
fn train_stage(
    cfg: &PipelineConfig,
    stage: &StageConfig,
    run_dir: &Path,
    progress: &mut dyn Progress,
    stop: &AtomicBool,
    ddp: Option<Arc<Ddp>>,
) -> Result<Option<TrainOutcome>, TrainError> {
    let dir = run_dir.join(&stage.name);
    // Finished means every epoch it is asked for: a resume may extend a finished stage.
    let done = crate::resume::is_finished(&dir, stage.config.schedule.epochs)?;
    let started = rundir::holds_run(&dir);
    // Every rank has read the stage's state before rank 0 starts writing it.
    barrier(ddp.as_deref())?;
    if done {
        return Ok(None);
    }
    let mut resolved = resolve(&stage.config, run_dir, &cfg.stages)?;
    if started {
        // The stage's own config.json says how many processes trained it (the trainer
        // refuses to continue it exactly with another number).
        resolved.compute.world_size = saved_stage(&stage.name, &resolved, &dir)?
            .compute
            .world_size;
    }
    if ddp.as_ref().is_none_or(|d| d.is_root()) {
        eprintln!(
            "stage {} ({}, {}): {} epochs into {}",
            stage.name,
            resolved.learning.procedure.name(),
            resolved.network.model.name(),
            resolved.schedule.epochs,
            dir.display()
        );
    }
    let mut in_stage = InStage {
        stage: &stage.name,
        inner: progress,
    };
    let outcome =
        trainer::train_observed(&resolved, &dir, started, &mut in_stage, stop, ddp.clone())?;
    // Rank 0 has written the stage's weights before any rank reads them.
    barrier(ddp.as_deref())?;
    Ok(Some(outcome))
}

/// The configuration a started stage's folder holds, which must be this stage's: the same
/// network, procedure and inputs (a folder copied from another recipe's run, or a corrupt
/// config.json, is refused rather than continued as this stage).
fn saved_stage(name: &str, stage: &TrainConfig, dir: &Path) -> Result<TrainConfig, TrainError> {
    let path = dir.join(CONFIG_FILE);
    let RunConfig::Single(saved) = trainer::read_config(dir)? else {
        return Err(run_error(
            &path,
            format!("holds a multi-stage run, not stage {name}"),
        ));
    };
    let model = |c: &TrainConfig| serde_json::to_value(&c.network.model).ok();
    let differs = [
        ("network", model(stage) != model(&saved)),
        (
            "procedure",
            stage.learning.procedure.name() != saved.learning.procedure.name(),
        ),
        ("inputs", stage.network.inputs != saved.network.inputs),
    ];
    if let Some((what, _)) = differs.iter().find(|(_, d)| *d) {
        return Err(run_error(
            &path,
            format!(
                "holds a run of another {what} than stage {name} of this run (a folder from \
                 another run?); remove it to train the stage again"
            ),
        ));
    }
    Ok(*saved)
}

/// The last stage's final and best weights, copied to the run folder.
fn copy_last_stage_weights(cfg: &PipelineConfig, run_dir: &Path) -> Result<(), TrainError> {
    let last = run_dir.join(&cfg.stages.last().expect("validated: a stage").name);
    for file in [FINAL_FILE, BEST_FILE] {
        if last.join(file).is_file() {
            let bytes = std::fs::read(last.join(file))
                .map_err(|e| run_error(&last.join(file), format!("cannot read: {e}")))?;
            rtf_core::write_bytes_atomic(&run_dir.join(file), &bytes)
                .map_err(|e| run_error(&run_dir.join(file), e.to_string()))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_stages(root: &Path) -> PipelineConfig {
        let stage = |name: &str| StageConfig {
            name: name.into(),
            config: TrainConfig::mfnet_paper(root.to_path_buf()),
        };
        PipelineConfig {
            recipe: None,
            stages: vec![stage("teacher"), stage("student")],
        }
    }

    #[test]
    fn a_missing_stage_before_a_started_one_is_refused_naming_both() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = two_stages(dir.path());
        let started = |stage: &str| {
            std::fs::create_dir_all(dir.path().join(stage)).unwrap();
            std::fs::write(dir.path().join(stage).join(CONFIG_FILE), b"{}").unwrap();
        };
        check_stage_folders(&cfg, dir.path()).expect("nothing started");
        started("student");
        let err = check_stage_folders(&cfg, dir.path())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("stage teacher holds no run") && err.contains("student"),
            "{err}"
        );
        started("teacher");
        check_stage_folders(&cfg, dir.path()).expect("both started");
    }
}
