//! The training loop, written once for every procedure: epochs and steps, libtorch reseeded
//! per step, mid-epoch checkpoints, Ctrl-C, validation, logging, best/final weights. What a
//! step does is the procedure's ([`crate::procedure`]). The run folder is described in
//! [`crate::run`].
//!
//! A run's life, in [`train_planned`]'s phases. The configuration is resolved once first
//! ([`RunPlan::resolve`]: its dataset opened and fingerprinted, its teachers checked, its
//! device found); each phase then takes the plan's parts it needs, so that what a phase
//! depends on is visible in its signature:
//!
//! 1. **Open the run folder** (`OpenedRun::open`): every check of the folder that can refuse
//!    the run before it writes, then the lock. Takes `FolderChecks`: the recorded number of
//!    processes (`compute.world_size`) and `schedule.epochs` (a resume must not end before
//!    where it stands).
//! 2. **Restore or start** (`Run::restore_or_start`): takes the plan. It writes the recorded
//!    configuration (`record_config`: `config.json`, with the data's fingerprint and the
//!    number of processes), and hands each step its part: the procedure's networks from
//!    `network`, `learning` and the checked teachers (`procedure::build_from`), a new
//!    student's starting weights from `network` (`start`) or everything from the checkpoint
//!    (`restore`), data-parallel with `network.sync_batch_norm`, label caches with
//!    `learning.procedure`'s threshold (`cache_labels`), and the streams over the plan's
//!    frames from `data` and `schedule` (`Streams::open`, `val_loader`). What the later phases
//!    read is kept in `Run`'s fields: `schedule`, `network`, `learning.optimizer` and
//!    `data.resize`.
//! 3. **An epoch** (`Run::epoch`: `train_steps` → `step`, then `validate`, `keep_best`):
//!    `schedule` (epochs, seed, `checkpoint_every`, `max_steps_per_epoch`), and the
//!    optimiser's learning rate for the epoch's record.
//! 4. **Validate** (`Run::validate`): the validation loader and selection metric built in
//!    phase 2 (`schedule.select_by`, or the dataset's default).
//! 5. **Save** (`Run::save`, rank 0: checkpoint, log line, TensorBoard):
//!    `schedule.tb_images_every`, and for the prediction grid `network.model` and
//!    `data.resize`.
//! 6. **Finish** (`Run::finish`: `final.safetensors`): `network.model` and `network.inputs`
//!    for the weights' metadata.
//!
//! A per-epoch hook goes in `Run::epoch`.
mod epoch;
mod restore_or_start;
mod run_folder;
mod streams;
mod validation;
mod weights;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use indicatif::ProgressBar;
use rtf_data::TrainedOn;
use rtf_models::Network;

use crate::checkpoint::{PartialEpoch, TrainState};
use crate::config::{
    NetworkConfig, OptimizerConfig, ScheduleConfig, SelectMetric, StepAt, TrainConfig,
};
use crate::ddp::Ddp;
pub use crate::error::TrainError;
use crate::plan::RunPlan;
use crate::procedure::{self, Procedure, StepBatches};
use crate::progress::{Epochs, Progress};
use crate::run::{self as rundir, run_error};
pub use crate::run::{BEST_FILE, CHECKPOINT_FILE, CONFIG_FILE, FINAL_FILE, LOG_FILE};

use epoch::{progress_bar, EpochProgress};
use restore_or_start::{cache_labels, networks, record_config, tensorboard_writer};
use run_folder::{FolderChecks, OpenedRun};
pub use streams::training_loader;
use streams::{val_loader, Streams};
pub use validation::{default_select_metric, val_record};
use weights::{check_finite, prediction_grid_png, save_checkpoint};

/// The records of `log.jsonl` (rtf-run: a run folder's files are read back there).
pub use rtf_run::{EpochRecord, ValRecord};

