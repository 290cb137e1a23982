//! The full, serialisable description of a training run (written to `RUN/config.json`).

use std::path::{Path, PathBuf};

use rtf_data::dataset::{RecordedKind, TrainingChoice};
use rtf_data::{AugmentConfig, FreiburgPreprocess};
use rtf_models::ModelConfig;
use serde::{Deserialize, Serialize};

mod legacy;

/// One training: five sections, one per concern, each its own type (written nested to
/// `config.json`; a flat `config.json` written before the sections existed still reads,
/// see [`legacy`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrainConfig {
    /// The network trained and where its weights start.
    pub network: NetworkConfig,
    /// The frames it learns from and how they are read.
    pub data: DataConfig,
    /// How it learns: procedure, optimiser, loss, arithmetic.
    pub learning: LearningConfig,
    /// How long, in what batches, with which checkpoints and hooks.
    pub schedule: ScheduleConfig,
    /// Where it runs.
    pub compute: ComputeConfig,
}

/// The network trained and where its weights start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkConfig {
    pub model: ModelConfig,
    /// Which input channels the trained network sees (the others are zeroed): RGB-only and
    /// thermal-only variants of any network (HeatNet Tab. II V1, V2; the RGB teacher).
    #[serde(default)]
    pub inputs: Modality,
    /// Weights the network starts from (a stage's fine-tuning: HeatNet's second stage).
    #[serde(default)]
    pub init_from: Option<WeightsRef>,
    /// The class-dependent tensors of the network (its classifier head: those whose shapes
    /// depend on the class count) start fresh instead of from `init_from`, which then may
    /// come from a network of another class set (fine-tuning onto new classes; `rtf train
    /// --reset-head`). Every other tensor still loads strictly. Written only when true.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub init_reset_head: bool,
    /// ImageNet ResNet weights (torchvision names, safetensors) loaded into the encoders before
    /// the first step (RTFNet and the ResNet-based baselines).
    #[serde(default)]
    pub backbone_weights: Option<PathBuf>,
    /// Under data-parallel training, BatchNorm normalises with the statistics of the whole
    /// batch of every rank (`torch.nn.SyncBatchNorm`) instead of each rank's own (DDP's
    /// default). No effect on a single process.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub sync_batch_norm: bool,
}

/// The frames a run learns from and how they are read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    pub dataset: DatasetConfig,
    /// Resize frames to (width, height) for training and validation; None = as stored.
    pub resize: Option<(usize, usize)>,
    pub augment: AugmentConfig,
    /// Batches in a new random order every epoch; false = in the order of the split list
    /// (parity runs against a reference trainer). Written only when false.
    #[serde(default = "yes", skip_serializing_if = "is_yes")]
    pub shuffle: bool,
    /// Decode/augment threads.
    pub workers: usize,
    /// Content hash of the dataset (`rtf data fingerprint`), recorded when the run starts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fingerprint: Option<rtf_data::Fingerprint>,
}

/// How a network learns.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LearningConfig {
    /// The procedure (HeatNet §III-A): supervised, teacher-student or adversarial.
    #[serde(default)]
    pub procedure: Procedure,
    pub optimizer: OptimizerConfig,
    pub loss: LossConfig,
    /// Arithmetic of the training step: fp32, or autocast mixed precision (bf16; fp16 on CUDA,
    /// with loss scaling) over fp32 master weights and optimiser state.
    #[serde(default)]
    pub precision: Precision,
}

/// How long a run trains, in what batches, and what it saves and shows along the way.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduleConfig {
    pub epochs: usize,
    pub batch_size: usize,
    pub seed: u64,
    /// Stop each epoch after this many steps (quick experiments); None = full epochs.
    pub max_steps_per_epoch: Option<usize>,
    /// Also write the checkpoint every this many steps inside an epoch (long epochs,
    /// preemptible machines); None = at the end of each epoch only.
    #[serde(default)]
    pub checkpoint_every: Option<usize>,
    /// The validation score that picks `best.safetensors`; None = the dataset's usual one
    /// (HeatNet's day/night mIoU on Freiburg, mIoU on MF).
    #[serde(default)]
    pub select_by: Option<SelectMetric>,
    /// Every this many epochs a prediction grid of validation frames goes to TensorBoard
    /// (`val/predictions`); None or 0 = never.
    #[serde(default)]
    pub tb_images_every: Option<usize>,
}

/// Where a run computes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ComputeConfig {
    /// "cpu", "cuda" or "cuda:N".
    pub device: String,
    /// Processes of a data-parallel run (`torchrun`), recorded by rank 0 when the run starts; a
    /// resume needs as many. None = a single-process run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub world_size: Option<usize>,
    /// bf16 on the CPU: which convolution kernels the run started with
    /// ([`rtf_amp::Bf16Convolutions`], chosen by measurement where the CPU has bf16 arithmetic
    /// and `RTF_BF16_CONVOLUTIONS` is unset), recorded so that a resume computes the same
    /// numbers (a `--config` may set it). None = not recorded (fp32, another device, or a run
    /// before the record).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bf16_convolutions: Option<rtf_amp::Bf16Convolutions>,
    /// fp32 stages: the layout of the feature maps the run started with
    /// ([`Fp32Layout`]; chosen by the caller, `RTF_TRAIN_LAYOUT` for rtf's binaries, else the
    /// faster on the device), recorded so that a resume computes the same sums. None = not
    /// recorded ([`Fp32Layout::faster_on`] the device then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fp32_layout: Option<Fp32Layout>,
}

/// How fp32 training lays out its feature maps. Convolutional networks only: CMX (attention)
/// keeps NCHW.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fp32Layout {
    Nchw,
    ChannelsLast,
}

impl Fp32Layout {
    /// The layout fp32 training measured faster in on `device`: channels-last on CUDA (cuDNN's
    /// TF32 convolutions are laid out for NHWC; docs/src/gpu.md) and on CPUs with AVX-512
    /// (`avx512f`: oneDNN's fp32 training kernels take channels-last operands without
    /// reorders); NCHW on CPUs without (docs/src/benchmarks.md).
    pub fn faster_on(device: tch::Device) -> Self {
        let avx512 = || {
            rtf_core::host::CpuInfo::read()
                .flags
                .iter()
                .any(|f| f == "avx512f")
        };
        match device {
            tch::Device::Cpu if !avx512() => Fp32Layout::Nchw,
            _ => Fp32Layout::ChannelsLast,
        }
    }

    /// A layout as users name it: `nchw`, or `nhwc` / `channels_last`; `auto` (or nothing)
    /// leaves the choice open (None).
    pub fn parse(text: &str) -> Result<Option<Self>, String> {
        match text.trim() {
            "" | "auto" => Ok(None),
            "nchw" => Ok(Some(Fp32Layout::Nchw)),
            "nhwc" | "channels_last" => Ok(Some(Fp32Layout::ChannelsLast)),
            other => Err(format!(
                "unknown training layout `{other}` (expected nchw, nhwc or auto)"
            )),
        }
    }
}

