//! Phase 2's steps, restore or start: `config.json` recorded, the procedure's networks built
//! and restored from the checkpoint or started, data-parallel started, label caches, and
//! rank 0's TensorBoard writer.
use std::sync::Arc;

use rtf_models::Network;

use super::run_folder::OpenedRun;
use crate::checkpoint::{self, TrainState};
use crate::config::{NetworkConfig, Procedure as ProcedureConfig};
use crate::ddp::Ddp;
use crate::error::TrainError;
use crate::plan::{RunPlan, Sources};
use crate::procedure::{self, Procedure};
use crate::run::{run_error, LOG_FILE};

/// Writes `config.json` (rank 0): the configuration the plan records, with the data's
/// fingerprint (which data the run used: a resume on changed data says so) and the number of
/// processes. Everything in it was resolved and checked by the plan.
pub(super) fn record_config(plan: &RunPlan, folder: &OpenedRun) -> Result<(), TrainError> {
    if let Some(owned) = &folder.owned {
        owned.write_config(&plan.record(folder.world))?;
    }
    Ok(())
}

/// A resumed run's networks, optimisers and progress from its checkpoint; its log restored to
/// the checkpoint's epochs (a line lost to a kill comes back from the record it carries).
fn restore(folder: &OpenedRun, procedure: &mut dyn Procedure) -> Result<TrainState, TrainError> {
    let mut trained = procedure.trained_mut();
    let mut parts: Vec<(&str, &mut tch::nn::VarStore)> =
        trained.iter_mut().map(|t| (t.role, &mut t.vs)).collect();
    let (mut optimizers, saved) = checkpoint::load(&folder.checkpoint, &mut parts)?;
    drop(parts);
    for t in trained.iter_mut() {
        t.optimizer
            .set_state(optimizers.remove(t.role).unwrap_or_default());
    }
    if let Some(owned) = &folder.owned {
        let lacking = owned.restore_log(saved.epochs_done, &saved.records)?;
        if !lacking.is_empty() {
            eprintln!(
                "warning: {} lacks the records of epochs {lacking:?} (edited or truncated?); \
                 the checkpoint carries only the last one, so they stay missing",
                folder.dir.join(LOG_FILE).display()
            );
        }
    }
    Ok(saved)
}

/// A new run's student from its backbone or starting weights, and no log.
fn start(
    network: &NetworkConfig,
    folder: &OpenedRun,
    procedure: &mut dyn Procedure,
) -> Result<TrainState, TrainError> {
    if folder.is_root {
        let _ = std::fs::remove_file(folder.dir.join(LOG_FILE));
    }
    let student = &mut procedure.trained_mut()[0].vs;
    if let Some(path) = &network.backbone_weights {
        let loaded = rtf_models::backbone::load_backbone_weights(student, &network.model, path)?;
        if folder.is_root {
            eprintln!("{loaded}");
        }
    }
    if let Some(report) = crate::init::load_init(student, network)? {
        if folder.is_root {
            eprintln!("{report}");
        }
    }
    Ok(TrainState {
        epochs_done: 0,
        steps_done: 0,
        best_val_miou: None,
        partial: None,
        records: Vec::new(),
    })
}

/// Teacher labels written once, if the procedure asks: the streams then carry them as labels.
/// Ranks other than 0 never write the run folder: they label into a scratch folder of their
/// own, removed when the run returns.
pub(super) fn cache_labels(
    procedure_cfg: &ProcedureConfig,
    folder: &OpenedRun,
    procedure: &dyn Procedure,
    sources: &mut Sources,
    device: tch::Device,
) -> Result<Option<crate::ddp::ScratchDir>, TrainError> {
    let input = procedure.student().net.input_convention();
    let threshold = match procedure_cfg {
        ProcedureConfig::TeacherStudent { targets, .. }
        | ProcedureConfig::Adversarial { targets, .. } => targets.threshold,
        ProcedureConfig::Supervised => None,
    };
    let (day_labeller, night_labeller) = procedure.labellers();
    let mut scratch: Option<crate::ddp::ScratchDir> = None;
    let streams = [
        (day_labeller, Some(&mut sources.main), "day"),
        (night_labeller, sources.night.as_mut(), "night"),
    ];
    for (labeller, stream, name) in streams {
        let (Some(labeller), Some(stream)) = (labeller.filter(|l| l.cached.is_some()), stream)
        else {
            continue;
        };
        let dir = match folder.is_root {
            true => folder.dir.join("labels").join(name),
            false => scratch
                .get_or_insert_with(crate::ddp::ScratchDir::new)
                .path()
                .join(name),
        };
        crate::label_cache::write(
            &labeller.teacher,
            stream.clone(),
            &dir,
            threshold,
            input,
            device,
        )?;
        *stream = Arc::new(crate::label_cache::CachedLabels::new(stream.clone(), dir));
    }
    Ok(scratch)
}

/// Rank 0's TensorBoard writer (RUN/tb); the other ranks write none.
pub(super) fn tensorboard_writer(
    folder: &OpenedRun,
) -> Result<Option<crate::tensorboard::TbWriter>, TrainError> {
    if !folder.is_root {
        return Ok(None);
    }
    crate::tensorboard::TbWriter::create(folder.dir)
        .map(Some)
        .map_err(|e| run_error(&folder.dir.join("tb"), format!("TensorBoard: {e}")))
}

/// DDP's start: rank 0's weights and BatchNorm statistics on every rank, and every trained
/// network's gradients averaged from now on.
fn start_data_parallel(
    ddp: Option<&Arc<Ddp>>,
    procedure: &mut dyn Procedure,
) -> Result<(), TrainError> {
    let Some(d) = ddp else {
        return Ok(());
    };
    for t in procedure.trained_mut() {
        d.broadcast_all(&t.vs)?;
        t.ddp = Some(d.clone());
    }
    Ok(())
}

/// The procedure and its progress ([`networks`]).
pub(super) type Networks = (Box<dyn Procedure>, TrainState);

/// The procedure's networks and progress: built from the plan's `network`, `learning` and
/// checked teachers (libtorch seeded with the run's seed first; data-parallel with
/// `network.sync_batch_norm`, their BatchNorms built to sum their statistics over the group),
/// restored from the checkpoint or started, and data-parallel started.
pub(super) fn networks(
    plan: &RunPlan,
    folder: &OpenedRun,
    ddp: Option<&Arc<Ddp>>,
) -> Result<Networks, TrainError> {
    tch::manual_seed(plan.schedule.seed as i64);
    let sync = ddp
        .filter(|_| plan.network.sync_batch_norm)
        .map(|d| Arc::clone(d) as Arc<dyn rtf_models::StatsAllReduce>);
    let spec = procedure::Spec {
        network: plan.network,
        learning: plan.learning,
        compute: plan.compute,
        teachers: &plan.teachers,
        sync,
    };
    let mut procedure = procedure::build_from(&spec, plan.sources.ignore_id, plan.device)?;
    let state = match folder.resume {
        true => restore(folder, procedure.as_mut())?,
        false => start(plan.network, folder, procedure.as_mut())?,
    };
    procedure.resume_at(state.steps_done);
    start_data_parallel(ddp, procedure.as_mut())?;
    Ok((procedure, state))
}