#[derive(Debug, Clone)]
pub struct TrainOutcome {
    pub run_dir: PathBuf,
    /// `final.safetensors`; None when the run was interrupted (its checkpoint holds where it
    /// stopped, `--resume` continues it).
    pub final_weights: Option<PathBuf>,
    /// The records of the epochs this call trained, as `log.jsonl` holds them (rank 0; the
    /// other ranks of a data-parallel run: none).
    pub records: Vec<EpochRecord>,
    pub state: TrainState,
    /// Data-parallel runs: the digest of every trained variable at the end, checked equal on
    /// every rank ([`crate::ddp::Ddp::check_identical`]).
    pub weights_digest: Option<u64>,
}

/// Reads the configuration of an existing run (for `--resume`), checked.
pub use crate::folder::read_config;

/// An error writing RUN/steps.jsonl, naming the file.
fn step_log_error(run_dir: &Path, e: std::io::Error) -> TrainError {
    run_error(&run_dir.join(crate::step_log::STEP_LOG_FILE), e.to_string())
}

/// [`train_until`] that runs to the end.
pub fn train(
    cfg: &TrainConfig,
    run_dir: &Path,
    resume: bool,
    on_epoch: &mut dyn FnMut(&EpochRecord),
) -> Result<TrainOutcome, TrainError> {
    train_until(cfg, run_dir, resume, on_epoch, &AtomicBool::new(false))
}

/// [`train_distributed`] as a single process.
pub fn train_until(
    cfg: &TrainConfig,
    run_dir: &Path,
    resume: bool,
    on_epoch: &mut dyn FnMut(&EpochRecord),
    stop: &AtomicBool,
) -> Result<TrainOutcome, TrainError> {
    train_distributed(cfg, run_dir, resume, on_epoch, stop, None)
}

/// Trains `cfg` into `run_dir`. With `resume`, continues from its checkpoint (every trained
/// network, optimiser state, epoch and, for a mid-epoch checkpoint, the batch; data order and
/// augmentation depend only on (seed, stream, epoch), and libtorch's generator is reseeded from
/// (seed, epoch, batch) before every step, so the continuation equals an uninterrupted run).
/// Stops cleanly once `stop` is set (Ctrl-C, SIGTERM): it finishes the step in flight, writes a
/// mid-epoch checkpoint and returns with `final_weights` None.
///
/// With `ddp`, this process is one rank of a data-parallel run ([`crate::ddp`]): it trains on
/// its shard of every epoch, gradients are averaged over the ranks, a stop on any rank stops
/// every rank at the same step, and only rank 0 writes `run_dir` (the other ranks read it on
/// resume: a multi-node run needs it on a shared filesystem to resume).
pub fn train_distributed(
    cfg: &TrainConfig,
    run_dir: &Path,
    resume: bool,
    on_epoch: &mut dyn FnMut(&EpochRecord),
    stop: &AtomicBool,
    ddp: Option<Arc<Ddp>>,
) -> Result<TrainOutcome, TrainError> {
    let mut epochs = Epochs(|_: &str, r: &EpochRecord| on_epoch(r));
    train_observed(cfg, run_dir, resume, &mut epochs, stop, ddp)
}

/// [`train_distributed`] reporting every step and epoch to `progress`.
pub fn train_observed(
    cfg: &TrainConfig,
    run_dir: &Path,
    resume: bool,
    progress: &mut dyn Progress,
    stop: &AtomicBool,
    ddp: Option<Arc<Ddp>>,
) -> Result<TrainOutcome, TrainError> {
    let plan = RunPlan::resolve(cfg)?;
    train_planned(plan, run_dir, resume, progress, stop, ddp)
}

/// Trains a resolved run `plan` into `run_dir` ([`train_distributed`] once the configuration
/// is resolved: nothing of it is opened or checked again).
pub fn train_planned(
    plan: RunPlan,
    run_dir: &Path,
    resume: bool,
    progress: &mut dyn Progress,
    stop: &AtomicBool,
    ddp: Option<Arc<Ddp>>,
) -> Result<TrainOutcome, TrainError> {
    let folder = OpenedRun::open(FolderChecks::of(&plan), run_dir, resume, ddp.as_deref())?;
    let epochs = plan.schedule.epochs;
    let (mut run, streams) = Run::restore_or_start(plan, folder, ddp)?;
    for epoch in run.state.epochs_done..epochs {
        if let EpochEnd::Stopped = run.epoch(&streams, epoch, progress, stop)? {
            return run.stopped();
        }
    }
    run.finish()
}

