//! The training loop, written once for every procedure: epochs and steps, libtorch reseeded
//! per step, mid-epoch checkpoints, Ctrl-C, validation, logging, best/final weights. What a
//! step does is the procedure's ([`crate::procedure`]). The run folder is described in
//! [`crate::run`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use rtf_core::Daytime;
use rtf_data::frame::Subset;
use rtf_data::{FrameSource, FreiburgPart, FreiburgSplit, Loader, LoaderConfig, MfDataset};
use rtf_eval::{EvalOptions, EvalReport};
use rtf_models::Network;
use serde::{Deserialize, Serialize};

use crate::checkpoint::{self, Part, PartialEpoch, TrainState};
use crate::config::{DatasetConfig, SelectMetric, TrainConfig, WeightsRef};
pub use crate::error::TrainError;
use crate::procedure::{self, Procedure, StepBatches};
use crate::run::{self as rundir, run_error};
pub use crate::run::{BEST_FILE, CHECKPOINT_FILE, CONFIG_FILE, FINAL_FILE, LOG_FILE};

/// Validation scores of one epoch (percent-free fractions like every score of rtf-eval).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ValRecord {
    pub miou: f64,
    pub macc: f64,
    #[serde(default)]
    pub miou_day: Option<f64>,
    #[serde(default)]
    pub miou_night: Option<f64>,
    /// HeatNet's convention (Freiburg only): day, night and their mean.
    #[serde(default)]
    pub miou_heatnet_day: Option<f64>,
    #[serde(default)]
    pub miou_heatnet_night: Option<f64>,
    #[serde(default)]
    pub miou_heatnet: Option<f64>,
    #[serde(default)]
    pub per_class_iou: BTreeMap<String, Option<f64>>,
    #[serde(default)]
    pub per_class_iou_day: BTreeMap<String, Option<f64>>,
    #[serde(default)]
    pub per_class_iou_night: BTreeMap<String, Option<f64>>,
    /// The score that picks `best.safetensors`, and its value.
    pub selected_by: String,
    pub selected: f64,
}

/// What one epoch did (a line of `log.jsonl`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochRecord {
    pub epoch: usize,
    /// The student's learning rate.
    pub lr: f64,
    /// Mean of the student's objective over the epoch's steps.
    pub train_loss: f64,
    pub images: usize,
    pub seconds: f64,
    pub images_per_s: f64,
    /// Share of the epoch's time spent waiting for the data pipeline.
    pub data_wait_fraction: f64,
    pub val_miou: Option<f64>,
    pub val_macc: Option<f64>,
    /// Every loss term by name, mean over the epoch's steps.
    #[serde(default)]
    pub losses: BTreeMap<String, f64>,
    /// Learning rate of every trained network, by role.
    #[serde(default)]
    pub lrs: BTreeMap<String, f64>,
    /// Training metrics (the critic's day / night accuracy), mean over the epoch's steps.
    #[serde(default)]
    pub metrics: BTreeMap<String, f64>,
    #[serde(default)]
    pub val: Option<ValRecord>,
}

#[derive(Debug, Clone)]
pub struct TrainOutcome {
    pub run_dir: PathBuf,
    /// `final.safetensors`; None when the run was interrupted (its checkpoint holds where it
    /// stopped, `--resume` continues it).
    pub final_weights: Option<PathBuf>,
    pub records: Vec<EpochRecord>,
    pub state: TrainState,
    /// Data-parallel runs: the digest of every trained variable at the end, checked equal on
    /// every rank ([`crate::ddp::Ddp::check_identical`]).
    pub weights_digest: Option<u64>,
}

/// Reads the configuration of an existing run (for `--resume`), checked.
pub fn read_config(run_dir: &Path) -> Result<crate::config::RunConfig, TrainError> {
    let path = run_dir.join(CONFIG_FILE);
    let text = std::fs::read_to_string(&path)
        .map_err(|e| run_error(&path, format!("cannot read: {e}")))?;
    let cfg = crate::config::RunConfig::parse(&text, false)
        .map_err(|e| run_error(&path, format!("not a training config: {e}")))?;
    cfg.validate()
        .map_err(|e| run_error(&path, format!("invalid value: {e}")))?;
    Ok(cfg)
}

