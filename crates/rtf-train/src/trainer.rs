//! The supervised training loop. A run folder holds:
//! `config.json` (written before the first step), `log.jsonl` (one record per epoch),
//! `checkpoint.safetensors` (weights + optimiser + state, after every epoch), `best.safetensors`
//! (best validation mIoU) and `final.safetensors` (weights, reference names).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use rtf_data::{
    DataError, FrameSource, FreiburgPart, FreiburgSplit, Loader, LoaderConfig, MfDataset,
};
use rtf_eval::{EvalError, EvalOptions};
use rtf_models::ModelError;
use serde::{Deserialize, Serialize};
use tch::nn::VarStore;

use crate::checkpoint::{self, CheckpointError, PartialEpoch, TrainState};
use crate::config::{DatasetConfig, TrainConfig};
use crate::optim::Optimizer;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("{path}: {message}")]
    Run { path: PathBuf, message: String },
    #[error("{0}")]
    Config(String),
    #[error("training diverged at epoch {epoch}, step {step}: loss is {loss}")]
    Diverged { epoch: usize, step: u64, loss: f64 },
}

/// What one epoch did (a line of `log.jsonl`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochRecord {
    pub epoch: usize,
    pub lr: f64,
    pub train_loss: f64,
    pub images: usize,
    pub seconds: f64,
    pub images_per_s: f64,
    /// Share of the epoch's time spent waiting for the data pipeline.
    pub data_wait_fraction: f64,
    pub val_miou: Option<f64>,
    pub val_macc: Option<f64>,
}

#[derive(Debug, Clone)]
pub struct TrainOutcome {
    pub run_dir: PathBuf,
    /// `final.safetensors`; None when the run was interrupted (its checkpoint holds where it
    /// stopped, `--resume` continues it).
    pub final_weights: Option<PathBuf>,
    pub records: Vec<EpochRecord>,
    pub state: TrainState,
}

pub const CONFIG_FILE: &str = "config.json";
pub const LOG_FILE: &str = "log.jsonl";
pub const CHECKPOINT_FILE: &str = "checkpoint.safetensors";
pub const BEST_FILE: &str = "best.safetensors";
pub const FINAL_FILE: &str = "final.safetensors";