enum EpochEnd {
    Done,
    /// Stopped (Ctrl-C, SIGTERM, a stop agreed by every rank); its checkpoint is written.
    Stopped,
}

/// One run's life after its folder is open: the trained networks and their progress, what
/// validation reads, and what rank 0 writes besides the checkpoint.
struct Run<'a> {
    /// Epochs, seed, checkpoint and TensorBoard cadence.
    schedule: &'a ScheduleConfig,
    /// The student's network and inputs (the weights' metadata, the prediction grid's title).
    network: &'a NetworkConfig,
    /// The learning rate each epoch's record logs.
    optimizer: &'a OptimizerConfig,
    /// The frame size the prediction grid is drawn at.
    resize: Option<(usize, usize)>,
    ddp: Option<Arc<Ddp>>,
    device: tch::Device,
    procedure: Box<dyn Procedure>,
    state: TrainState,
    /// One validation loader for the whole run: a loader per validation started fresh decoding
    /// threads every epoch, and each ended thread's allocator heap stayed behind (~15 MB per
    /// epoch at 64×48, issue 30; rtf_eval::evaluate::split_loader).
    val: Option<rtf_data::Loader>,
    /// Each step's loss terms (RUN/steps.jsonl), for step-by-step comparison with a reference.
    step_log: crate::step_log::StepLog,
    freiburg: bool,
    /// Recorded in the weights' metadata beside the network.
    trained_on: TrainedOn,
    select: SelectMetric,
    steps_per_epoch: usize,
    tb: Option<crate::tensorboard::TbWriter>,
    /// The first epoch this call trains (its records are the outcome's, read back from the
    /// log at the end: nothing per epoch stays in memory).
    first_epoch: usize,
    /// Data-parallel: the stop every rank agreed on at the last step.
    stop_agreed: bool,
    _scratch: Option<crate::ddp::ScratchDir>,
    /// Last: the run folder's lock goes when everything else is done.
    folder: OpenedRun<'a>,
}

impl<'a> Run<'a> {
    /// Phase 2, restore or start: the config recorded, the networks built and restored from
    /// the checkpoint or initialised, data-parallel started, label caches and the streams.
    fn restore_or_start(
        plan: RunPlan<'a>,
        folder: OpenedRun<'a>,
        ddp: Option<Arc<Ddp>>,
    ) -> Result<(Self, Streams), TrainError> {
        record_config(&plan, &folder)?;
        let (procedure, state) = networks(&plan, &folder, ddp.as_ref())?;
        let RunPlan {
            network,
            data,
            learning,
            schedule,
            device,
            mut sources,
            ..
        } = plan;
        let scratch = cache_labels(
            &learning.procedure,
            &folder,
            procedure.as_ref(),
            &mut sources,
            device,
        )?;
        let tb = tensorboard_writer(&folder)?;
        let input = procedure.student().net.input_convention();
        let streams = Streams::open(data, schedule, &sources, input, ddp.as_deref())?;
        let val = sources
            .val
            .clone()
            .map(|val| val_loader(data, schedule.batch_size, val, input));
        let step_log = crate::step_log::StepLog::open(folder.dir, folder.is_root, state.steps_done)
            .map_err(|e| step_log_error(folder.dir, e))?;
        let batches = streams.main.num_batches();
        let steps_per_epoch = schedule
            .max_steps_per_epoch
            .map_or(batches, |m| m.min(batches));
        let first_epoch = state.epochs_done;
        let run = Self {
            schedule,
            network,
            optimizer: &learning.optimizer,
            resize: data.resize,
            ddp,
            device,
            procedure,
            state,
            val,
            step_log,
            freiburg: sources.dataset.scores_heatnet(),
            trained_on: sources.trained_on.clone(),
            select: schedule
                .select_by
                .unwrap_or_else(|| default_select_metric(&sources.dataset)),
            steps_per_epoch,
            tb,
            first_epoch,
            stop_agreed: false,
            _scratch: scratch,
            folder,
        };
        Ok((run, streams))
    }