type Source = Arc<dyn FrameSource>;

/// Where a run's frames come from: the main stream (labelled frames for supervised training,
/// day frames for the label-free procedures), the night stream if the procedure uses one, and
/// validation (never the test split).
struct Sources {
    main: Source,
    night: Option<Source>,
    val: Option<Source>,
    ignore_id: Option<u8>,
    freiburg: bool,
}

fn open_sources(cfg: &TrainConfig) -> Result<Sources, TrainError> {
    let labels = cfg.procedure.reads_labels();
    let (train, val, freiburg): (Source, Option<Source>, bool) = match &cfg.dataset {
        DatasetConfig::Mf {
            root,
            train_split,
            val_split,
        } => {
            let mf = MfDataset::open(root)?;
            let train: Source = match labels {
                true => Arc::new(mf.split(train_split)?),
                false => Arc::new(mf.split_images_only(train_split)?),
            };
            let val = match val_split {
                Some(name) => Some(Arc::new(mf.split(name)?) as Source),
                None => None,
            };
            (train, val, false)
        }
        DatasetConfig::Freiburg {
            root,
            train_preprocess,
            val_preprocess,
            validate,
        } => {
            let tree =
                FreiburgSplit::open(root, train_preprocess.clone())?.part(FreiburgPart::TrainTree);
            let train = match labels {
                true => tree.filter(|_, _, labelled| labelled),
                false => tree,
            };
            if train.is_empty() {
                return Err(run_error(
                    root,
                    match labels {
                        true => "no labelled frames in a Freiburg training tree (<run>/<seq>/fl_rgb + fl_rgb_labels)",
                        false => "no frames in a Freiburg training tree (<run>/<seq>/fl_rgb)",
                    },
                ));
            }
            let val = match validate {
                true => Some(
                    FreiburgSplit::open(root, val_preprocess.clone())?
                        .part(FreiburgPart::Validation)
                        .filter(|_, _, labelled| labelled),
                ),
                false => None,
            }
            .filter(|v| !v.is_empty())
            .map(|v| Arc::new(v) as Source);
            (Arc::new(train), val, true)
        }
    };
    let ignore_id = train.class_set().ignore_id;
    if labels {
        return Ok(Sources {
            main: train,
            night: None,
            val,
            ignore_id,
            freiburg,
        });
    }
    let day: Source = Arc::new(Subset::of_daytime(train.clone(), Daytime::Day, false));
    if day.is_empty() {
        return Err(TrainError::Config(
            "the training frames hold no day frame (MF: names ending in D; Freiburg: paths without `night`)".into(),
        ));
    }
    let night = match cfg.procedure.uses_night() {
        true => {
            let night: Source = Arc::new(Subset::of_daytime(train, Daytime::Night, false));
            if night.is_empty() {
                return Err(TrainError::Config(format!(
                    "the {} procedure needs night frames; the training frames hold none",
                    cfg.procedure.name()
                )));
            }
            Some(night)
        }
        false => None,
    };
    Ok(Sources {
        // Unlabelled subsets of MF gain an ignore id: label caches mark low confidence with it.
        ignore_id: day.class_set().ignore_id,
        main: day,
        night,
        val,
        freiburg,
    })
}

fn loader(
    cfg: &TrainConfig,
    source: Source,
    seed: u64,
    input: rtf_core::InputConvention,
) -> Loader {
    Loader::new(
        source,
        LoaderConfig {
            batch_size: cfg.batch_size,
            shuffle: true,
            drop_last: false,
            seed,
            workers: cfg.workers,
            prefetch: 2,
            augment: cfg.augment.clone(),
            resize: cfg.resize,
        },
        input,
    )
}