/// The sections as they are read: every one required, no other key.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Sections {
    network: NetworkConfig,
    data: DataConfig,
    learning: LearningConfig,
    schedule: ScheduleConfig,
    compute: ComputeConfig,
}

/// The keys of [`TrainConfig`]'s sections.
pub const SECTIONS: [&str; 5] = ["network", "data", "learning", "schedule", "compute"];

/// Reads the sections, or the flat layout written before them (a document without any section
/// key). Unknown keys are refused in both.
impl<'de> Deserialize<'de> for TrainConfig {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let value = serde_json::Value::deserialize(d)?;
        if !SECTIONS.iter().any(|key| value.get(key).is_some()) {
            return serde_json::from_value::<legacy::LegacyFlatConfig>(value)
                .map(Into::into)
                .map_err(D::Error::custom);
        }
        let s: Sections = serde_json::from_value(value).map_err(D::Error::custom)?;
        Ok(TrainConfig {
            network: s.network,
            data: s.data,
            learning: s.learning,
            schedule: s.schedule,
            compute: s.compute,
        })
    }
}

/// Which input channels a network sees (defined beside the networks, and recorded in their
/// weights files, so that evaluation applies the same mask).
pub use rtf_models::Modality;

/// The arithmetic of a training step (PyTorch's automatic mixed precision; defined in rtf-amp,
/// one type with the fast inference path's).
pub use rtf_amp::Precision;

/// How a network learns.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Procedure {
    /// Cross-entropy on the dataset's labels (MFNet, RTFNet; the RGB teacher on labelled days).
    #[default]
    Supervised,
    /// HeatNet eq. 1: the student learns from a frozen teacher's labels of day frames and,
    /// with a night teacher, from its labels of night frames (stage 1 of two-stage training;
    /// the thermal teacher; RGB-T → RGB distillation). No dataset label is read.
    TeacherStudent {
        day_teacher: TeacherRef,
        #[serde(default)]
        night_teacher: Option<TeacherRef>,
        #[serde(default)]
        targets: TargetOptions,
    },
    /// HeatNet eq. 2–3: teacher labels by day plus a day/night critic on the student's night
    /// outputs, alternating critic and segmentation steps. No dataset label is read.
    Adversarial {
        day_teacher: TeacherRef,
        /// The published code's best configuration also keeps a night teacher, whose
        /// confidence weights its cross-entropy and the adversarial term per pixel.
        #[serde(default)]
        night_teacher: Option<TeacherRef>,
        #[serde(default)]
        targets: TargetOptions,
        #[serde(default)]
        critic: CriticOptions,
    },
}

impl Procedure {
    pub fn name(&self) -> &'static str {
        match self {
            Procedure::Supervised => "supervised",
            Procedure::TeacherStudent { .. } => "teacher_student",
            Procedure::Adversarial { .. } => "adversarial",
        }
    }

    /// Whether the procedure reads the dataset's training labels.
    pub fn reads_labels(&self) -> bool {
        matches!(self, Procedure::Supervised)
    }

    /// Whether the procedure needs a stream of night frames.
    pub fn uses_night(&self) -> bool {
        match self {
            Procedure::Supervised => false,
            Procedure::TeacherStudent { night_teacher, .. } => night_teacher.is_some(),
            Procedure::Adversarial { .. } => true,
        }
    }

    /// Every teacher the procedure names.
    pub fn teachers(&self) -> Vec<&TeacherRef> {
        match self {
            Procedure::Supervised => vec![],
            Procedure::TeacherStudent {
                day_teacher,
                night_teacher,
                ..
            }
            | Procedure::Adversarial {
                day_teacher,
                night_teacher,
                ..
            } => std::iter::once(day_teacher)
                .chain(night_teacher.as_ref())
                .collect(),
        }
    }

    pub(crate) fn teachers_mut(&mut self) -> Vec<&mut TeacherRef> {
        match self {
            Procedure::Supervised => vec![],
            Procedure::TeacherStudent {
                day_teacher,
                night_teacher,
                ..
            }
            | Procedure::Adversarial {
                day_teacher,
                night_teacher,
                ..
            } => std::iter::once(day_teacher)
                .chain(night_teacher.as_mut())
                .collect(),
        }
    }
}

/// A frozen network that labels frames: an earlier stage of the same run, or a weights file
/// with the network it belongs to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum TeacherRef {
    /// The selected (best, else final) weights of an earlier stage, by stage name.
    Stage(String),
    Weights {
        path: PathBuf,
        model: ModelConfig,
        #[serde(default)]
        inputs: Modality,
    },
}

/// Weights a network starts from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum WeightsRef {
    /// The final weights of an earlier stage, by stage name.
    Stage(String),
    File(PathBuf),
}

/// How a teacher's output becomes the student's target.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetOptions {
    /// Pixels whose teacher confidence (max softmax) is below this are ignored.
    #[serde(default)]
    pub threshold: Option<f64>,
    /// Learn the teacher's softmax (soft cross-entropy) instead of its arg-max.
    #[serde(default)]
    pub soft: bool,
    /// Label every frame once (un-augmented, at its own size) into `RUN/labels/`, then train on
    /// those labels augmented with the frames, instead of running the teacher every step.
    #[serde(default)]
    pub cache: bool,
}

/// What the critic reads (paper: the softmax; published code: raw logits).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CriticInput {
    #[default]
    Softmax,
    Logits,
}

/// The critic and the adversarial term (HeatNet eq. 2–3, spec §5).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CriticOptions {
    /// λ of eq. 3 (paper: 0.01).
    #[serde(default = "lambda_paper")]
    pub lambda: f64,
    #[serde(default)]
    pub input: CriticInput,
    /// Published code's `--multidir`: a second term pushes day outputs toward the night target.
    #[serde(default)]
    pub multidir: bool,
    /// Weight the adversarial term per pixel by (1 − night-teacher confidence) (published
    /// code; needs a night teacher).
    #[serde(default)]
    pub confidence_weighting: bool,
    /// Critic steps per segmentation step (paper: 1).
    #[serde(default = "one")]
    pub steps: usize,
    /// The critic's own optimiser (paper: RMSprop 1e-4, halved every 30 epochs).
    #[serde(default = "OptimizerConfig::heatnet_paper")]
    pub optimizer: OptimizerConfig,
    /// The critic starts from these weights (safetensors under the reference names `conv1`
    /// … `classifier`; parity runs) instead of a fresh initialisation.
    #[serde(default)]
    pub init: Option<PathBuf>,
    /// Published code: the critic's targets flipped (day → 1, night → 0; paper: day → 0,
    /// night → 1).
    #[serde(default)]
    pub flip_targets: bool,
    /// Published code: the segmentation step also scores the day outputs, pushing them toward
    /// the day target (toward the night target with `multidir`).
    #[serde(default)]
    pub day_term: bool,
    /// Published code's alternation: each step is either critic steps or one segmentation
    /// step, each on its own batches and its own forward pass, the critic's first (`steps`
    /// critic steps, then one segmentation step, and again). Paper (false): every step is a
    /// segmentation step followed by `steps` critic steps on the same batches' outputs.
    #[serde(default)]
    pub alternate: bool,
}