    /// Phase 3, an epoch: its steps, validation, the best weights, and its checkpoint, log
    /// line and TensorBoard scalars (rank 0).
    fn epoch(
        &mut self,
        streams: &Streams,
        epoch: usize,
        observer: &mut dyn Progress,
        stop: &AtomicBool,
    ) -> Result<EpochEnd, TrainError> {
        let Some(progress) = self.train_steps(streams, epoch, observer, stop)? else {
            return Ok(EpochEnd::Stopped);
        };
        let seconds = progress.elapsed().as_secs_f64();
        let val = self.validate()?;
        self.state.epochs_done = epoch + 1;
        let record = self.epoch_record(epoch, progress, seconds, val);
        self.keep_best(epoch, &record)?;
        // The checkpoint carries this epoch's record only: the log holds the others.
        self.state.records = vec![record.clone()];
        let data_parallel = self.ddp.is_some();
        let stopping = match (data_parallel, self.folder.is_root) {
            (_, false) => {
                // Rank 0 writes the checkpoint, the log and TensorBoard.
                check_finite(self.procedure.as_ref(), epoch, self.state.steps_done)?;
                self.stop_agreed
            }
            (data_parallel, true) => {
                self.save(epoch, &record)?;
                observer.epoch("", &record);
                match data_parallel {
                    true => self.stop_agreed,
                    false => stop.load(Ordering::Relaxed),
                }
            }
        };
        // Stopped on an epoch's last step: its checkpoint is the epoch-end one.
        match stopping && self.state.epochs_done < self.schedule.epochs {
            true => Ok(EpochEnd::Stopped),
            false => Ok(EpochEnd::Done),
        }
    }

    /// The epoch's steps from where its checkpoint left it; None when stopped inside it (its
    /// mid-epoch checkpoint is written).
    fn train_steps(
        &mut self,
        streams: &Streams,
        epoch: usize,
        observer: &mut dyn Progress,
        stop: &AtomicBool,
    ) -> Result<Option<EpochProgress>, TrainError> {
        let steps_per_epoch = self.steps_per_epoch;
        let bar = match self.folder.is_root {
            true => progress_bar(steps_per_epoch, epoch, self.schedule.epochs),
            false => ProgressBar::hidden(),
        };
        let mut progress =
            EpochProgress::from_checkpoint(self.state.partial.take(), steps_per_epoch);
        let first = progress.first;
        bar.set_position(first as u64);
        if let Some(shard) = &streams.main_shard {
            shard.set_epoch(epoch as u64);
        }
        let batches = streams
            .main
            .epoch_from(epoch as u64, first)
            .take(steps_per_epoch - first);
        let mut night_batches = streams.night_from(epoch * steps_per_epoch + first);
        for (step, batch) in (first..).zip(batches) {
            // Reseeded per step so a resumed run draws the same random numbers (dropout, ...).
            tch::manual_seed(
                rtf_data::loader::mix(self.schedule.seed, epoch as u64, step as u64) as i64,
            );
            let batch = batch?;
            let night_batch = match night_batches.as_mut() {
                Some(it) => Some(
                    it.next()
                        .ok_or_else(|| TrainError::Config("the night stream ended".into()))??,
                ),
                None => None,
            };
            let mut interrupted =
                self.step(epoch, step, batch, night_batch, &mut progress, stop)?;
            if self.folder.is_root {
                observer.step("", &self.step_log.last);
            }
            // A stop asked while the observer ran (its exception, a signal) ends the run at this
            // step; a data-parallel run stops only at a step every rank agreed on.
            if self.ddp.is_none() {
                interrupted |= stop.load(Ordering::Relaxed);
            }
            bar.set_message(format!(
                "loss {:.4} | {:.1} img/s",
                progress.loss_sum / (step + 1) as f64,
                progress.images as f64 / progress.elapsed().as_secs_f64().max(1e-9)
            ));
            bar.inc(1);
            let scheduled = self.schedule.checkpoint_every.is_some_and(|every| {
                every > 0 && self.state.steps_done.is_multiple_of(every as u64)
            });
            // On an epoch's last step the epoch-end checkpoint does the work.
            if step + 1 < steps_per_epoch && (interrupted || scheduled) {
                self.state.partial = Some(progress.partial(step + 1));
                self.save_or_check(epoch)?;
                if interrupted {
                    bar.abandon();
                    return Ok(None);
                }
                self.state.partial = None;
            }
        }
        bar.finish_and_clear();
        Ok(Some(progress))
    }

