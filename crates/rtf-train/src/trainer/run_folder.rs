//! Phase 1, open the run folder: what it checks the configuration for ([`FolderChecks`]),
//! every check that can refuse the run before it writes, and, on rank 0, the folder owned
//! for writing (rtf-run's [`OwnedFolder`]: created, locked) ([`OpenedRun`]).
use std::path::{Path, PathBuf};

use crate::checkpoint;
use crate::ddp::Ddp;
use crate::error::TrainError;
use crate::plan::RunPlan;
use rtf_run::write::{refuse_existing_run, OwnedFolder};

use crate::run::CHECKPOINT_FILE;

/// What opening the run folder checks the configuration for (phase 1): the number of
/// processes the run was trained by, and its epochs (a resume must not end before where it
/// stands). The teachers were checked by the plan.
pub(super) struct FolderChecks {
    pub(super) world_size: Option<usize>,
    pub(super) epochs: usize,
}

impl FolderChecks {
    pub(super) fn of(plan: &RunPlan) -> Self {
        Self {
            world_size: plan.compute.world_size,
            epochs: plan.schedule.epochs,
        }
    }
}

/// The run folder, held for the run's life: rank 0 owns it for writing; `resume` says whether
/// the run continues its checkpoint.
pub(super) struct OpenedRun<'a> {
    pub(super) dir: &'a Path,
    pub(super) checkpoint: PathBuf,
    pub(super) resume: bool,
    pub(super) is_root: bool,
    /// Data-parallel: the number of processes.
    pub(super) world: Option<usize>,
    /// Rank 0's ownership of the folder (its lock); None on the other ranks.
    pub(super) owned: Option<OwnedFolder>,
}

impl<'a> OpenedRun<'a> {
    /// Phase 1, open the run folder: every check that can refuse the run before it writes.
    pub(super) fn open(
        checks: FolderChecks,
        dir: &'a Path,
        resume: bool,
        ddp: Option<&Ddp>,
    ) -> Result<Self, TrainError> {
        let checkpoint = dir.join(CHECKPOINT_FILE);
        let is_root = ddp.is_none_or(|d| d.is_root());
        let world = ddp.map(|d| d.world_size());
        if checks.world_size.unwrap_or(1) != world.unwrap_or(1) && resume {
            return Err(TrainError::Config(format!(
                "{}: the run was trained by {} process(es), this is {}; resume it with as many \
                 (torchrun --nproc-per-node ...) so that it continues exactly",
                dir.display(),
                checks.world_size.unwrap_or(1),
                world.unwrap_or(1)
            )));
        }
        if is_root && !resume {
            refuse_existing_run(dir)?;
        }
        let owned = match is_root {
            true => Some(OwnedFolder::open(dir)?),
            false => None,
        };
        // A resume of a run killed before its first checkpoint starts it over.
        let resume = resume && checkpoint.exists();
        if resume {
            check_resume_epochs(checks.epochs, dir, &checkpoint)?;
        }
        Ok(Self {
            dir,
            checkpoint,
            resume,
            is_root,
            world,
            owned,
        })
    }
}

/// Refuses `--epochs` that would end a resumed run before where it stands.
fn check_resume_epochs(epochs: usize, dir: &Path, checkpoint: &Path) -> Result<(), TrainError> {
    let saved = checkpoint::read_state(checkpoint)?;
    // A checkpoint inside an epoch holds weights past the epochs done: ending the run
    // there would call mid-epoch weights final.
    let stands_at = saved.epochs_done + saved.partial.is_some() as usize;
    if epochs < stands_at {
        return Err(TrainError::Config(format!(
            "{}: the run has done {} epochs{}; --epochs {} would end it before where it stands",
            dir.display(),
            saved.epochs_done,
            match saved.partial.is_some() {
                true => format!(" and part of epoch {stands_at}"),
                false => String::new(),
            },
            epochs
        )));
    }
    Ok(())
}
