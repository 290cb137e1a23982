use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result};
use rtf_core::ClassSet;
use rtf_data::inspect::DatasetFormat;
use rtf_models::ModelConfig;
use rtf_train::{
    config::available_device, DatasetConfig, OptimizerConfig, OptimizerKind, TrainConfig,
};

use super::parse_size;

#[derive(clap::Args)]
pub struct Args {
    /// Network name (see `rtf models`).
    #[arg(long, default_value = "mfnet")]
    pub model: String,
    /// Dataset root, MF or Freiburg Thermal layout (recognised by its folders). Freiburg:
    /// trains on the labelled frames of the training tree with the reference preprocessing and
    /// a random 640×320 window, validates on the test layout (13 classes).
    #[arg(long, required_unless_present = "resume")]
    pub data: Option<PathBuf>,
    /// Run folder: config.json, log.jsonl, checkpoints, final.safetensors.
    #[arg(long, required_unless_present = "resume")]
    pub out: Option<PathBuf>,
    /// Continue the run in this folder exactly where it stopped (its config.json is used;
    /// --epochs may extend it).
    #[arg(long, conflicts_with_all = ["data", "out"])]
    pub resume: Option<PathBuf>,
    /// Number of epochs (MFNet paper: 80).
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Batch size (MFNet paper: 6).
    #[arg(long, default_value_t = 6)]
    pub batch_size: usize,
    /// sgd (MFNet paper: lr 0.01, momentum 0.9, weight decay 5e-4, ×0.94 every epoch) or
    /// rmsprop (HeatNet paper: lr 1e-4, no momentum or weight decay, ×0.5 every 30 epochs);
    /// the flags below override the chosen paper's values.
    #[arg(long, default_value = "sgd", value_parser = parse_optimizer)]
    pub optimizer: OptimizerKind,
    /// Initial learning rate.
    #[arg(long)]
    pub lr: Option<f64>,
    /// Learning-rate factor applied every --decay-every epochs.
    #[arg(long)]
    pub lr_decay: Option<f64>,
    /// Epochs between learning-rate decays.
    #[arg(long)]
    pub decay_every: Option<usize>,
    #[arg(long)]
    pub momentum: Option<f64>,
    #[arg(long)]
    pub weight_decay: Option<f64>,
    /// Disable horizontal-flip augmentation.
    #[arg(long)]
    pub no_flip: bool,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// MF: the training split.
    #[arg(long, default_value = "train")]
    pub train_split: String,
    /// Validation split evaluated after every epoch ("none" to skip; Freiburg: "none" or the
    /// default, which means its test layout).
    #[arg(long, default_value = "val")]
    pub val_split: String,
    /// Resize frames to WxH (labels nearest) before the network.
    #[arg(long, value_parser = parse_size)]
    pub resize: Option<(usize, usize)>,
    /// Stop each epoch after N steps (quick experiments).
    #[arg(long)]
    pub max_steps: Option<usize>,
    /// Also checkpoint every N steps inside an epoch (long epochs, preemptible machines).
    /// Ctrl-C always checkpoints the step it stops at.
    #[arg(long)]
    pub checkpoint_every: Option<usize>,
    /// Data-loading threads.
    #[arg(long, default_value_t = 2)]
    pub workers: usize,
    /// cpu, cuda or cuda:N.
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// ImageNet ResNet weights (torchvision names, safetensors; see `cargo xtask convert-pth`)
    /// for the encoders of RTFNet and the ResNet-based baselines.
    #[arg(long)]
    pub backbone_weights: Option<PathBuf>,
}