    /// One optimisation step and its accounting; whether the run stops after it.
    fn step(
        &mut self,
        epoch: usize,
        step: usize,
        batch: rtf_data::Batch,
        night_batch: Option<rtf_data::Batch>,
        progress: &mut EpochProgress,
        stop: &AtomicBool,
    ) -> Result<bool, TrainError> {
        progress.waited += batch.wait + night_batch.as_ref().map_or(Duration::ZERO, |b| b.wait);
        let count = batch.names.len();
        let device = self.device;
        let on_device = |mut b: rtf_data::Batch| {
            b.input = b.input.to_device(device);
            b.target = b.target.to_device(device);
            b
        };
        let batches = StepBatches {
            main: on_device(batch),
            night: night_batch.map(on_device),
        };
        let mut report = self.procedure.step(&batches, self.at(epoch, step))?;
        let mut interrupted = stop.load(Ordering::Relaxed);
        if self.ddp.is_some() {
            interrupted = self.sync_step(epoch, step, count, &mut report, progress, interrupted)?;
            self.stop_agreed = interrupted;
        }
        if !report.total.is_finite() {
            return Err(TrainError::Diverged {
                epoch,
                step: self.state.steps_done,
                what: format!("loss is {}", report.total),
            });
        }
        let terms = report.terms.iter().chain(&report.metrics);
        self.step_log
            .record(epoch, self.state.steps_done, report.total, terms)
            .map_err(|e| step_log_error(self.folder.dir, e))?;
        self.state.steps_done += 1;
        progress.loss_sum += report.total;
        for (name, value) in report.terms.iter().chain(&report.metrics) {
            *progress.term_sums.entry(name.clone()).or_default() += value;
        }
        progress.images += count * self.folder.world.unwrap_or(1);
        Ok(interrupted)
    }

    /// Data-parallel: rank 0's BatchNorm statistics everywhere, and one all-reduce that agrees
    /// on stopping and averages the losses to log over every rank's batch. Returns the stop
    /// every rank agreed on. A collective that failed (a dead rank, a timeout) stops every
    /// rank; rank 0 checkpoints where the step left its weights: before it when the gradient
    /// all-reduce failed (the update was skipped), after it otherwise.
    fn sync_step(
        &mut self,
        epoch: usize,
        step: usize,
        count: usize,
        report: &mut procedure::StepReport,
        progress: &EpochProgress,
        interrupted: bool,
    ) -> Result<bool, TrainError> {
        let d = self.ddp.clone().expect("a data-parallel run");
        let keys: Vec<String> = report
            .terms
            .keys()
            .chain(report.metrics.keys())
            .cloned()
            .collect();
        let values: Vec<f64> = std::iter::once(report.total)
            .chain(report.terms.values().copied())
            .chain(report.metrics.values().copied())
            .collect();
        let synced = match d.check() {
            Err(e) => Err((e, step)),
            Ok(()) => self
                .procedure
                .trained()
                .iter()
                .try_for_each(|t| d.broadcast_buffers(&t.vs))
                .and_then(|_| d.agree(interrupted, &values))
                .map_err(|e| (e, step + 1)),
        };
        let (any_stop, sums) = match synced {
            Ok(agreed) => agreed,
            Err((error, batches)) => {
                let after = batches > step;
                let mut partial = progress.partial(batches);
                if after {
                    partial.loss_sum += report.total;
                    partial.images += count * self.folder.world.unwrap_or(1);
                }
                return Err(self.collective_failed(epoch, partial, after, error));
            }
        };
        let n = d.world_size() as f64;
        report.total = sums[0] / n;
        for (key, sum) in keys.iter().zip(&sums[1..]) {
            if let Some(v) = report.terms.get_mut(key) {
                *v = sum / n;
            } else if let Some(v) = report.metrics.get_mut(key) {
                *v = sum / n;
            }
        }
        Ok(any_stop)
    }