fn lambda_paper() -> f64 {
    0.01
}

impl Default for CriticOptions {
    fn default() -> Self {
        Self {
            lambda: lambda_paper(),
            input: CriticInput::default(),
            multidir: false,
            confidence_weighting: false,
            steps: 1,
            optimizer: OptimizerConfig::heatnet_paper(),
            init: None,
            flip_targets: false,
            day_term: false,
            alternate: false,
        }
    }
}

/// The validation score that picks `best.safetensors`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SelectMetric {
    /// mIoU over all validation frames (RTFNet convention).
    Miou,
    /// Mean of the day and night mIoU (RTFNet convention each).
    DayNightMiou,
    /// HeatNet's convention (classes 0–11, undefined skipped), mean of day and night.
    HeatnetMiou,
    DayMiou,
    NightMiou,
}

impl SelectMetric {
    pub fn name(self) -> &'static str {
        match self {
            SelectMetric::Miou => "miou",
            SelectMetric::DayNightMiou => "day_night_miou",
            SelectMetric::HeatnetMiou => "heatnet_miou",
            SelectMetric::DayMiou => "day_miou",
            SelectMetric::NightMiou => "night_miou",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "format", rename_all = "snake_case")]
pub enum DatasetConfig {
    /// MF layout (spec §1).
    Mf {
        root: PathBuf,
        train_split: String,
        val_split: Option<String>,
    },
    /// Freiburg Thermal (spec §5), supervised: trains on the labelled frames of the training
    /// tree under `root`, validates on the test layout under `root` (if any), each with its
    /// own preprocessing (reference: 960×320, columns 150..850 / 148..852, IR clip).
    Freiburg {
        root: PathBuf,
        #[serde(default = "FreiburgPreprocess::reference_train")]
        train_preprocess: FreiburgPreprocess,
        #[serde(default = "FreiburgPreprocess::reference_test")]
        val_preprocess: FreiburgPreprocess,
        /// Evaluate the test layout after every epoch.
        #[serde(default = "yes")]
        validate: bool,
    },
    /// A root read through a dataset description (rtf_data::layouts): `root/dataset.yaml`
    /// (the plain layout) or a recognised MSRS, PST900 or FMB root. Its class set decides the
    /// network's number of outputs.
    Described {
        root: PathBuf,
        train_split: String,
        /// None: no validation (the public sets ship only train and test).
        val_split: Option<String>,
        /// The class set and thermal rule read when the run started (`rtf train` records
        /// them; the weights carry them too): a resume refuses a root whose classes changed.
        /// None in configs written before it was recorded.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        trained_on: Option<rtf_data::TrainedOn>,
    },
}

pub(crate) fn yes() -> bool {
    true
}

pub(crate) fn is_yes(value: &bool) -> bool {
    *value
}

impl DatasetConfig {
    /// A Freiburg Thermal root with the reference preprocessing.
    pub fn freiburg(root: PathBuf, validate: bool) -> Self {
        DatasetConfig::Freiburg {
            root,
            train_preprocess: FreiburgPreprocess::reference_train(),
            val_preprocess: FreiburgPreprocess::reference_test(),
            validate,
        }
    }

    /// The dataset root the run reads.
    pub fn root(&self) -> &Path {
        match self {
            DatasetConfig::Mf { root, .. }
            | DatasetConfig::Freiburg { root, .. }
            | DatasetConfig::Described { root, .. } => root,
        }
    }

    /// The frames the run reads, for rtf-data to open ([`rtf_data::dataset::TrainingChoice`]):
    /// the recorded kind of root, the splits and Freiburg's preprocessing, field by field.
    pub fn choice(&self) -> TrainingChoice {
        let reference = || {
            (
                FreiburgPreprocess::reference_train(),
                FreiburgPreprocess::reference_test(),
            )
        };
        match self {
            DatasetConfig::Mf {
                train_split,
                val_split,
                ..
            } => TrainingChoice {
                kind: RecordedKind::Mf,
                train_split: train_split.clone(),
                val_split: val_split.clone(),
                preprocess: reference(),
            },
            DatasetConfig::Freiburg {
                train_preprocess,
                val_preprocess,
                validate,
                ..
            } => TrainingChoice {
                kind: RecordedKind::Freiburg,
                train_split: "train".into(),
                val_split: validate.then(|| "val".into()),
                preprocess: (train_preprocess.clone(), val_preprocess.clone()),
            },
            DatasetConfig::Described {
                train_split,
                val_split,
                ..
            } => TrainingChoice {
                kind: RecordedKind::Described,
                train_split: train_split.clone(),
                val_split: val_split.clone(),
                preprocess: reference(),
            },
        }
    }

    /// The class set and thermal rule recorded when the run started (described roots).
    pub fn recorded(&self) -> Option<&rtf_data::TrainedOn> {
        match self {
            DatasetConfig::Described { trained_on, .. } => trained_on.as_ref(),
            _ => None,
        }
    }
}

/// Which update rule [`crate::optim::Optimizer`] applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OptimizerKind {
    /// SGD with momentum (MFNet, RTFNet).
    #[default]
    Sgd,
    /// RMSprop (HeatNet).
    Rmsprop,
    /// AdamW (CMX): Adam with weight decay decoupled from the gradient.
    Adamw,
}

impl OptimizerKind {
    /// `sgd`, `rmsprop` or `adamw` (command-line flags).
    pub fn parse(text: &str) -> Result<Self, String> {
        match text {
            "sgd" => Ok(OptimizerKind::Sgd),
            "rmsprop" => Ok(OptimizerKind::Rmsprop),
            "adamw" => Ok(OptimizerKind::Adamw),
            other => Err(format!(
                "unknown optimizer `{other}` (expected sgd, rmsprop or adamw)"
            )),
        }
    }
}

/// Which trainable tensors weight decay applies to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DecayScope {
    /// Every trainable tensor (PyTorch's optimisers given `model.parameters()`).
    #[default]
    All,
    /// Convolution and linear weights only, none on normalisation layers' weights nor on any
    /// bias (CMX: `utils/init_func.py` `group_weight`, whose no-decay group holds the biases
    /// and every BatchNorm/LayerNorm/GroupNorm parameter). Decided by shape: a tensor decays
    /// when it has two or more dimensions. Convolution and linear weights are the only such
    /// trainable tensors of rtf's networks; norm weights and biases are 1-D.
    ConvAndLinearWeights,
}

