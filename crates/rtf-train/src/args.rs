//! `rtf train`'s flags (clap), shared by the command and the Python package's `rtf.train`
//! (which takes the same options by name), so that both take exactly the same options with the
//! same checks. Built with the `cli` feature.

use std::path::PathBuf;

use crate::config::{CriticInput, Precision, SelectMetric};
use crate::launch::Request;
use crate::setup::{NewRun, Overrides, TeacherArg};
use crate::{Modality, OptimizerKind};

#[derive(clap::Args)]
pub struct TrainArgs {
    /// A paper's recipe (`rtf recipes` lists them): procedure, networks, schedule, stages.
    #[arg(long, conflicts_with = "config")]
    pub recipe: Option<String>,
    /// A run configuration (YAML or JSON, the schema of a run folder's config.json).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Network name (see `rtf models`; default mfnet). With a HeatNet recipe: one network for
    /// every role (e.g. a light one on a CPU), the paper's networks otherwise.
    #[arg(long)]
    pub model: Option<String>,
    /// Dataset root (dataset.yaml or the folder holding it, MF, Freiburg Thermal, MSRS,
    /// PST900 or FMB; recognised by its folders). Freiburg: trains on the training tree with
    /// the reference preprocessing and a random 640×320 window, validates on `<root>/val` if
    /// present (never on the test layout).
    #[arg(long, required_unless_present_any = ["resume", "config"], value_parser = rtf_data::dataset::parse_root)]
    pub data: Option<PathBuf>,
    /// Run folder: config.json, log.jsonl, checkpoints, final.safetensors (one sub-folder per
    /// stage for multi-stage recipes).
    #[arg(long, required_unless_present = "resume")]
    pub out: Option<PathBuf>,
    /// Continue the run in this folder exactly where it stopped (its config.json is used).
    /// --epochs extends it, finished or not: a multi-stage run in the stage it continues and
    /// those after it, or its last stage once every stage is done. A finished run with nothing
    /// to do says so and exits 0.
    #[arg(long, conflicts_with_all = ["data", "out", "recipe", "config", "precision", "sync_bn", "init", "no_shuffle", "no_augment"])]
    pub resume: Option<PathBuf>,
    /// The day teacher (HeatNet's RGB teacher): a run folder, or a weights file with
    /// --teacher-model. Without it, recipes train the teacher first.
    #[arg(long)]
    pub teacher: Option<PathBuf>,
    /// Network of a --teacher weights file.
    #[arg(long)]
    pub teacher_model: Option<String>,
    /// Channels the --teacher sees (rgb_t, rgb, thermal; default: its run's, else rgb_t).
    #[arg(long, value_parser = Modality::parse)]
    pub teacher_inputs: Option<Modality>,
    /// The night teacher (two-stage: the thermal teacher; distillation: the RGB-T model).
    #[arg(long)]
    pub night_teacher: Option<PathBuf>,
    #[arg(long)]
    pub night_teacher_model: Option<String>,
    #[arg(long, value_parser = Modality::parse)]
    pub night_teacher_inputs: Option<Modality>,
    /// Channels the trained network sees (rgb_t, rgb, thermal); the others are zeroed.
    #[arg(long, value_parser = Modality::parse)]
    pub inputs: Option<Modality>,
    /// Teacher pixels below this confidence are ignored.
    #[arg(long)]
    pub threshold: Option<f64>,
    /// Learn the teacher's softmax (soft targets) instead of its labels.
    #[arg(long)]
    pub soft: bool,
    /// λ of the adversarial term (HeatNet: 0.01).
    #[arg(long)]
    pub lambda: Option<f64>,
    /// What the critic reads: softmax (paper) or logits (published code).
    #[arg(long, value_parser = parse_critic_input)]
    pub critic_input: Option<CriticInput>,
    /// Also push day outputs toward the night target (published code's --multidir).
    #[arg(long)]
    pub multidir: bool,
    /// Critic steps per segmentation step.
    #[arg(long)]
    pub critic_steps: Option<usize>,
    /// The critic starts from these weights (safetensors, reference names `conv1` …
    /// `classifier`), as --init does for the segmentation network. Recorded in config.json.
    #[arg(long)]
    pub critic_init: Option<PathBuf>,
    /// The published code's critic procedure instead of the paper's: the critic reads logits,
    /// its targets are flipped (day 1, night 0), the segmentation step also keeps day outputs
    /// on the day side, and steps alternate (--critic-steps critic steps, then one
    /// segmentation step, each on its own batches, critic first). For parity runs.
    #[arg(long)]
    pub critic_code: bool,
    /// Validation score that picks best.safetensors: miou, day_night_miou, heatnet_miou,
    /// day_miou, night_miou (default: heatnet_miou on Freiburg, miou on MF).
    #[arg(long, value_parser = parse_select)]
    pub select_by: Option<SelectMetric>,
    /// Number of epochs (MFNet paper: 80; HeatNet: 100 per stage).
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Batch size (MFNet paper: 6; HeatNet: 8).
    #[arg(long)]
    pub batch_size: Option<usize>,
    /// sgd (MFNet paper: lr 0.01, momentum 0.9, weight decay 5e-4, ×0.94 every epoch),
    /// rmsprop (HeatNet paper: lr 1e-4, no momentum or weight decay, ×0.5 every 30 epochs) or
    /// adamw (CMX's training: lr 6e-5, weight decay 0.01 on convolution and linear weights
    /// only, 10 epochs of linear warm-up then poly 0.9 per step); the flags below override
    /// the chosen paper's values.
    #[arg(long, value_parser = OptimizerKind::parse)]
    pub optimizer: Option<OptimizerKind>,
    /// Initial learning rate.
    #[arg(long)]
    pub lr: Option<f64>,
    /// Learning-rate factor applied every --decay-every epochs.
    #[arg(long)]
    pub lr_decay: Option<f64>,
    /// Epochs between learning-rate decays.
    #[arg(long)]
    pub decay_every: Option<usize>,
    /// Epochs of linear warm-up of a warm-up-then-poly schedule (--optimizer adamw,
    /// --recipe cmx-mf: 10).
    #[arg(long)]
    pub warmup_epochs: Option<usize>,
    #[arg(long)]
    pub momentum: Option<f64>,
    #[arg(long)]
    pub weight_decay: Option<f64>,
    /// Disable horizontal-flip augmentation.
    #[arg(long)]
    pub no_flip: bool,
    /// No augmentation at all (no flip, crop, window, rotation, modality drop-out, IR or
    /// brightness scaling, noise): every frame as stored (resized if --resize). Recorded in
    /// config.json.
    #[arg(long)]
    pub no_augment: bool,
    /// Batches in the order of the split list every epoch instead of a new random order
    /// (parity runs against a reference trainer). Recorded in config.json.
    #[arg(long)]
    pub no_shuffle: bool,
    /// Start the network from these weights (safetensors under the reference names, e.g.
    /// `rtf convert` output or another run's final.safetensors) instead of a fresh
    /// initialisation: fine-tuning, parity runs. Every tensor must match the network; the
    /// error names those that do not. Single-stage runs only. Recorded in config.json.
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// With --init: the network's class-dependent tensors (its classifier head) start fresh,
    /// so that weights trained on another class set (e.g. MF's 9 classes) fine-tune onto this
    /// dataset's classes. Every other tensor must still match; stderr lists the tensors that
    /// start fresh. Recorded in config.json.
    #[arg(long, requires = "init")]
    pub reset_head: bool,
    #[arg(long)]
    pub seed: Option<u64>,
    /// MF and described layouts (dataset.yaml, MSRS, PST900, FMB): the training split.
    #[arg(long)]
    pub train_split: Option<String>,
    /// MF: validation split evaluated after every epoch ("none" to skip). Freiburg: "none"
    /// skips the `val` layout. Described layouts: `val` when there is one, else none (said
    /// on stderr); `holdout:N` holds every N-th training frame out for validation; `test`
    /// only when named here (and announced).
    #[arg(long)]
    pub val_split: Option<String>,
    /// Resize frames to WxH (labels nearest) before the network.
    #[arg(long, value_parser = rtf_core::parse_size)]
    pub resize: Option<(usize, usize)>,
    /// Stop each epoch after N steps (quick experiments).
    #[arg(long)]
    pub max_steps: Option<usize>,
    /// Also checkpoint every N steps inside an epoch (long epochs, preemptible machines).
    /// Ctrl-C and SIGTERM always checkpoint the step they stop at.
    #[arg(long)]
    pub checkpoint_every: Option<usize>,
    /// Data-loading threads.
    #[arg(long)]
    pub workers: Option<usize>,
    /// cpu, cuda or cuda:N.
    #[arg(long)]
    pub device: Option<String>,
    /// Arithmetic of the training step: fp32, bf16 or fp16 (CUDA only): autocast mixed
    /// precision over fp32 weights and optimiser state, the loss scaled under fp16. Recorded in
    /// config.json (a resume keeps it).
    #[arg(long, value_parser = Precision::parse)]
    pub precision: Option<Precision>,
    /// Under torchrun: BatchNorm normalises with the statistics of every rank's batch together
    /// (PyTorch's SyncBatchNorm) instead of each rank's own. Recorded in config.json.
    #[arg(long)]
    pub sync_bn: bool,
    /// Every N epochs, a prediction grid of validation frames in TensorBoard (0: never).
    #[arg(long, default_value_t = 5)]
    pub tb_images_every: usize,
    /// Under torchrun (RANK, WORLD_SIZE, MASTER_ADDR, MASTER_PORT set): seconds a collective
    /// may wait for the other ranks before the run stops with an error.
    #[arg(long, default_value_t = 300)]
    pub dist_timeout: u64,
    /// ImageNet ResNet weights (torchvision names, safetensors; see `cargo xtask convert-pth`)
    /// for the encoders of RTFNet and the ResNet-based baselines.
    #[arg(long)]
    pub backbone_weights: Option<PathBuf>,
}