    /// A failed collective: rank 0 writes the checkpoint `partial` describes (`after`: the
    /// failed step's update was applied) and the error says how to continue.
    fn collective_failed(
        &mut self,
        epoch: usize,
        partial: PartialEpoch,
        after: bool,
        error: TrainError,
    ) -> TrainError {
        let mut message = format!("{error}; every rank stops");
        if !self.folder.is_root {
            return TrainError::Config(message);
        }
        self.state.steps_done += after as u64;
        let partial_batches = partial.batches;
        self.state.partial = Some(partial);
        if let Err(e) = self.save_checkpoint(epoch) {
            return e;
        }
        message += &format!(
            "; rank 0 wrote a checkpoint at epoch {}, batch {}: \
             continue with `rtf train --resume {}` under torchrun with as \
             many processes",
            epoch + 1,
            partial_batches,
            self.folder.dir.display()
        );
        TrainError::Config(message)
    }

    /// Phase 4, validate: the student on the validation frames, if the run has them.
    fn validate(&self) -> Result<Option<ValRecord>, TrainError> {
        let Some(loader) = &self.val else {
            return Ok(None);
        };
        let student = &self.procedure.student().net;
        let report = rtf_eval::evaluate::evaluate_loader(student, loader, None, self.device)?;
        Ok(Some(val_record(&report, self.freiburg, self.select)))
    }

    /// Step `step` of `epoch` in this run (what per-step schedules read).
    fn at(&self, epoch: usize, step: usize) -> StepAt {
        StepAt {
            epoch,
            step,
            steps_per_epoch: self.steps_per_epoch,
            epochs: self.schedule.epochs,
        }
    }

    fn epoch_record(
        &self,
        epoch: usize,
        progress: EpochProgress,
        seconds: f64,
        val: Option<ValRecord>,
    ) -> EpochRecord {
        let steps = self.steps_per_epoch.max(1) as f64;
        let (losses, metrics): (BTreeMap<_, _>, BTreeMap<_, _>) = progress
            .term_sums
            .into_iter()
            .map(|(k, v)| (k, v / steps))
            .partition(|(k, _)| !k.starts_with("critic_acc"));
        EpochRecord {
            epoch,
            lr: self.optimizer.lr_at(self.at(epoch, 0)),
            train_loss: progress.loss_sum / steps,
            images: progress.images,
            seconds,
            images_per_s: progress.images as f64 / seconds.max(1e-9),
            data_wait_fraction: progress.waited.as_secs_f64() / seconds.max(1e-9),
            val_miou: val.as_ref().map(|v| v.miou),
            val_macc: val.as_ref().map(|v| v.macc),
            losses,
            lrs: self
                .procedure
                .trained()
                .iter()
                .map(|t| (t.role.to_string(), t.schedule.lr_at(self.at(epoch, 0))))
                .collect(),
            metrics,
            val,
        }
    }

    /// `best.safetensors` when the selection metric improved.
    fn keep_best(&mut self, epoch: usize, record: &EpochRecord) -> Result<(), TrainError> {
        let Some(v) = &record.val else {
            return Ok(());
        };
        if !self
            .state
            .best_val_miou
            .is_none_or(|best| v.selected > best)
        {
            return Ok(());
        }
        check_finite(self.procedure.as_ref(), epoch, self.state.steps_done)?;
        self.state.best_val_miou = Some(v.selected);
        if self.folder.is_root {
            self.save_student(&self.folder.dir.join(BEST_FILE))?;
        }
        Ok(())
    }