impl DecayScope {
    pub fn is_all(&self) -> bool {
        *self == DecayScope::All
    }

    /// Whether weight decay applies to `param`.
    pub fn decays(self, param: &tch::Tensor) -> bool {
        match self {
            DecayScope::All => true,
            DecayScope::ConvAndLinearWeights => param.dim() >= 2,
        }
    }
}

/// Optimiser and learning-rate schedule. With the default [`LrSchedule::StepDecay`] the rate is
/// multiplied by `lr_decay` every `decay_every` epochs (MFNet: ×0.94 every epoch; HeatNet: ×0.5
/// every 30). SGD reads `momentum`; RMSprop `momentum`, `alpha`, `eps`; AdamW `betas`, `eps`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizerConfig {
    #[serde(default)]
    pub kind: OptimizerKind,
    pub lr: f64,
    pub momentum: f64,
    pub weight_decay: f64,
    pub lr_decay: f64,
    #[serde(default = "one")]
    pub decay_every: usize,
    /// RMSprop's smoothing constant (PyTorch: 0.99).
    #[serde(default = "rmsprop_alpha")]
    pub alpha: f64,
    /// RMSprop's and AdamW's denominator term (PyTorch: 1e-8 both).
    #[serde(default = "rmsprop_eps")]
    pub eps: f64,
    /// AdamW's (β1, β2) (PyTorch's and CMX's: 0.9, 0.999). Written only when not those.
    #[serde(default = "adam_betas", skip_serializing_if = "is_adam_betas")]
    pub betas: (f64, f64),
    /// Which tensors `weight_decay` applies to. Written only when not all.
    #[serde(default, skip_serializing_if = "DecayScope::is_all")]
    pub decay_scope: DecayScope,
    /// The learning-rate schedule. Written only when not the per-epoch step decay.
    #[serde(default, skip_serializing_if = "LrSchedule::is_step_decay")]
    pub schedule: LrSchedule,
}

pub use crate::schedule::{LrSchedule, StepAt};

fn one() -> usize {
    1
}
fn rmsprop_alpha() -> f64 {
    0.99
}
fn rmsprop_eps() -> f64 {
    1e-8
}
fn adam_betas() -> (f64, f64) {
    (0.9, 0.999)
}
fn is_adam_betas(betas: &(f64, f64)) -> bool {
    *betas == adam_betas()
}

impl OptimizerConfig {
    /// MFNet paper: SGD, lr 0.01, momentum 0.9, weight decay 5e-4, ×0.94 per epoch.
    pub fn mfnet_paper() -> Self {
        Self {
            kind: OptimizerKind::Sgd,
            lr: 0.01,
            momentum: 0.9,
            weight_decay: 5e-4,
            lr_decay: 0.94,
            decay_every: 1,
            alpha: rmsprop_alpha(),
            eps: rmsprop_eps(),
            betas: adam_betas(),
            decay_scope: DecayScope::All,
            schedule: LrSchedule::StepDecay,
        }
    }

    /// HeatNet paper (spec §5): RMSprop, lr 1e-4, halved every 30 epochs; PyTorch's RMSprop
    /// defaults otherwise (no momentum, no weight decay).
    pub fn heatnet_paper() -> Self {
        Self {
            kind: OptimizerKind::Rmsprop,
            lr: 1e-4,
            momentum: 0.0,
            weight_decay: 0.0,
            lr_decay: 0.5,
            decay_every: 30,
            ..Self::mfnet_paper()
        }
    }

    /// CMX's official training (huaaaliu/RGBX_Semantic_Segmentation: `config.py`, `train.py`,
    /// `utils/init_func.py` `group_weight`): AdamW, lr 6e-5, betas (0.9, 0.999), eps 1e-8,
    /// weight decay 0.01 on convolution and linear weights only, linear warm-up over 10 epochs
    /// then poly decay with power 0.9 per step. `momentum`, `lr_decay` and `decay_every` are
    /// not read (0, 1, 1).
    pub fn cmx_code() -> Self {
        Self {
            kind: OptimizerKind::Adamw,
            lr: 6e-5,
            momentum: 0.0,
            weight_decay: 0.01,
            lr_decay: 1.0,
            decay_every: 1,
            decay_scope: DecayScope::ConvAndLinearWeights,
            schedule: LrSchedule::cmx_code(),
            ..Self::mfnet_paper()
        }
    }

    /// The paper's optimiser and schedule of a kind: SGD → MFNet's, RMSprop → HeatNet's, AdamW
    /// → CMX's.
    pub fn paper_default(kind: OptimizerKind) -> Self {
        match kind {
            OptimizerKind::Sgd => Self::mfnet_paper(),
            OptimizerKind::Rmsprop => Self::heatnet_paper(),
            OptimizerKind::Adamw => Self::cmx_code(),
        }
    }

    /// Learning rate of the step `at` ([`LrSchedule`]).
    pub fn lr_at(&self, at: StepAt) -> f64 {
        match self.schedule {
            LrSchedule::StepDecay => {
                let decays = at.epoch / self.decay_every.max(1);
                self.lr * self.lr_decay.powi(decays as i32)
            }
            LrSchedule::WarmupPoly {
                power,
                warmup_epochs,
            } => crate::schedule::warmup_poly(
                self.lr,
                power,
                warmup_epochs * at.steps_per_epoch,
                at.total(),
                at.global(),
            ),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum LossConfig {
    /// Pixel-wise cross-entropy over all classes; the class set's ignore id is skipped.
    CrossEntropy { class_weights: Option<Vec<f64>> },
}

/// A run of several stages, each an ordinary run folder `RUN/<name>/` (HeatNet's teachers,
/// two-stage training, distillation). A later stage names earlier ones as teachers or as
/// its starting weights; a resumed run skips finished stages.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PipelineConfig {
    /// The recipe it was made from, if any (`rtf recipes`).
    #[serde(default)]
    pub recipe: Option<String>,
    pub stages: Vec<StageConfig>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageConfig {
    /// Folder name under the run folder (letters, digits, `-`, `_`).
    pub name: String,
    pub config: TrainConfig,
}

/// What a run folder's `config.json` holds: one training, or a pipeline of stages.
#[derive(Debug, Clone, PartialEq)]
pub enum RunConfig {
    Single(Box<TrainConfig>),
    Pipeline(PipelineConfig),
}

impl Serialize for RunConfig {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            RunConfig::Single(c) => c.serialize(s),
            RunConfig::Pipeline(p) => p.serialize(s),
        }
    }
}

impl RunConfig {
    /// Parses JSON or YAML text; a document with `stages` is a pipeline. Errors name the field.
    pub fn parse(text: &str, yaml: bool) -> Result<Self, String> {
        let value: serde_json::Value = if yaml {
            serde_yaml_ng::from_str(text).map_err(|e| e.to_string())?
        } else {
            serde_json::from_str(text).map_err(|e| e.to_string())?
        };
        let is_pipeline = value.get("stages").is_some();
        if is_pipeline {
            serde_json::from_value(value)
                .map(RunConfig::Pipeline)
                .map_err(|e| e.to_string())
        } else {
            serde_json::from_value(value)
                .map(|c| RunConfig::Single(Box::new(c)))
                .map_err(|e| e.to_string())
        }
    }