/// The default selection metric of a dataset: HeatNet's day/night mIoU on Freiburg, mIoU on MF.
pub fn default_select_metric(dataset: &DatasetConfig) -> SelectMetric {
    match dataset {
        DatasetConfig::Freiburg { .. } => SelectMetric::HeatnetMiou,
        DatasetConfig::Mf { .. } => SelectMetric::Miou,
    }
}

fn per_class(scores: &rtf_eval::metrics::Scores) -> BTreeMap<String, Option<f64>> {
    scores
        .per_class
        .iter()
        .map(|c| (c.name.clone(), c.iou))
        .collect()
}

fn mean_of(values: &[Option<f64>]) -> Option<f64> {
    let v: Vec<f64> = values.iter().flatten().copied().collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The epoch's validation record from an evaluation report.
pub fn val_record(report: &EvalReport, freiburg: bool, select: SelectMetric) -> ValRecord {
    let classes = rtf_eval::metrics::HEATNET_MIOU_CLASSES;
    let heatnet = |s: &Option<rtf_eval::metrics::Scores>| {
        s.as_ref()
            .filter(|_| freiburg)
            .and_then(|s| s.miou_heatnet(classes))
    };
    let (miou_day, miou_night) = (
        report.day.as_ref().map(|s| s.miou),
        report.night.as_ref().map(|s| s.miou),
    );
    let (h_day, h_night) = (heatnet(&report.day), heatnet(&report.night));
    let miou_heatnet = mean_of(&[h_day, h_night]);
    let selected = match select {
        SelectMetric::Miou => Some(report.all.miou),
        SelectMetric::DayNightMiou => mean_of(&[miou_day, miou_night]),
        SelectMetric::HeatnetMiou => miou_heatnet,
        SelectMetric::DayMiou => miou_day,
        SelectMetric::NightMiou => miou_night,
    };
    ValRecord {
        miou: report.all.miou,
        macc: report.all.macc,
        miou_day,
        miou_night,
        miou_heatnet_day: h_day,
        miou_heatnet_night: h_night,
        miou_heatnet,
        per_class_iou: per_class(&report.all),
        per_class_iou_day: report.day.as_ref().map(per_class).unwrap_or_default(),
        per_class_iou_night: report.night.as_ref().map(per_class).unwrap_or_default(),
        selected_by: select.name().to_string(),
        // A metric the validation frames cannot give (no night frame) falls back to mIoU.
        selected: selected.unwrap_or(report.all.miou),
    }
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
    ddp: Option<Arc<crate::ddp::Ddp>>,
) -> Result<TrainOutcome, TrainError> {
    cfg.validate()?;
    let device = cfg.device().map_err(TrainError::Config)?;
    let checkpoint_path = run_dir.join(CHECKPOINT_FILE);
    let is_root = ddp.as_ref().is_none_or(|d| d.is_root());
    let world = ddp.as_ref().map(|d| d.world_size());
    if cfg.world_size.unwrap_or(1) != world.unwrap_or(1) && resume {
        return Err(TrainError::Config(format!(
            "{}: the run was trained by {} process(es), this is {}; resume it with as many \
             (torchrun --nproc-per-node ...) so that it continues exactly",
            run_dir.display(),
            cfg.world_size.unwrap_or(1),
            world.unwrap_or(1)
        )));
    }
    if is_root && !resume && rundir::holds_run(run_dir) {
        return Err(run_error(
            run_dir,
            "already holds a run; use --resume to continue it or choose another output folder",
        ));
    }
    procedure::check_teachers(cfg)?;
    let _lock = match is_root {
        true => {
            std::fs::create_dir_all(run_dir)
                .map_err(|e| run_error(run_dir, format!("cannot create: {e}")))?;
            let lock = rundir::RunLock::acquire(run_dir)?;
            rundir::remove_orphan_temp_files(run_dir);
            Some(lock)
        }
        false => None,
    };
    // A resume of a run killed before its first checkpoint starts it over.
    let resume = resume && checkpoint_path.exists();
    if resume {
        let saved = checkpoint::read_state(&checkpoint_path)?;
        // A checkpoint inside an epoch holds weights past the epochs done: ending the run
        // there would call mid-epoch weights final.
        let stands_at = saved.epochs_done + saved.partial.is_some() as usize;
        if cfg.epochs < stands_at {
            return Err(TrainError::Config(format!(
                "{}: the run has done {} epochs{}; --epochs {} would end it before where it stands",
                run_dir.display(),
                saved.epochs_done,
                match saved.partial.is_some() {
                    true => format!(" and part of epoch {stands_at}"),
                    false => String::new(),
                },
                cfg.epochs
            )));
        }
    }

    let sources = open_sources(cfg)?;
    let classes = sources.main.class_set().clone();
    if classes.len() as i64 != cfg.model.num_classes() {
        return Err(TrainError::Config(format!(
            "the dataset has {} classes but the model is configured for {}",
            classes.len(),
            cfg.model.num_classes()
        )));
    }
    procedure::check_teachers(cfg)?;
    // Which data the run used: its content hash, in config.json (a resume on changed data says so).
    let mut cfg_written = cfg.clone();
    let root = match &cfg.dataset {
        DatasetConfig::Mf { root, .. } | DatasetConfig::Freiburg { root, .. } => root,
    };
    let fingerprint = rtf_data::fingerprint(root)?;
    if let Some(before) = cfg
        .data_fingerprint
        .as_ref()
        .filter(|f| f.hash != fingerprint.hash)
    {
        eprintln!(
            "warning: {} changed since this run started (data hash {} then, {} now)",
            root.display(),
            &before.hash[..12.min(before.hash.len())],
            &fingerprint.hash[..12.min(fingerprint.hash.len())]
        );
    }
    cfg_written.data_fingerprint = Some(fingerprint);
    if world.is_some() {
        cfg_written.world_size = world;
    }
    if is_root {
        rundir::write_json_atomic(&run_dir.join(CONFIG_FILE), &cfg_written)?;
    }

    tch::manual_seed(cfg.seed as i64);
    let mut procedure = procedure::build(cfg, sources.ignore_id, device)?;
    let mut state = TrainState {
        epochs_done: 0,
        steps_done: 0,
        best_val_miou: None,
        partial: None,
        records: Vec::new(),
    };
    if resume {
        let mut trained = procedure.trained_mut();
        let mut parts: Vec<(&str, &mut tch::nn::VarStore)> =
            trained.iter_mut().map(|t| (t.role, &mut t.vs)).collect();
        let (mut optimizers, saved) = checkpoint::load(&checkpoint_path, &mut parts)?;
        drop(parts);
        for t in trained.iter_mut() {
            t.optimizer
                .set_state(optimizers.remove(t.role).unwrap_or_default());
        }
        state = saved;
        if is_root {
            rundir::rewrite_log(run_dir, &state.records)?;
        }
    } else {
        if is_root {
            let _ = std::fs::remove_file(run_dir.join(LOG_FILE));
        }
        let student = &mut procedure.trained_mut()[0].vs;
        if let Some(path) = &cfg.backbone_weights {
            rtf_models::backbone::load_backbone_weights(student, &cfg.model, path)?;
        }
        match &cfg.init_from {
            Some(WeightsRef::File(path)) => rtf_models::weights::load_safetensors(student, path)?,
            Some(WeightsRef::Stage(name)) => {
                return Err(TrainError::Config(format!(
                    "init_from stage `{name}` was not resolved (stage references only work inside a multi-stage run)"
                )))
            }
            None => {}
        }
    }
    if let Some(d) = &ddp {
        // DDP's start: rank 0's weights and BatchNorm statistics on every rank, and every
        // trained network's gradients averaged from now on.
        for t in procedure.trained_mut() {
            d.broadcast_all(&t.vs)?;
            t.ddp = Some(d.clone());
        }
    }
    // Synchronised BatchNorm: the training-mode forwards of this thread (every step runs here)
    // use the whole data-parallel batch's statistics until the run returns.
    let _sync_batch_norm = match &ddp {
        Some(d) if cfg.sync_batch_norm => Some(rtf_models::SyncBatchNorm::install(d.clone())),
        _ => None,
    };
    let input = procedure.student().net.input_convention();
    // Teacher labels written once, if asked: the streams then carry them as labels.
    let mut sources = sources;
    let threshold = match &cfg.procedure {
        crate::config::Procedure::TeacherStudent { targets, .. }
        | crate::config::Procedure::Adversarial { targets, .. } => targets.threshold,
        crate::config::Procedure::Supervised => None,
    };
    let (day_labeller, night_labeller) = procedure.labellers();
    // Label caches of ranks other than 0, removed when the run returns.
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
        // Other ranks than 0 never write the run folder: they label into a folder of their own.
        let dir = match is_root {
            true => run_dir.join("labels").join(name),
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
    let mut tb = match is_root {
        true => Some(
            crate::tensorboard::TbWriter::create(run_dir)
                .map_err(|e| run_error(&run_dir.join("tb"), format!("TensorBoard: {e}")))?,
        ),
        false => None,
    };
    let main = loader(cfg, sources.main.clone(), cfg.seed, input);
    // The night stream has its own order, and cycles when it is the shorter one.
    let night = sources.night.clone().map(|s| {
        loader(
            cfg,
            s,
            rtf_data::loader::mix(cfg.seed, 0x6e69676874, 0),
            input,
        )
    });
    // A data-parallel rank loads only its shard of each stream.
    let (main, main_shard, night, night_shard) = match &ddp {
        None => (main, None, night, None),
        Some(d) => {
            let (main, shard) =
                crate::ddp::shard_loader(main.source().clone(), main.config().clone(), input, d)?;
            let (night, night_shard) = match night {
                Some(n) => {
                    let (l, s) =
                        crate::ddp::shard_loader(n.source().clone(), n.config().clone(), input, d)?;
                    (Some(l), Some(s))
                }
                None => (None, None),
            };
            (main, Some(shard), night, night_shard)
        }
    };
    let select = cfg
        .select_by
        .unwrap_or_else(|| default_select_metric(&cfg.dataset));
    let steps_per_epoch = cfg
        .max_steps_per_epoch
        .map_or(main.num_batches(), |m| m.min(main.num_batches()));
    let mut records = Vec::new();
    // Data-parallel: the stop every rank agreed on at the last step.
    let mut stop_agreed = false;
    for epoch in state.epochs_done..cfg.epochs {
        let lr = cfg.optimizer.lr_at(epoch);
        let bar = match is_root {
            true => progress_bar(steps_per_epoch, epoch, cfg.epochs),
            false => ProgressBar::hidden(),
        };
        // A mid-epoch checkpoint resumes at its batch with the epoch's sums so far.
        let done = state.partial.take().unwrap_or(PartialEpoch {
            batches: 0,
            loss_sum: 0.0,
            images: 0,
            seconds: 0.0,
            wait_seconds: 0.0,
            term_sums: BTreeMap::new(),
        });
        let first = done.batches.min(steps_per_epoch);
        bar.set_position(first as u64);
        // Time of the epoch so far (the part before a resume, if any, plus this process's).
        let (before, started) = (Duration::from_secs_f64(done.seconds), Instant::now());
        let elapsed = || before + started.elapsed();
        let (mut loss_sum, mut images, mut waited, mut term_sums) = (
            done.loss_sum,
            done.images,
            Duration::from_secs_f64(done.wait_seconds),
            done.term_sums,
        );
        if let Some(shard) = &main_shard {
            shard.set_epoch(epoch as u64);
        }
        let batches = main
            .epoch_from(epoch as u64, first)
            .take(steps_per_epoch - first);
        // Night batch g of the run is batch g mod n of night epoch g div n.
        let mut night_batches = night.as_ref().map(|n| {
            let per_epoch = n.num_batches().max(1);
            let global = epoch * steps_per_epoch + first;
            let (start_epoch, start_batch) = (global / per_epoch, global % per_epoch);
            let shard = night_shard.clone();
            (start_epoch..).flat_map(move |e| {
                if let Some(shard) = &shard {
                    shard.set_epoch(e as u64);
                }
                n.epoch_from(e as u64, if e == start_epoch { start_batch } else { 0 })
            })
        });
        for (step, batch) in (first..).zip(batches) {
            // Reseeded per step so a resumed run draws the same random numbers (dropout, ...).
            tch::manual_seed(rtf_data::loader::mix(cfg.seed, epoch as u64, step as u64) as i64);
            let batch = batch?;
            let night_batch = match night_batches.as_mut() {
                Some(it) => Some(
                    it.next()
                        .ok_or_else(|| TrainError::Config("the night stream ended".into()))??,
                ),
                None => None,
            };
            waited += batch.wait + night_batch.as_ref().map_or(Duration::ZERO, |b| b.wait);
            let count = batch.names.len();
            let on_device = |mut b: rtf_data::Batch| {
                b.input = b.input.to_device(device);
                b.target = b.target.to_device(device);
                b
            };
            let batches = StepBatches {
                main: on_device(batch),
                night: night_batch.map(on_device),
            };
            let mut report = procedure.step(&batches, epoch)?;
            // Data-parallel: rank 0's BatchNorm statistics everywhere, and one all-reduce that
            // agrees on stopping and averages the losses to log over every rank's batch.
            let mut interrupted = stop.load(Ordering::Relaxed);
            if let Some(d) = &ddp {
                // A collective that failed (a dead rank, a timeout) stops every rank; rank 0
                // checkpoints where the step left its weights: before it when the gradient
                // all-reduce failed (the update was skipped), after it otherwise.
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
                    Ok(()) => procedure
                        .trained()
                        .iter()
                        .try_for_each(|t| d.broadcast_buffers(&t.vs))
                        .and_then(|_| d.agree(interrupted, &values))
                        .map_err(|e| (e, step + 1)),
                };
                let (any_stop, sums) = match synced {
                    Ok(agreed) => agreed,
                    Err((error, batches)) => {
                        let mut message = format!("{error}; every rank stops");
                        if is_root {
                            let after = batches > step;
                            state.steps_done += after as u64;
                            state.partial = Some(PartialEpoch {
                                batches,
                                loss_sum: loss_sum + if after { report.total } else { 0.0 },
                                images: images + if after { count * world.unwrap_or(1) } else { 0 },
                                seconds: elapsed().as_secs_f64(),
                                wait_seconds: waited.as_secs_f64(),
                                term_sums: term_sums.clone(),
                            });
                            save_checkpoint(&checkpoint_path, procedure.as_ref(), &state, epoch)?;
                            message += &format!(
                                "; rank 0 wrote a checkpoint at epoch {}, batch {batches}: \
                                 continue with `rtf train --resume {}` under torchrun with as \
                                 many processes",
                                epoch + 1,
                                run_dir.display()
                            );
                        }
                        return Err(TrainError::Config(message));
                    }
                };
                interrupted = any_stop;
                stop_agreed = any_stop;
                let n = d.world_size() as f64;
                report.total = sums[0] / n;
                for (key, sum) in keys.iter().zip(&sums[1..]) {
                    if let Some(v) = report.terms.get_mut(key) {
                        *v = sum / n;
                    } else if let Some(v) = report.metrics.get_mut(key) {
                        *v = sum / n;
                    }
                }
            }
            if !report.total.is_finite() {
                return Err(TrainError::Diverged {
                    epoch,
                    step: state.steps_done,
                    what: format!("loss is {}", report.total),
                });
            }
            state.steps_done += 1;
            loss_sum += report.total;
            for (name, value) in report.terms.iter().chain(&report.metrics) {
                *term_sums.entry(name.clone()).or_default() += value;
            }
            images += count * world.unwrap_or(1);
            let rate = images as f64 / elapsed().as_secs_f64().max(1e-9);
            bar.set_message(format!(
                "loss {:.4} | {rate:.1} img/s",
                loss_sum / (step + 1) as f64
            ));
            bar.inc(1);
            let scheduled = cfg
                .checkpoint_every
                .is_some_and(|every| every > 0 && state.steps_done % every as u64 == 0);
            // On an epoch's last step the epoch-end checkpoint below does the work.
            if step + 1 < steps_per_epoch && (interrupted || scheduled) {
                state.partial = Some(PartialEpoch {
                    batches: step + 1,
                    loss_sum,
                    images,
                    seconds: elapsed().as_secs_f64(),
                    wait_seconds: waited.as_secs_f64(),
                    term_sums: term_sums.clone(),
                });
                match is_root {
                    true => save_checkpoint(&checkpoint_path, procedure.as_ref(), &state, epoch)?,
                    false => check_finite(procedure.as_ref(), epoch, state.steps_done)?,
                }
                if interrupted {
                    bar.abandon();
                    return Ok(TrainOutcome {
                        run_dir: run_dir.to_path_buf(),
                        final_weights: None,
                        records,
                        state,
                        weights_digest: None,
                    });
                }
                state.partial = None;
            }
        }
        bar.finish_and_clear();
        let seconds = elapsed().as_secs_f64();
        let val = match &sources.val {
            Some(val) => {
                let options = EvalOptions {
                    batch_size: cfg.batch_size,
                    resize: cfg.resize,
                    workers: cfg.workers,
                };
                let report =
                    rtf_eval::evaluate(&procedure.student().net, val.clone(), &options, device)?;
                Some(val_record(&report, sources.freiburg, select))
            }
            None => None,
        };
        state.epochs_done = epoch + 1;
        let steps = steps_per_epoch.max(1) as f64;
        let (losses, metrics): (BTreeMap<_, _>, BTreeMap<_, _>) = term_sums
            .into_iter()
            .map(|(k, v)| (k, v / steps))
            .partition(|(k, _)| !k.starts_with("critic_acc"));
        let record = EpochRecord {
            epoch,
            lr,
            train_loss: loss_sum / steps,
            images,
            seconds,
            images_per_s: images as f64 / seconds.max(1e-9),
            data_wait_fraction: waited.as_secs_f64() / seconds.max(1e-9),
            val_miou: val.as_ref().map(|v| v.miou),
            val_macc: val.as_ref().map(|v| v.macc),
            losses,
            lrs: procedure
                .trained()
                .iter()
                .map(|t| (t.role.to_string(), t.schedule.lr_at(epoch)))
                .collect(),
            metrics,
            val,
        };
        if let Some(v) = &record.val {
            if state.best_val_miou.is_none_or(|best| v.selected > best) {
                check_finite(procedure.as_ref(), epoch, state.steps_done)?;
                state.best_val_miou = Some(v.selected);
                if is_root {
                    rtf_models::weights::save_safetensors(
                        &procedure.student().trained.vs,
                        &cfg.model,
                        cfg.inputs,
                        &run_dir.join(BEST_FILE),
                    )?;
                }
            }
        }
        state
            .records
            .push(serde_json::to_value(&record).expect("record serialises"));
        if !is_root {
            // Rank 0 writes the checkpoint, the log and TensorBoard.
            check_finite(procedure.as_ref(), epoch, state.steps_done)?;
            records.push(record);
            if stop_agreed && state.epochs_done < cfg.epochs {
                return Ok(TrainOutcome {
                    run_dir: run_dir.to_path_buf(),
                    final_weights: None,
                    records,
                    state,
                    weights_digest: None,
                });
            }
            continue;
        }
        save_checkpoint(&checkpoint_path, procedure.as_ref(), &state, epoch)?;
        rundir::append_log(run_dir, &record)?;
        // TensorBoard: every scalar of the record (loss terms, rates, validation, critic), and
        // every N epochs a prediction grid of validation frames.
        let grid = match (&sources.val, cfg.tb_images_every) {
            (Some(val), Some(every)) if every > 0 && (epoch + 1) % every == 0 => Some(
                prediction_grid_png(procedure.student(), val.as_ref(), cfg, device)?,
            ),
            _ => None,
        };
        let tb = tb.as_mut().expect("rank 0 has its TensorBoard writer");
        let written = tb
            .record(&serde_json::to_value(&record).expect("record serialises"))
            .and_then(|_| match &grid {
                Some(png) => tb.image_png("val/predictions", epoch as i64, png),
                None => Ok(()),
            })
            .and_then(|_| tb.flush());
        if let Err(e) = written {
            return Err(run_error(&run_dir.join("tb"), format!("TensorBoard: {e}")));
        }
        on_epoch(&record);
        records.push(record);
        let stopping = match ddp {
            Some(_) => stop_agreed,
            None => stop.load(Ordering::Relaxed),
        };
        if stopping && state.epochs_done < cfg.epochs {
            // Stopped on an epoch's last step: its checkpoint is the epoch-end one.
            return Ok(TrainOutcome {
                run_dir: run_dir.to_path_buf(),
                final_weights: None,
                records,
                state,
                weights_digest: None,
            });
        }
    }
    let final_weights = run_dir.join(FINAL_FILE);
    let weights_digest = match &ddp {
        Some(d) => Some(d.check_identical(procedure.trained().iter().map(|t| &t.vs))?),
        None => None,
    };
    if is_root {
        rtf_models::weights::save_safetensors(
            &procedure.student().trained.vs,
            &cfg.model,
            cfg.inputs,
            &final_weights,
        )?;
    }
    Ok(TrainOutcome {
        run_dir: run_dir.to_path_buf(),
        final_weights: Some(final_weights),
        records,
        state,
        weights_digest,
    })
}

/// A titled grid (RGB | thermal | truth | prediction) of four validation frames, as PNG.
fn prediction_grid_png(
    student: &procedure::Student,
    val: &dyn FrameSource,
    cfg: &TrainConfig,
    device: tch::Device,
) -> Result<Vec<u8>, TrainError> {
    let rows = rtf_eval::figure::rows_for(&student.net, val, 4, cfg.resize, device)?;
    let column = rtf_eval::figure::PredictionColumn {
        title: cfg.model.name(),
        ids: rows.iter().map(|r| r.prediction.clone()).collect(),
    };
    let grid = rtf_eval::figure::annotated_grid(&rows, &[column], val.class_set());
    let mut png = Vec::new();
    image::DynamicImage::ImageRgb8(grid)
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| TrainError::Config(format!("encoding the prediction grid: {e}")))?;
    Ok(png)
}