impl TrainArgs {
    /// What the flags ask: a resume, or a new run into `--out`.
    pub fn request(&self) -> Result<Request, rtf_core::Refusal> {
        match (&self.resume, &self.out) {
            (Some(dir), _) => Ok(Request::Resume {
                dir: dir.clone(),
                epochs: self.epochs,
            }),
            (None, Some(out)) => Ok(Request::New {
                run: Box::new(new_run_request(self)),
                out: out.clone(),
            }),
            (None, None) => Err(rtf_core::refused("--out is required")),
        }
    }
}

/// The flags of a new run, typed for rtf_train::setup (which makes its configuration).
fn new_run_request(args: &TrainArgs) -> NewRun {
    let teacher = |path: &Option<PathBuf>, model: &Option<String>, inputs| TeacherArg {
        path: path.clone(),
        model: model.clone(),
        inputs,
    };
    NewRun {
        recipe: args.recipe.clone(),
        config: args.config.clone(),
        data: args.data.clone(),
        train_split: args.train_split.clone(),
        val_split: args.val_split.clone(),
        teacher: teacher(&args.teacher, &args.teacher_model, args.teacher_inputs),
        night_teacher: teacher(
            &args.night_teacher,
            &args.night_teacher_model,
            args.night_teacher_inputs,
        ),
        init: args.init.clone(),
        reset_head: args.reset_head,
        overrides: overrides(args),
    }
}