    /// Every stage with its name (a single training is one stage named "").
    pub fn stages(&self) -> Vec<(&str, &TrainConfig)> {
        match self {
            RunConfig::Single(c) => vec![("", c)],
            RunConfig::Pipeline(p) => p
                .stages
                .iter()
                .map(|s| (s.name.as_str(), &s.config))
                .collect(),
        }
    }

    pub fn stages_mut(&mut self) -> Vec<&mut TrainConfig> {
        match self {
            RunConfig::Single(c) => vec![c],
            RunConfig::Pipeline(p) => p.stages.iter_mut().map(|s| &mut s.config).collect(),
        }
    }

    /// The network the run ends with (the last stage's).
    pub fn final_model(&self) -> &ModelConfig {
        &self
            .stages()
            .last()
            .expect("a run has a stage")
            .1
            .network
            .model
    }

    /// Every check of [`TrainConfig::validate`] per stage, plus stage names and references
    /// (a stage names only earlier stages).
    pub fn validate(&self) -> Result<(), ConfigError> {
        let stages = self.stages();
        if stages.is_empty() {
            return Err(ConfigError::field(
                "stages",
                "a pipeline needs at least one stage",
            ));
        }
        for (i, (name, cfg)) in stages.iter().enumerate() {
            let at = |field: &str| match name.is_empty() {
                true => field.to_string(),
                false => format!("stages[{i}] ({name}).{field}"),
            };
            if let RunConfig::Pipeline(_) = self {
                let ok = !name.is_empty()
                    && name
                        .chars()
                        .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
                if !ok {
                    return Err(ConfigError::field(
                        &at("name"),
                        "a stage name is letters, digits, '-' or '_'",
                    ));
                }
                if stages[..i].iter().any(|(n, _)| n == name) {
                    return Err(ConfigError::field(
                        &at("name"),
                        "two stages share this name",
                    ));
                }
            }
            cfg.validate().map_err(|e| ConfigError {
                field: at(&e.field),
                message: e.message,
            })?;
            let earlier: Vec<&str> = stages[..i].iter().map(|(n, _)| *n).collect();
            let check_stage = |field: &str, stage: &str| {
                if earlier.contains(&stage) {
                    Ok(())
                } else {
                    Err(ConfigError::field(
                        &at(field),
                        &format!(
                            "names stage `{stage}`, which is not an earlier stage of this run (earlier: {})",
                            if earlier.is_empty() { "none".to_string() } else { earlier.join(", ") }
                        ),
                    ))
                }
            };
            for teacher in cfg.learning.procedure.teachers() {
                if let TeacherRef::Stage(stage) = teacher {
                    check_stage("learning.procedure (teacher)", stage)?;
                }
            }
            if let Some(WeightsRef::Stage(stage)) = &cfg.network.init_from {
                check_stage("network.init_from", stage)?;
            }
        }
        Ok(())
    }
}

/// A configuration value that cannot work, with the field it is in.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct ConfigError {
    pub field: String,
    pub message: String,
}

impl ConfigError {
    pub fn field(field: &str, message: &str) -> Self {
        Self {
            field: field.to_string(),
            message: message.to_string(),
        }
    }
}

impl OptimizerConfig {
    /// Values the update rules can work with; `prefix` names the field in errors.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        let bad = |field: &str, message: String| {
            Err(ConfigError {
                field: format!("{prefix}.{field}"),
                message,
            })
        };
        if !(self.lr.is_finite() && self.lr > 0.0) {
            return bad("lr", format!("must be a positive number, got {}", self.lr));
        }
        if !(self.momentum.is_finite() && (0.0..1.0).contains(&self.momentum)) {
            return bad(
                "momentum",
                format!("must be in [0, 1), got {}", self.momentum),
            );
        }
        if !(self.weight_decay.is_finite() && self.weight_decay >= 0.0) {
            return bad(
                "weight_decay",
                format!("must be ≥ 0, got {}", self.weight_decay),
            );
        }
        if !(self.lr_decay.is_finite() && self.lr_decay > 0.0 && self.lr_decay <= 1.0) {
            return bad(
                "lr_decay",
                format!("must be in (0, 1], got {}", self.lr_decay),
            );
        }
        if self.decay_every == 0 {
            return bad("decay_every", "must be at least 1".into());
        }
        if !(self.alpha.is_finite() && self.alpha > 0.0 && self.alpha < 1.0) {
            return bad("alpha", format!("must be in (0, 1), got {}", self.alpha));
        }
        if !(self.eps.is_finite() && self.eps > 0.0) {
            return bad("eps", format!("must be > 0, got {}", self.eps));
        }
        self.validate_adamw_and_schedule(prefix)
    }

    /// The AdamW betas and the warm-up-poly power.
    fn validate_adamw_and_schedule(&self, prefix: &str) -> Result<(), ConfigError> {
        let (b1, b2) = self.betas;
        if ![b1, b2]
            .iter()
            .all(|b| b.is_finite() && (0.0..1.0).contains(b))
        {
            return Err(ConfigError {
                field: format!("{prefix}.betas"),
                message: format!("must both be in [0, 1), got ({b1}, {b2})"),
            });
        }
        match self.schedule {
            LrSchedule::WarmupPoly { power, .. } if !(power.is_finite() && power > 0.0) => {
                Err(ConfigError {
                    field: format!("{prefix}.schedule.power"),
                    message: format!("must be > 0, got {power}"),
                })
            }
            _ => Ok(()),
        }
    }
}