pub fn run(args: Args) -> Result<()> {
    let (cfg, run_dir, resume) = match &args.resume {
        Some(run_dir) => {
            let mut cfg = rtf_train::trainer::read_config(run_dir)?;
            if let Some(epochs) = args.epochs {
                cfg.epochs = epochs;
            }
            (cfg, run_dir.clone(), true)
        }
        None => {
            let data = args.data.clone().context("--data is required")?;
            let out = args.out.clone().context("--out is required")?;
            available_device(&args.device).map_err(anyhow::Error::msg)?;
            let mut cfg = TrainConfig::mfnet_paper(data.clone());
            let validate = args.val_split != "none";
            let (dataset, classes) = match super::segmentation_format(&data, "a training")? {
                DatasetFormat::Mf => (
                    DatasetConfig::Mf {
                        root: data.clone(),
                        train_split: args.train_split.clone(),
                        val_split: validate.then(|| args.val_split.clone()),
                    },
                    ClassSet::mf(),
                ),
                DatasetFormat::Freiburg => {
                    anyhow::ensure!(
                        args.train_split == "train" && ["val", "none"].contains(&args.val_split.as_str()),
                        "{}: a Freiburg Thermal root has no named splits (training tree and test layout); \
                         drop --train-split, and use --val-split only as \"none\"",
                        data.display()
                    );
                    // The reference preprocessing leaves 700×320; HeatNet trains on a random
                    // 640×320 window of it.
                    if args.resize.is_none() {
                        cfg.augment.window = Some((640, 320));
                    }
                    (
                        DatasetConfig::freiburg(data.clone(), validate),
                        ClassSet::freiburg(),
                    )
                }
                other => unreachable!("segmentation_format returned {other:?}"),
            };
            cfg.model = ModelConfig::from_name(&args.model, classes.len() as i64)?;
            cfg.dataset = dataset;
            cfg.epochs = args.epochs.unwrap_or(80);
            cfg.batch_size = args.batch_size;
            cfg.seed = args.seed;
            let paper = match args.optimizer {
                OptimizerKind::Sgd => OptimizerConfig::mfnet_paper(),
                OptimizerKind::Rmsprop => OptimizerConfig::heatnet_paper(),
            };
            cfg.optimizer = OptimizerConfig {
                lr: args.lr.unwrap_or(paper.lr),
                lr_decay: args.lr_decay.unwrap_or(paper.lr_decay),
                decay_every: args.decay_every.unwrap_or(paper.decay_every),
                momentum: args.momentum.unwrap_or(paper.momentum),
                weight_decay: args.weight_decay.unwrap_or(paper.weight_decay),
                ..paper
            };
            anyhow::ensure!(
                cfg.optimizer.decay_every >= 1,
                "--decay-every must be at least 1"
            );
            cfg.augment.hflip = !args.no_flip;
            cfg.resize = args.resize;
            cfg.max_steps_per_epoch = args.max_steps;
            cfg.checkpoint_every = args.checkpoint_every;
            cfg.workers = args.workers;
            cfg.device = args.device.clone();
            cfg.backbone_weights = args.backbone_weights.clone();
            (cfg, out, false)
        }
    };
    eprintln!(
        "training {} for {} epochs into {}",
        cfg.model.name(),
        cfg.epochs,
        run_dir.display()
    );
    let stop = stop_on_ctrl_c();
    let outcome = rtf_train::trainer::train_until(
        &cfg,
        &run_dir,
        resume,
        &mut |r| {
            let val = r
                .val_miou
                .map_or(String::new(), |m| format!("  val mIoU {:.1}", 100.0 * m));
            eprintln!(
                "epoch {:>3}  lr {:.5}  loss {:.4}  {:.1} img/s  data wait {:.0}%{val}",
                r.epoch + 1,
                r.lr,
                r.train_loss,
                r.images_per_s,
                100.0 * r.data_wait_fraction
            );
        },
        stop,
    )?;
    match &outcome.final_weights {
        Some(path) => println!("{}", path.display()),
        None => {
            let batch = outcome.state.partial.as_ref().map_or(0, |p| p.batches);
            eprintln!(
                "interrupted in epoch {} after batch {batch}: checkpoint written; continue with \
                 `rtf train --resume {}`",
                outcome.state.epochs_done + 1,
                run_dir.display()
            );
            std::process::exit(130);
        }
    }
    Ok(())
}

/// Set by the first Ctrl-C; training then checkpoints and stops after the step in flight.
static STOP: AtomicBool = AtomicBool::new(false);

/// Installs a SIGINT handler that sets [`STOP`] (a second Ctrl-C kills as usual).
fn stop_on_ctrl_c() -> &'static AtomicBool {
    #[cfg(unix)]
    {
        extern "C" fn on_sigint(_: libc::c_int) {
            STOP.store(true, Ordering::SeqCst);
            // SAFETY: signal() is async-signal-safe; restores the default for a second Ctrl-C.
            unsafe {
                libc::signal(libc::SIGINT, libc::SIG_DFL);
            }
        }
        // SAFETY: the handler only stores an atomic and calls signal(), both allowed in
        // a signal handler.
        unsafe {
            libc::signal(libc::SIGINT, on_sigint as *const () as libc::sighandler_t);
        }
    }
    &STOP
}

fn parse_optimizer(text: &str) -> Result<OptimizerKind, String> {
    match text {
        "sgd" => Ok(OptimizerKind::Sgd),
        "rmsprop" => Ok(OptimizerKind::Rmsprop),
        other => Err(format!(
            "unknown optimizer `{other}` (expected sgd or rmsprop)"
        )),
    }
}