fn run_error(path: &Path, message: impl Into<String>) -> TrainError {
    TrainError::Run {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Reads the configuration of an existing run (for `--resume`).
pub fn read_config(run_dir: &Path) -> Result<TrainConfig, TrainError> {
    let path = run_dir.join(CONFIG_FILE);
    let text = std::fs::read_to_string(&path)
        .map_err(|e| run_error(&path, format!("cannot read: {e}")))?;
    serde_json::from_str(&text).map_err(|e| run_error(&path, format!("not a training config: {e}")))
}

fn write_config(run_dir: &Path, cfg: &TrainConfig) -> Result<(), TrainError> {
    let path = run_dir.join(CONFIG_FILE);
    let json = serde_json::to_string_pretty(cfg).expect("config serialises");
    rtf_core::write_bytes_atomic(&path, json.as_bytes())
        .map_err(|e| run_error(&path, e.to_string()))
}

type Source = Arc<dyn FrameSource>;

/// The training split and, if configured, the validation split.
fn open_split(dataset: &DatasetConfig) -> Result<(Source, Option<Source>), TrainError> {
    match dataset {
        DatasetConfig::Mf {
            root,
            train_split,
            val_split,
        } => {
            let mf = MfDataset::open(root)?;
            let train: Arc<dyn FrameSource> = Arc::new(mf.split(train_split)?);
            let val = match val_split {
                Some(name) => Some(Arc::new(mf.split(name)?) as Arc<dyn FrameSource>),
                None => None,
            };
            Ok((train, val))
        }
        DatasetConfig::Freiburg {
            root,
            train_preprocess,
            val_preprocess,
            validate,
        } => {
            let train = FreiburgSplit::open(root, train_preprocess.clone())?
                .part(FreiburgPart::TrainTree)
                .filter(|_, _, labelled| labelled);
            if train.is_empty() {
                return Err(run_error(
                    root,
                    "no labelled frames in a Freiburg training tree (<run>/<seq>/fl_rgb + fl_rgb_labels)",
                ));
            }
            let val = if *validate {
                Some(
                    FreiburgSplit::open(root, val_preprocess.clone())?
                        .part(FreiburgPart::TestLayout)
                        .filter(|_, _, labelled| labelled),
                )
            } else {
                None
            };
            let val = val
                .filter(|v| !v.is_empty())
                .map(|v| Arc::new(v) as Arc<dyn FrameSource>);
            Ok((Arc::new(train), val))
        }
    }
}

/// Trains `cfg` into `run_dir`. With `resume`, continues from `run_dir/checkpoint.safetensors`
/// (weights, optimiser state, epoch and, for a mid-epoch checkpoint, the batch; data order and
/// augmentation depend only on (seed, epoch), and libtorch's generator is reseeded from (seed,
/// epoch, batch) before every step, so the continuation equals an uninterrupted run).
/// `on_epoch` sees each epoch's record as it is logged.
pub fn train(
    cfg: &TrainConfig,
    run_dir: &Path,
    resume: bool,
    on_epoch: &mut dyn FnMut(&EpochRecord),
) -> Result<TrainOutcome, TrainError> {
    train_until(cfg, run_dir, resume, on_epoch, &AtomicBool::new(false))
}

/// [`train`] that stops cleanly once `stop` is set (e.g. by Ctrl-C): it finishes the step in
/// flight, writes a mid-epoch checkpoint and returns with `final_weights` None.
pub fn train_until(
    cfg: &TrainConfig,
    run_dir: &Path,
    resume: bool,
    on_epoch: &mut dyn FnMut(&EpochRecord),
    stop: &AtomicBool,
) -> Result<TrainOutcome, TrainError> {
    if cfg.batch_size == 0 || cfg.epochs == 0 {
        return Err(TrainError::Config(
            "batch size and epochs must be at least 1".into(),
        ));
    }
    let device = cfg.device().map_err(TrainError::Config)?;
    let checkpoint_path = run_dir.join(CHECKPOINT_FILE);
    if !resume && checkpoint_path.exists() {
        return Err(run_error(
            run_dir,
            "already holds a run; use --resume to continue it or choose another output folder",
        ));
    }
    if resume && !checkpoint_path.exists() {
        return Err(run_error(&checkpoint_path, "no checkpoint to resume from"));
    }
    std::fs::create_dir_all(run_dir)
        .map_err(|e| run_error(run_dir, format!("cannot create: {e}")))?;

    let (train_source, val_source) = open_split(&cfg.dataset)?;
    let classes = train_source.class_set().clone();
    if classes.len() as i64 != cfg.model.num_classes() {
        return Err(TrainError::Config(format!(
            "the dataset has {} classes but the model is configured for {}",
            classes.len(),
            cfg.model.num_classes()
        )));
    }
    write_config(run_dir, cfg)?;

    tch::manual_seed(cfg.seed as i64);
    let mut vs = VarStore::new(device);
    let network = rtf_models::build(&vs.root(), &cfg.model)?;
    let mut optimizer = Optimizer::new(&cfg.optimizer);
    let mut state = TrainState {
        epochs_done: 0,
        steps_done: 0,
        best_val_miou: None,
        partial: None,
    };
    if resume {
        let (optimizer_state, saved) = checkpoint::load(&checkpoint_path, &mut vs)?;
        optimizer.set_state(optimizer_state);
        state = saved;
    } else if let Some(path) = &cfg.backbone_weights {
        rtf_models::backbone::load_backbone_weights(&mut vs, &cfg.model, path)?;
    }
    let loss_fn = cfg.loss.build(classes.ignore_id);
    let loader = Loader::new(
        train_source,
        LoaderConfig {
            batch_size: cfg.batch_size,
            shuffle: true,
            drop_last: false,
            seed: cfg.seed,
            workers: cfg.workers,
            prefetch: 2,
            augment: cfg.augment.clone(),
            resize: cfg.resize,
        },
        network.input_convention(),
    );
    let steps_per_epoch = cfg
        .max_steps_per_epoch
        .map_or(loader.num_batches(), |m| m.min(loader.num_batches()));
    let mut records = Vec::new();
    for epoch in state.epochs_done..cfg.epochs {
        let lr = cfg.optimizer.lr_at(epoch);
        let bar = progress_bar(steps_per_epoch, epoch, cfg.epochs);
        // A mid-epoch checkpoint resumes at its batch with the epoch's sums so far.
        let done = state.partial.take().unwrap_or(PartialEpoch {
            batches: 0,
            loss_sum: 0.0,
            images: 0,
            seconds: 0.0,
            wait_seconds: 0.0,
        });
        let first = done.batches.min(steps_per_epoch);
        bar.set_position(first as u64);
        // Time of the epoch so far (the part before a resume, if any, plus this process's).
        let (before, started) = (Duration::from_secs_f64(done.seconds), Instant::now());
        let elapsed = || before + started.elapsed();
        let (mut loss_sum, mut images, mut waited) = (
            done.loss_sum,
            done.images,
            Duration::from_secs_f64(done.wait_seconds),
        );
        let batches = loader
            .epoch_from(epoch as u64, first)
            .take(steps_per_epoch - first);
        for (step, batch) in (first..).zip(batches) {
            // Reseeded per step so a resumed run draws the same random numbers (dropout, ...).
            tch::manual_seed(rtf_data::loader::mix(cfg.seed, epoch as u64, step as u64) as i64);
            let batch = batch?;
            waited += batch.wait;
            let input = batch.input.to_device(device);
            let target = batch.target.to_device(device);
            let logits = network.forward_t(&input, true);
            let loss = loss_fn.compute(&logits, &target);
            optimizer.zero_grad(&vs);
            loss.backward();
            optimizer.step(&vs, lr);
            let value = f64::try_from(&loss).unwrap_or(f64::NAN);
            if !value.is_finite() {
                return Err(TrainError::Diverged {
                    epoch,
                    step: state.steps_done,
                    loss: value,
                });
            }
            state.steps_done += 1;
            loss_sum += value;
            images += batch.names.len();
            let rate = images as f64 / elapsed().as_secs_f64().max(1e-9);
            bar.set_message(format!(
                "loss {:.4} | {rate:.1} img/s",
                loss_sum / (step + 1) as f64
            ));
            bar.inc(1);
            let interrupted = stop.load(Ordering::Relaxed);
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
                });
                checkpoint::save(&checkpoint_path, &vs, optimizer.state(), &state)?;
                if interrupted {
                    bar.abandon();
                    return Ok(TrainOutcome {
                        run_dir: run_dir.to_path_buf(),
                        final_weights: None,
                        records,
                        state,
                    });
                }
                state.partial = None;
            }
        }
        bar.finish_and_clear();
        let seconds = elapsed().as_secs_f64();
        let (val_miou, val_macc) = match &val_source {
            Some(val) => {
                let options = EvalOptions {
                    batch_size: cfg.batch_size,
                    resize: cfg.resize,
                    workers: cfg.workers,
                };
                let report = rtf_eval::evaluate(network.as_ref(), val.clone(), &options, device)?;
                (Some(report.all.miou), Some(report.all.macc))
            }
            None => (None, None),
        };
        state.epochs_done = epoch + 1;
        if let Some(miou) = val_miou {
            if state.best_val_miou.is_none_or(|best| miou > best) {
                state.best_val_miou = Some(miou);
                rtf_models::weights::save_safetensors(&vs, &cfg.model, &run_dir.join(BEST_FILE))?;
            }
        }
        checkpoint::save(&checkpoint_path, &vs, optimizer.state(), &state)?;
        let record = EpochRecord {
            epoch,
            lr,
            train_loss: loss_sum / steps_per_epoch.max(1) as f64,
            images,
            seconds,
            images_per_s: images as f64 / seconds.max(1e-9),
            data_wait_fraction: waited.as_secs_f64() / seconds.max(1e-9),
            val_miou,
            val_macc,
        };
        append_log(run_dir, &record)?;
        on_epoch(&record);
        records.push(record);
        if stop.load(Ordering::Relaxed) && state.epochs_done < cfg.epochs {
            // Stopped on an epoch's last step: its checkpoint is the epoch-end one.
            return Ok(TrainOutcome {
                run_dir: run_dir.to_path_buf(),
                final_weights: None,
                records,
                state,
            });
        }
    }
    let final_weights = run_dir.join(FINAL_FILE);
    rtf_models::weights::save_safetensors(&vs, &cfg.model, &final_weights)?;
    Ok(TrainOutcome {
        run_dir: run_dir.to_path_buf(),
        final_weights: Some(final_weights),
        records,
        state,
    })
}

fn append_log(run_dir: &Path, record: &EpochRecord) -> Result<(), TrainError> {
    let path = run_dir.join(LOG_FILE);
    let line = serde_json::to_string(record).expect("record serialises");
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .and_then(|mut f| writeln!(f, "{line}"))
        .map_err(|e| run_error(&path, format!("cannot append: {e}")))
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