impl TrainConfig {
    /// Every value checked in one place: flags, `--config` files and edited `config.json`s of
    /// resumed runs all pass here before anything is written. Errors name the field by its
    /// path in the sections (`schedule.epochs`).
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.schedule.validate()?;
        if let Some((w, h)) = self.data.resize {
            if w == 0 || h == 0 {
                return Err(ConfigError::field(
                    "data.resize",
                    "width and height must be ≥ 1",
                ));
            }
        }
        let device = parse_device(&self.compute.device)
            .map_err(|m| ConfigError::field("compute.device", &m))?;
        self.learning
            .validate(device, self.network.model.num_classes())
    }

    /// MFNet paper's recipe on an MF-layout dataset (spec §3): 80 epochs, batch 6, SGD ×0.94,
    /// horizontal flips.
    pub fn mfnet_paper(root: PathBuf) -> Self {
        Self {
            network: NetworkConfig {
                model: ModelConfig::from_name("mfnet", 9).expect("mfnet is a known network"),
                inputs: Modality::RgbT,
                init_from: None,
                init_reset_head: false,
                backbone_weights: None,
                sync_batch_norm: false,
            },
            data: DataConfig {
                dataset: DatasetConfig::Mf {
                    root,
                    train_split: "train".into(),
                    val_split: Some("val".into()),
                },
                resize: None,
                augment: AugmentConfig {
                    hflip: true,
                    ..Default::default()
                },
                shuffle: true,
                workers: 2,
                fingerprint: None,
            },
            learning: LearningConfig {
                procedure: Procedure::Supervised,
                optimizer: OptimizerConfig::mfnet_paper(),
                loss: LossConfig::CrossEntropy {
                    class_weights: None,
                },
                precision: Precision::Fp32,
            },
            schedule: ScheduleConfig {
                epochs: 80,
                batch_size: 6,
                seed: 0,
                max_steps_per_epoch: None,
                checkpoint_every: None,
                select_by: None,
                tb_images_every: None,
            },
            compute: ComputeConfig {
                device: "cpu".into(),
                world_size: None,
                bf16_convolutions: None,
                fp32_layout: None,
            },
        }
    }

    /// This config with `edit` applied: a variant in one expression
    /// (`base.with(|c| c.schedule.epochs = 4)`).
    pub fn with(mut self, edit: impl FnOnce(&mut Self)) -> Self {
        edit(&mut self);
        self
    }

    /// The configured device, checked to exist on this machine.
    pub fn device(&self) -> Result<tch::Device, String> {
        available_device(&self.compute.device)
    }
}

fn at_least_one(field: &str, v: usize) -> Result<(), ConfigError> {
    match v {
        0 => Err(ConfigError::field(field, "must be at least 1")),
        _ => Ok(()),
    }
}

impl ScheduleConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        at_least_one("schedule.epochs", self.epochs)?;
        at_least_one("schedule.batch_size", self.batch_size)?;
        if let Some(steps) = self.max_steps_per_epoch {
            at_least_one("schedule.max_steps_per_epoch", steps)?;
        }
        if let Some(every) = self.checkpoint_every {
            at_least_one("schedule.checkpoint_every", every)?;
        }
        Ok(())
    }
}

impl LearningConfig {
    /// The arithmetic on `device`, the optimiser, the loss's class weights (one per class of
    /// the network's `num_classes`) and the procedure's options.
    fn validate(&self, device: tch::Device, num_classes: i64) -> Result<(), ConfigError> {
        if self.precision == Precision::Fp16 && device == tch::Device::Cpu {
            return Err(ConfigError::field(
                "learning.precision",
                "fp16 needs a CUDA device (libtorch's CPU autocast is bf16 only); use bf16 on the CPU",
            ));
        }
        if self.precision == Precision::Bf16 && device == tch::Device::Cpu {
            // A bad RTF_BF16_CONVOLUTIONS is refused here, before a run folder is written.
            rtf_amp::cpu_bf16_convolutions()
                .map_err(|e| ConfigError::field("learning.precision", &e.to_string()))?;
        }
        self.optimizer.validate("learning.optimizer")?;
        let LossConfig::CrossEntropy { class_weights } = &self.loss;
        if let Some(w) = class_weights {
            if w.len() as i64 != num_classes || w.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
                return Err(ConfigError::field(
                    "learning.loss.class_weights",
                    &format!("needs {num_classes} finite values ≥ 0 (one per class), got {w:?}"),
                ));
            }
        }
        self.validate_procedure()
    }

    fn validate_procedure(&self) -> Result<(), ConfigError> {
        let field = |name: &str| format!("learning.procedure.{name}");
        match &self.procedure {
            Procedure::Supervised => Ok(()),
            Procedure::TeacherStudent { targets, .. } => targets.validate(),
            Procedure::Adversarial {
                targets,
                critic,
                night_teacher,
                ..
            } => {
                targets.validate()?;
                if !(critic.lambda.is_finite() && critic.lambda >= 0.0) {
                    return Err(ConfigError::field(
                        &field("critic.lambda"),
                        &format!("must be ≥ 0, got {}", critic.lambda),
                    ));
                }
                at_least_one(&field("critic.steps"), critic.steps)?;
                critic.optimizer.validate(&field("critic.optimizer"))?;
                if critic.confidence_weighting && targets.cache {
                    return Err(ConfigError::field(
                        &field("critic.confidence_weighting"),
                        "needs the night teacher's confidence, which a label cache does not keep",
                    ));
                }
                if critic.confidence_weighting && night_teacher.is_none() {
                    return Err(ConfigError::field(
                        &field("critic.confidence_weighting"),
                        "weights by the night teacher's confidence: set learning.procedure.night_teacher",
                    ));
                }
                Ok(())
            }
        }
    }
}

impl TargetOptions {
    fn validate(&self) -> Result<(), ConfigError> {
        if self.cache && self.soft {
            return Err(ConfigError::field(
                "learning.procedure.targets.cache",
                "a label cache holds hard labels: it cannot go with soft targets",
            ));
        }
        match self.threshold {
            Some(t) if !(t.is_finite() && (0.0..1.0).contains(&t)) => Err(ConfigError::field(
                "learning.procedure.targets.threshold",
                &format!("must be in [0, 1), got {t}"),
            )),
            _ => Ok(()),
        }
    }
}

/// "cpu", "cuda" (first GPU) or "cuda:N".
pub fn parse_device(name: &str) -> Result<tch::Device, String> {
    match name {
        "cpu" => Ok(tch::Device::Cpu),
        "cuda" => Ok(tch::Device::Cuda(0)),
        _ => name
            .strip_prefix("cuda:")
            .and_then(|i| i.parse().ok())
            .map(tch::Device::Cuda)
            .ok_or_else(|| format!("unknown device `{name}` (expected cpu, cuda or cuda:N)")),
    }
}

/// [`parse_device`], then checks libtorch can use it here, so a missing GPU is a clear error
/// rather than a libtorch panic at the first tensor. (cuDNN's autotuner is the caller's: `rtf`
/// turns it on for every command, `RTF_CUDNN_BENCHMARK=0` off; see [`cudnn_benchmark`].)
pub fn available_device(name: &str) -> Result<tch::Device, String> {
    let device = parse_device(name)?;
    if let tch::Device::Cuda(index) = device {
        let count = tch::Cuda::device_count();
        if index as i64 >= count {
            return Err(format!(
                "device `{name}` is not available: libtorch sees {count} CUDA device(s) here{}",
                if tch::Cuda::is_available() {
                    ""
                } else {
                    " (no usable NVIDIA driver, or a CPU-only libtorch)"
                }
            ));
        }
    }
    Ok(device)
}

