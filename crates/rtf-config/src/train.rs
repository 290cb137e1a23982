//! The full, serialisable description of a training run (written to `RUN/config.json`): one
//! training ([`TrainConfig`]) or the stages of a multi-stage run ([`RunConfig`]), each checked
//! by `validate` before anything is written. rtf-train trains them.

use std::path::{Path, PathBuf};

use crate::data::{AugmentConfig, FreiburgPreprocess};
use crate::data::{RecordedKind, TrainingChoice};
use serde::{Deserialize, Serialize};

use crate::network::ModelConfig;

mod legacy;
mod optimizer;
pub mod schedule;

pub use crate::compute::{ComputeConfig, DeviceName, Fp32Layout};
pub use optimizer::{DecayScope, OptimizerConfig, OptimizerKind};

/// One training: five sections, one per concern, each its own type (written nested to
/// `config.json`; a flat `config.json` written before the sections existed still reads,
/// see the `legacy` module).
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
    pub fingerprint: Option<crate::data::Fingerprint>,
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

/// Which input channels a network sees (recorded in weights files too, so that evaluation
/// applies the same mask).
pub use crate::network::Modality;

/// The arithmetic of a training step (PyTorch's automatic mixed precision; one type with the
/// fast inference path's).
pub use crate::Precision;

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

    /// Every teacher the procedure names, to resolve in place.
    pub fn teachers_mut(&mut self) -> Vec<&mut TeacherRef> {
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
    /// A root read through a dataset description (rtf-data's `layouts`): `root/dataset.yaml`
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
        trained_on: Option<crate::data::TrainedOn>,
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

    /// The frames the run reads, for rtf-data to open ([`TrainingChoice`]):
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
    pub fn recorded(&self) -> Option<&crate::data::TrainedOn> {
        match self {
            DatasetConfig::Described { trained_on, .. } => trained_on.as_ref(),
            _ => None,
        }
    }
}

pub use schedule::{LrSchedule, StepAt};

fn one() -> usize {
    1
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
        let device = DeviceName::parse(&self.compute.device)
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
                winograd: crate::compute::Forms::All,
            },
        }
    }

    /// This config with `edit` applied: a variant in one expression
    /// (`base.with(|c| c.schedule.epochs = 4)`).
    pub fn with(mut self, edit: impl FnOnce(&mut Self)) -> Self {
        edit(&mut self);
        self
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
    fn validate(&self, device: DeviceName, num_classes: i64) -> Result<(), ConfigError> {
        if self.precision == Precision::Fp16 && device == DeviceName::Cpu {
            return Err(ConfigError::field(
                "learning.precision",
                "fp16 needs a CUDA device (libtorch's CPU autocast is bf16 only); use bf16 on the CPU",
            ));
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

#[cfg(test)]
mod tests;