/// Refuses to keep weights with a non-finite value (a diverged run would otherwise leave Inf
/// BatchNorm statistics in its checkpoint and best weights).
fn check_finite(procedure: &dyn Procedure, epoch: usize, step: u64) -> Result<(), TrainError> {
    for trained in procedure.trained() {
        for (name, t) in trained.vs.variables() {
            let finite = tch::no_grad(|| t.isfinite().all().int64_value(&[]) != 0);
            if !finite {
                return Err(TrainError::Diverged {
                    epoch,
                    step,
                    what: format!(
                        "`{}` `{name}` holds a non-finite value; the last checkpoint (before this) is kept",
                        trained.role
                    ),
                });
            }
        }
    }
    Ok(())
}

fn save_checkpoint(
    path: &Path,
    procedure: &dyn Procedure,
    state: &TrainState,
    epoch: usize,
) -> Result<(), TrainError> {
    check_finite(procedure, epoch, state.steps_done)?;
    let trained = procedure.trained();
    let parts: Vec<Part> = trained
        .iter()
        .map(|t| Part {
            role: t.role,
            vs: &t.vs,
            optimizer: t.optimizer.state(),
        })
        .collect();
    checkpoint::save(path, &parts, state)?;
    Ok(())
}

fn progress_bar(steps: usize, epoch: usize, epochs: usize) -> ProgressBar {
    let bar = ProgressBar::new(steps as u64);
    let style =
        ProgressStyle::with_template("epoch {prefix} [{bar:30}] {pos}/{len} {msg} ETA {eta}")
            .expect("valid template")
            .progress_chars("=> ");
    bar.set_style(style);
    bar.set_prefix(format!("{}/{}", epoch + 1, epochs));
    bar
}