/// Whether cuDNN's autotuner runs (PyTorch's `torch.backends.cudnn.benchmark = True`): each
/// convolution shape is timed once over cuDNN's algorithms and the fastest kept, which pays
/// for rtf's fixed frame sizes. On unless the caller's `RTF_CUDNN_BENCHMARK` (read by `get`,
/// the binary's environment) is `0`. A libtorch setting of the whole process: the binary sets
/// it (`tch::Cuda::cudnn_set_benchmark`).
pub fn cudnn_benchmark(get: impl Fn(&str) -> Option<String>) -> bool {
    get("RTF_CUDNN_BENCHMARK").as_deref() != Some("0")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A config.json written before `shuffle` existed loads as shuffled; `false` is written
    /// and read back (rtf train --no-shuffle).
    #[test]
    fn shuffle_defaults_to_on_and_is_recorded_when_off() {
        let mut cfg = TrainConfig::mfnet_paper(PathBuf::from("/data"));
        let old = serde_json::to_value(&cfg).unwrap();
        assert!(old["data"].get("shuffle").is_none(), "{old}");
        let back: TrainConfig = serde_json::from_value(old).unwrap();
        assert!(back.data.shuffle);
        cfg.data.shuffle = false;
        let text = serde_json::to_string(&cfg).unwrap();
        assert!(text.contains("\"shuffle\":false"), "{text}");
        assert!(
            !serde_json::from_str::<TrainConfig>(&text)
                .unwrap()
                .data
                .shuffle
        );
    }

    /// A config.json written by `rtf train` before the sections (tests/fixtures/README.md)
    /// reads into them, and is written back in sections that read to the same config.
    #[test]
    fn a_flat_config_json_from_before_the_sections_reads_into_them() {
        let text = include_str!("../../tests/fixtures/flat_single_config.json");
        let RunConfig::Single(cfg) = RunConfig::parse(text, false).unwrap() else {
            panic!("a single run")
        };
        assert_eq!(cfg.network.model.name(), "mfnet");
        assert_eq!(
            cfg.data.dataset,
            DatasetConfig::Mf {
                root: "/tmp/house/fx/mf".into(),
                train_split: "train".into(),
                val_split: Some("val".into()),
            }
        );
        assert!(cfg.data.shuffle && cfg.data.augment.hflip);
        assert_eq!(cfg.data.workers, 2);
        assert_eq!(cfg.data.fingerprint.as_ref().unwrap().splits.len(), 5);
        assert_eq!(cfg.learning.optimizer, OptimizerConfig::mfnet_paper());
        assert_eq!(cfg.learning.precision, Precision::Fp32);
        assert_eq!((cfg.schedule.epochs, cfg.schedule.batch_size), (1, 6));
        assert_eq!(cfg.schedule.tb_images_every, Some(5));
        assert_eq!(cfg.compute.device, "cpu");
        let nested = serde_json::to_value(&*cfg).unwrap();
        let keys: Vec<&String> = nested.as_object().unwrap().keys().collect();
        assert_eq!(keys.len(), SECTIONS.len());
        assert!(SECTIONS.iter().all(|s| nested.get(s).is_some()), "{nested}");
        assert_eq!(serde_json::from_value::<TrainConfig>(nested).unwrap(), *cfg);
    }

    /// A multi-stage recipe's config.json and a stage's own (teachers by weights file) of
    /// the flat layout read too.
    #[test]
    fn a_flat_recipe_config_and_its_stage_config_read_into_sections() {
        let text = include_str!("../../tests/fixtures/flat_recipe_config.json");
        let RunConfig::Pipeline(p) = RunConfig::parse(text, false).unwrap() else {
            panic!("a pipeline")
        };
        assert_eq!(p.recipe.as_deref(), Some("heatnet-v3"));
        let names: Vec<&str> = p.stages.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["teacher-rgb", "v3"]);
        assert!(matches!(
            &p.stages[1].config.learning.procedure,
            Procedure::TeacherStudent { day_teacher: TeacherRef::Stage(s), .. } if s == "teacher-rgb"
        ));
        assert_eq!(p.stages[0].config.network.inputs, Modality::Rgb);
        RunConfig::Pipeline(p).validate().unwrap();
        let text = include_str!("../../tests/fixtures/flat_recipe_stage_config.json");
        let RunConfig::Single(stage) = RunConfig::parse(text, false).unwrap() else {
            panic!("a stage is a single run")
        };
        assert!(matches!(
            &stage.learning.procedure,
            Procedure::TeacherStudent { day_teacher: TeacherRef::Weights { path, .. }, .. }
                if path.ends_with("teacher-rgb/best.safetensors")
        ));
    }

    /// Unknown keys are refused in both layouts, by name: a flat config's misspelt setting, a
    /// setting left at the top of a sectioned one, a misspelt key inside a section.
    #[test]
    fn unknown_keys_are_refused_in_both_layouts() {
        let flat = r#"{"model": {"network": "mfnet", "num_classes": 9}, "epochz": 3}"#;
        let err = RunConfig::parse(flat, false).unwrap_err();
        assert!(err.contains("epochz"), "{err}");
        let cfg = TrainConfig::mfnet_paper("data".into());
        let mut nested = serde_json::to_value(&cfg).unwrap();
        nested["epochs"] = 3.into();
        let err = RunConfig::parse(&nested.to_string(), false).unwrap_err();
        assert!(err.contains("unknown field `epochs`"), "{err}");
        let mut nested = serde_json::to_value(&cfg).unwrap();
        nested["schedule"]["epochz"] = 3.into();
        let err = RunConfig::parse(&nested.to_string(), false).unwrap_err();
        assert!(err.contains("unknown field `epochz`"), "{err}");
        let yaml = "network: {model: {network: mfnet, num_classes: 9}}\nschedul: {}\n";
        let err = RunConfig::parse(yaml, true).unwrap_err();
        assert!(err.contains("schedul"), "{err}");
    }

    #[test]
    fn schedule_decays_per_epoch() {
        let sgd = OptimizerConfig::mfnet_paper();
        let epoch = |e, step| StepAt {
            epoch: e,
            step,
            steps_per_epoch: 7,
            epochs: 100,
        };
        assert_eq!(sgd.lr_at(epoch(0, 0)), 0.01);
        assert!((sgd.lr_at(epoch(2, 5)) - 0.01 * 0.94 * 0.94).abs() < 1e-15);
        let heatnet = OptimizerConfig::heatnet_paper();
        assert_eq!(heatnet.lr_at(StepAt::start_of(29)), 1e-4);
        assert_eq!(heatnet.lr_at(epoch(30, 6)), 0.5e-4);
        assert_eq!(heatnet.lr_at(StepAt::start_of(99)), 0.125e-4);
    }

    /// CMX's per-step schedule over the run's steps: 0 at the first step, half the rate half-way
    /// through the warm-up, the poly decay after it.
    #[test]
    fn cmx_schedule_warms_up_then_decays_per_step() {
        let cmx = OptimizerConfig::cmx_code();
        let at = |epoch, step| StepAt {
            epoch,
            step,
            steps_per_epoch: 4,
            epochs: 20,
        };
        assert_eq!(cmx.lr_at(at(0, 0)), 0.0);
        assert!((cmx.lr_at(at(5, 0)) - 3e-5).abs() < 1e-18);
        let poly = 6e-5 * (1.0 - 41.0 / 80.0f64).powf(0.9);
        assert!((cmx.lr_at(at(10, 1)) - poly).abs() < 1e-18);
        assert!(cmx.lr_at(at(19, 3)) > 0.0);
    }

    /// CMX's optimiser section is written with its kind, scope and schedule and reads back; the
    /// older sections (no such keys) read as before; bad betas and powers are refused by name.
    #[test]
    fn adamw_sections_round_trip_and_validate() {
        let cmx = OptimizerConfig::cmx_code();
        let json = serde_json::to_value(&cmx).unwrap();
        assert_eq!(json["kind"], "adamw");
        assert_eq!(json["decay_scope"], "conv_and_linear_weights");
        assert_eq!(json["schedule"]["kind"], "warmup_poly");
        assert!(
            json.get("betas").is_none(),
            "PyTorch's betas are not written"
        );
        assert_eq!(
            serde_json::from_value::<OptimizerConfig>(json).unwrap(),
            cmx
        );
        let sgd = serde_json::to_value(OptimizerConfig::mfnet_paper()).unwrap();
        assert!(sgd.get("schedule").is_none() && sgd.get("decay_scope").is_none());
        cmx.validate("o").unwrap();
        let bad_betas = OptimizerConfig {
            betas: (0.9, 1.0),
            ..cmx.clone()
        };
        assert_eq!(bad_betas.validate("o").unwrap_err().field, "o.betas");
        let bad_power = OptimizerConfig {
            schedule: LrSchedule::WarmupPoly {
                power: 0.0,
                warmup_epochs: 1,
            },
            ..cmx
        };
        assert_eq!(
            bad_power.validate("o").unwrap_err().field,
            "o.schedule.power"
        );
    }

    /// Decay on convolution and linear weights (≥ 2-D), none on norms' weights and biases.
    #[test]
    fn the_decay_scope_is_decided_by_shape() {
        let vs = tch::nn::VarStore::new(tch::Device::Cpu);
        let root = vs.root();
        let _conv = tch::nn::conv2d(&root / "conv", 3, 4, 3, Default::default());
        let _linear = tch::nn::linear(&root / "fc", 4, 2, Default::default());
        let _bn = tch::nn::batch_norm2d(&root / "bn", 4, Default::default());
        let _ln = tch::nn::layer_norm(&root / "ln", vec![4], Default::default());
        let decayed: Vec<String> = crate::optim::trainable(&vs)
            .into_iter()
            .filter(|(_, t)| DecayScope::ConvAndLinearWeights.decays(t))
            .map(|(n, _)| n)
            .collect();
        assert_eq!(decayed, ["conv.weight", "fc.weight"]);
        assert_eq!(crate::optim::trainable(&vs).len(), 8);
    }

    #[test]
    fn optimizer_kinds_parse_to_their_papers_optimisers() {
        for (text, expected) in [
            ("sgd", OptimizerConfig::mfnet_paper()),
            ("rmsprop", OptimizerConfig::heatnet_paper()),
            ("adamw", OptimizerConfig::cmx_code()),
        ] {
            let kind = OptimizerKind::parse(text).unwrap();
            assert_eq!(OptimizerConfig::paper_default(kind), expected);
        }
        let err = OptimizerKind::parse("adam").unwrap_err();
        assert!(err.contains("adamw"), "{err}");
    }

    #[test]
    fn optimizer_configs_written_before_rmsprop_still_read() {
        let old = r#"{"lr": 0.01, "momentum": 0.9, "weight_decay": 0.0005, "lr_decay": 0.94}"#;
        let cfg: OptimizerConfig = serde_json::from_str(old).unwrap();
        assert_eq!(cfg, OptimizerConfig::mfnet_paper());
    }

    #[test]
    fn config_round_trips_through_json() {
        let cfg = TrainConfig::mfnet_paper("data/mf".into());
        let json = serde_json::to_string_pretty(&cfg).unwrap();
        assert_eq!(serde_json::from_str::<TrainConfig>(&json).unwrap(), cfg);
        assert!(json.contains("\"seed\""));
    }

    #[test]
    fn a_described_dataset_round_trips_with_its_format_tag() {
        let cfg = DatasetConfig::Described {
            root: "data/pst900".into(),
            train_split: "train".into(),
            val_split: Some("holdout:10".into()),
            trained_on: Some(rtf_data::TrainedOn {
                classes: rtf_core::ClassSet::mf(),
                thermal: Some(rtf_data::thermal::ThermalNormalisation::Byte),
            }),
        };
        let json = serde_json::to_string(&cfg).unwrap();
        assert!(json.contains(r#""format":"described""#), "{json}");
        assert_eq!(serde_json::from_str::<DatasetConfig>(&json).unwrap(), cfg);
    }

    #[test]
    fn freiburg_dataset_round_trips_and_defaults_to_the_reference_preprocessing() {
        let cfg = DatasetConfig::freiburg("data/freiburg".into(), true);
        let json = serde_json::to_string(&cfg).unwrap();
        assert_eq!(serde_json::from_str::<DatasetConfig>(&json).unwrap(), cfg);
        let short = r#"{"format": "freiburg", "root": "data/freiburg"}"#;
        assert_eq!(serde_json::from_str::<DatasetConfig>(short).unwrap(), cfg);
    }

    #[test]
    fn devices_parse() {
        assert_eq!(parse_device("cpu"), Ok(tch::Device::Cpu));
        assert_eq!(parse_device("cuda:1"), Ok(tch::Device::Cuda(1)));
        assert!(parse_device("tpu").is_err());
    }

    #[test]
    fn unavailable_gpus_are_a_clear_error() {
        assert_eq!(available_device("cpu"), Ok(tch::Device::Cpu));
        let count = tch::Cuda::device_count();
        let missing = format!("cuda:{count}");
        let err = available_device(&missing).unwrap_err();
        assert!(
            err.contains(&missing) && err.contains("not available"),
            "{err}"
        );
    }
}