    /// Phase 5, save (rank 0): the epoch-end checkpoint, the log line, and TensorBoard: every
    /// scalar of the record (loss terms, rates, validation, critic), and every N epochs a
    /// prediction grid of validation frames.
    fn save(&mut self, epoch: usize, record: &EpochRecord) -> Result<(), TrainError> {
        self.save_checkpoint(epoch)?;
        if let Some(owned) = &self.folder.owned {
            owned.append_log(record)?;
        }
        let grid = match (&self.val, self.schedule.tb_images_every) {
            (Some(val), Some(every)) if every > 0 && (epoch + 1).is_multiple_of(every) => {
                Some(prediction_grid_png(
                    self.procedure.student(),
                    val.source().as_ref(),
                    self.network,
                    self.resize,
                    self.device,
                )?)
            }
            _ => None,
        };
        let tb = self.tb.as_mut().expect("rank 0 has its TensorBoard writer");
        let written = tb
            .record(&serde_json::to_value(record).expect("record serialises"))
            .and_then(|_| match &grid {
                Some(png) => tb.image_png("val/predictions", epoch as i64, png),
                None => Ok(()),
            })
            .and_then(|_| tb.flush());
        written.map_err(|e| run_error(&self.folder.dir.join("tb"), format!("TensorBoard: {e}")))
    }

    fn save_checkpoint(&self, epoch: usize) -> Result<(), TrainError> {
        save_checkpoint(
            &self.folder.checkpoint,
            self.procedure.as_ref(),
            &self.state,
            epoch,
        )
    }

    /// A mid-epoch checkpoint on rank 0; the other ranks check their weights as it would.
    fn save_or_check(&self, epoch: usize) -> Result<(), TrainError> {
        match self.folder.is_root {
            true => self.save_checkpoint(epoch),
            false => check_finite(self.procedure.as_ref(), epoch, self.state.steps_done),
        }
    }

    /// The student's weights with the network, its inputs and its classes in the metadata.
    fn save_student(&self, path: &Path) -> Result<(), TrainError> {
        use rtf_models::io::weights::{model_metadata, save_named_with_metadata, state_dict};
        let mut metadata = model_metadata(&self.network.model, self.network.inputs);
        metadata.extend([self.trained_on.metadata_entry()]);
        let vs = &self.procedure.student().trained.vs;
        save_named_with_metadata(&state_dict(vs), Some(metadata), path)?;
        Ok(())
    }

    /// The outcome of a stopped run (`--resume` continues it from its checkpoint).
    fn stopped(self) -> Result<TrainOutcome, TrainError> {
        Ok(TrainOutcome {
            run_dir: self.folder.dir.to_path_buf(),
            final_weights: None,
            records: self.records_trained()?,
            state: self.state,
            weights_digest: None,
        })
    }

    /// The records of the epochs this call trained, from `log.jsonl` (rank 0; the other ranks
    /// write no log and return none).
    fn records_trained(&self) -> Result<Vec<EpochRecord>, TrainError> {
        if !self.folder.is_root {
            return Ok(Vec::new());
        }
        let path = self.folder.dir.join(LOG_FILE);
        // Lines of earlier epochs may be an older build's schema: only this call's are read.
        let text = rundir::read_log(self.folder.dir)?;
        Ok(rtf_run::log::parse_from(&text, &path, self.first_epoch)?)
    }

    /// Phase 6, finish: every rank holds the same weights (data-parallel), and rank 0 writes
    /// `final.safetensors`.
    fn finish(self) -> Result<TrainOutcome, TrainError> {
        let final_weights = self.folder.dir.join(FINAL_FILE);
        let weights_digest = match &self.ddp {
            Some(d) => Some(d.check_identical(self.procedure.trained().iter().map(|t| &t.vs))?),
            None => None,
        };
        if self.folder.is_root {
            self.save_student(&final_weights)?;
        }
        Ok(TrainOutcome {
            run_dir: self.folder.dir.to_path_buf(),
            final_weights: Some(final_weights),
            records: self.records_trained()?,
            state: self.state,
            weights_digest,
        })
    }
}