/// The values given over a recipe's or config's.
fn overrides(args: &TrainArgs) -> Overrides {
    Overrides {
        model: args.model.clone(),
        inputs: args.inputs,
        threshold: args.threshold,
        soft: args.soft,
        lambda: args.lambda,
        critic_input: args.critic_input,
        multidir: args.multidir,
        critic_steps: args.critic_steps,
        critic_init: args.critic_init.clone(),
        critic_code: args.critic_code,
        select_by: args.select_by,
        epochs: args.epochs,
        batch_size: args.batch_size,
        optimizer: args.optimizer,
        lr: args.lr,
        lr_decay: args.lr_decay,
        decay_every: args.decay_every,
        warmup_epochs: args.warmup_epochs,
        momentum: args.momentum,
        weight_decay: args.weight_decay,
        no_flip: args.no_flip,
        no_augment: args.no_augment,
        no_shuffle: args.no_shuffle,
        seed: args.seed,
        resize: args.resize,
        max_steps: args.max_steps,
        checkpoint_every: args.checkpoint_every,
        workers: args.workers,
        device: args.device.clone(),
        precision: args.precision,
        sync_bn: args.sync_bn,
        tb_images_every: args.tb_images_every,
        backbone_weights: args.backbone_weights.clone(),
    }
}

fn parse_critic_input(text: &str) -> Result<CriticInput, String> {
    match text {
        "softmax" => Ok(CriticInput::Softmax),
        "logits" => Ok(CriticInput::Logits),
        other => Err(format!(
            "unknown critic input `{other}` (expected softmax or logits)"
        )),
    }
}

fn parse_select(text: &str) -> Result<SelectMetric, String> {
    serde_json::from_value(serde_json::Value::String(text.to_string())).map_err(|_| {
        format!("unknown metric `{text}` (expected miou, day_night_miou, heatnet_miou, day_miou or night_miou)")
    })
}
