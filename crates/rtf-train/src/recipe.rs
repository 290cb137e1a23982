//! The papers' training recipes, as data: `rtf recipes` lists them, `rtf train --recipe NAME`
//! instantiates one for a dataset. A recipe is a list of stages; each stage names its
//! procedure, the role of its network, the channels it sees, and the earlier stages it learns
//! from. Stages a user brings (`--teacher`, `--night-teacher`) are dropped, with every stage
//! that only they needed.
//!
//! HeatNet Tab. II follows the table's check marks: V1 = thermal only, V2 = RGB only (the
//! text swaps them), V3 = RGB-T, V4 = RGB + critic, V5 = RGB-T + critic, V6 = RGB-T + critic +
//! two-stage. HeatNet's schedule (§V-A): RMSprop 1e-4 halved every 30 epochs, batch 8, 100
//! epochs (every stage); augmentation (spec §5): flip, rotation ±20°, IR scaling ×U(0.1, 1)
//! (modality drop-out off: its probability is not published).
//!
//! CMX's recipe (`cmx-mf`) is its official training code's, read from
//! github.com/huaaaliu/RGBX_Semantic_Segmentation (commit e251d86):
//! - `config.py`: `optimizer = 'AdamW'`, `lr = 6e-5`, `weight_decay = 0.01`, `lr_power = 0.9`,
//!   `warm_up_epoch = 10`, `batch_size = 8`, `nepochs = 500`, `train_scale_array = [0.5, 0.75,
//!   1, 1.25, 1.5, 1.75]`, `image_height × image_width = 480 × 640` (the crop), `bn_eps = 1e-3`,
//!   `bn_momentum = 0.1`, `background = 255` (the ignored label);
//! - `train.py`: `torch.optim.AdamW(params, lr, betas=(0.9, 0.999), weight_decay)` over the two
//!   groups of `group_weight`; `WarmUpPolyLR(lr, lr_power, nepochs × niters_per_epoch,
//!   niters_per_epoch × warm_up_epoch)` evaluated per iteration; cross-entropy with
//!   `ignore_index = 255`;
//! - `utils/init_func.py`: `group_weight` (decay on Linear and Conv weights; none on their
//!   biases nor on any BatchNorm/GroupNorm/LayerNorm parameter), `init_weight` (sets eps and
//!   momentum of the decoder's BatchNorm: `models/builder.py` calls it on `decode_head` only);
//! - `utils/lr_policy.py`: `WarmUpPolyLR`;
//! - `dataloader/dataloader.py` `TrainPre`: random mirror, random scale from the set, normalise,
//!   random crop padded with 0 (image) and 255 (label); `utils/transforms.py`: the crop position
//!   and padding.
//!
//! Where rtf's `cmx-mf` differs: an epoch is one pass over the training split (the official
//! epoch is `len // batch + 1` batches, every frame once plus random repeats); the rate is
//! set before each step from its own index (the official loop sets it after each step, see
//! [`crate::schedule::LrSchedule::WarmupPoly`]); the mirror comes after the crop (the same
//! distribution); padding is the network's normalised zero in unit range
//! ([`rtf_models::ModelConfig::normalised_zero`]: exact for the colour planes, the nearest value
//! for the replicated thermal plane); frames are resampled in floating point (OpenCV resizes the
//! 8-bit images); the decoder's eps 1e-3 stays in the trained network's config, so evaluation
//! uses it too (the official evaluation rebuilds the network with PyTorch's 1e-5). The ImageNet
//! MiT weights the official run starts from are `--backbone-weights`.

use std::collections::BTreeMap;
use std::path::PathBuf;

use rtf_data::{AugmentConfig, ScaleCrop};
use rtf_models::ModelConfig;
use serde::Serialize;

use crate::config::{
    CriticOptions, DatasetConfig, Modality, OptimizerConfig, PipelineConfig, Procedure, RunConfig,
    StageConfig, TargetOptions, TeacherRef, TrainConfig, WeightsRef,
};

/// Which network of the recipe a stage trains (the paper's networks by default; `--model`
/// puts one network in every role, e.g. a light one for a CPU budget).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// MFNet / RTFNet supervised training: the network named by `--model`.
    Network,
    /// A network seeing `inputs` (HeatNet: `heatnet-rgb`, `heatnet-ir`, `heatnet`).
    HeatNet,
}

/// How a stage learns, naming earlier stages by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum StageProcedure {
    Supervised,
    TeacherStudent {
        day: &'static str,
        night: Option<&'static str>,
    },
    Adversarial {
        day: &'static str,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct StageSpec {
    pub name: &'static str,
    pub procedure: StageProcedure,
    pub role: Role,
    pub inputs: Modality,
    /// Starts from this earlier stage's final weights.
    pub init_from: Option<&'static str>,
}

/// The schedule a recipe trains with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Schedule {
    /// MFNet paper: SGD 0.01 ×0.94 per epoch, 80 epochs, batch 6, flips.
    MfnetPaper,
    /// RTFNet code: SGD 0.01 ×0.95 per epoch, weight decay 5e-4, batch 2, flip + 10 % crop.
    RtfnetCode,
    /// HeatNet paper: RMSprop 1e-4 halved every 30 epochs, 100 epochs, batch 8.
    HeatnetPaper,
    /// CMX code (module doc): AdamW 6e-5, weight decay 0.01 on convolution and linear weights,
    /// 10 epochs of linear warm-up then poly 0.9 per step, batch 8, 500 epochs, flip + random
    /// scale + crop padded with the network's normalised zero, decoder BatchNorm eps 1e-3.
    CmxCode,
}

/// The official CMX training's BatchNorm eps of the decoder (`config.bn_eps`).
pub const CMX_DECODER_BN_EPS: f64 = 1e-3;

#[derive(Debug, Clone, Serialize)]
pub struct Recipe {
    pub name: &'static str,
    /// `supervised`, `teacher_student`, `adversarial`, or `pipeline` for several stages.
    pub procedure: &'static str,
    pub description: &'static str,
    /// Paper and section or table.
    pub source: &'static str,
    pub schedule: Schedule,
    pub stages: &'static [StageSpec],
    /// The stage `--teacher` stands in for, and the one `--night-teacher` stands in for.
    pub teacher_stage: Option<&'static str>,
    pub night_teacher_stage: Option<&'static str>,
}

const fn stage(
    name: &'static str,
    procedure: StageProcedure,
    inputs: Modality,
    init_from: Option<&'static str>,
) -> StageSpec {
    StageSpec {
        name,
        procedure,
        role: Role::HeatNet,
        inputs,
        init_from,
    }
}

use Modality::{Rgb, RgbT, Thermal};
use StageProcedure::{Adversarial, Supervised, TeacherStudent};

const TEACHER_RGB: StageSpec = stage("teacher-rgb", Supervised, Rgb, None);
const TEACHER_IR: StageSpec = stage(
    "teacher-ir",
    TeacherStudent {
        day: "teacher-rgb",
        night: None,
    },
    Thermal,
    None,
);
const fn day_only(name: &'static str, inputs: Modality) -> StageSpec {
    stage(
        name,
        TeacherStudent {
            day: "teacher-rgb",
            night: None,
        },
        inputs,
        None,
    )
}
const fn adversarial(name: &'static str, inputs: Modality) -> StageSpec {
    stage(name, Adversarial { day: "teacher-rgb" }, inputs, None)
}
const STAGE1: StageSpec = stage(
    "stage1",
    TeacherStudent {
        day: "teacher-rgb",
        night: Some("teacher-ir"),
    },
    RgbT,
    None,
);
const STAGE2: StageSpec = stage(
    "stage2",
    Adversarial { day: "teacher-rgb" },
    RgbT,
    Some("stage1"),
);

pub const RECIPES: &[Recipe] = &[
    Recipe {
        name: "mfnet-paper",
        procedure: "supervised",
        description: "MFNet's training: SGD lr 0.01 ×0.94 per epoch, momentum 0.9, weight decay 5e-4, batch 6, 80 epochs, horizontal flips",
        source: "MFNet §IV-A",
        schedule: Schedule::MfnetPaper,
        stages: &[StageSpec { name: "train", procedure: Supervised, role: Role::Network, inputs: RgbT, init_from: None }],
        teacher_stage: None,
        night_teacher_stage: None,
    },
    Recipe {
        name: "rtfnet-code",
        procedure: "supervised",
        description: "RTFNet's published training: SGD lr 0.01 ×0.95 per epoch, momentum 0.9, weight decay 5e-4, batch 2, 100 epochs, flip + random 10 % edge crop",
        source: "RTFNet code (spec §4)",
        schedule: Schedule::RtfnetCode,
        stages: &[StageSpec { name: "train", procedure: Supervised, role: Role::Network, inputs: RgbT, init_from: None }],
        teacher_stage: None,
        night_teacher_stage: None,
    },
    Recipe {
        name: "cmx-mf",
        procedure: "supervised",
        description: "CMX's published training (--model cmx-mit-b0 … b5; the ImageNet MiT start: --backbone-weights): AdamW lr 6e-5, weight decay 0.01 on convolution and linear weights only, 10 epochs of linear warm-up then poly 0.9 per step, batch 8, 500 epochs, flip + random scale {0.5 … 1.75} + crop padded (label ignored), decoder BatchNorm eps 1e-3",
        source: "CMX code (huaaaliu/RGBX_Semantic_Segmentation config.py, train.py)",
        schedule: Schedule::CmxCode,
        stages: &[StageSpec { name: "train", procedure: Supervised, role: Role::Network, inputs: RgbT, init_from: None }],
        teacher_stage: None,
        night_teacher_stage: None,
    },
    Recipe {
        name: "heatnet-teacher-rgb",
        procedure: "supervised",
        description: "HeatNet's RGB day teacher M_D (paper: trained on Mapillary Vistas; here on the labelled day frames given)",
        source: "HeatNet §III-A",
        schedule: Schedule::HeatnetPaper,
        stages: &[TEACHER_RGB],
        teacher_stage: None,
        night_teacher_stage: None,
    },
    Recipe {
        name: "heatnet-teacher-ir",
        procedure: "teacher_student",
        description: "HeatNet's thermal night teacher M_N: thermal only, learns the RGB teacher's labels of day frames",
        source: "HeatNet §III-A.1",
        schedule: Schedule::HeatnetPaper,
        stages: &[TEACHER_RGB, TEACHER_IR],
        teacher_stage: Some("teacher-rgb"),
        night_teacher_stage: None,
    },
    Recipe {
        name: "heatnet-v1",
        procedure: "teacher_student",
        description: "Tab. II V1: thermal only, the RGB teacher's day labels, no critic",
        source: "HeatNet Tab. II",
        schedule: Schedule::HeatnetPaper,
        stages: &[TEACHER_RGB, day_only("v1", Thermal)],
        teacher_stage: Some("teacher-rgb"),
        night_teacher_stage: None,
    },
    Recipe {
        name: "heatnet-v2",
        procedure: "teacher_student",
        description: "Tab. II V2: RGB only, the RGB teacher's day labels, no critic",
        source: "HeatNet Tab. II",
        schedule: Schedule::HeatnetPaper,
        stages: &[TEACHER_RGB, day_only("v2", Rgb)],
        teacher_stage: Some("teacher-rgb"),
        night_teacher_stage: None,
    },
    Recipe {
        name: "heatnet-v3",
        procedure: "teacher_student",
        description: "Tab. II V3: RGB-T, the RGB teacher's day labels, no critic",
        source: "HeatNet Tab. II",
        schedule: Schedule::HeatnetPaper,
        stages: &[TEACHER_RGB, day_only("v3", RgbT)],
        teacher_stage: Some("teacher-rgb"),
        night_teacher_stage: None,
    },
    Recipe {
        name: "heatnet-v4",
        procedure: "adversarial",
        description: "Tab. II V4: RGB only, the RGB teacher's day labels + day/night critic",
        source: "HeatNet Tab. II",
        schedule: Schedule::HeatnetPaper,
        stages: &[TEACHER_RGB, adversarial("v4", Rgb)],
        teacher_stage: Some("teacher-rgb"),
        night_teacher_stage: None,
    },
    Recipe {
        name: "heatnet-v5",
        procedure: "adversarial",
        description: "Tab. II V5: RGB-T, the RGB teacher's day labels + day/night critic",
        source: "HeatNet Tab. II",
        schedule: Schedule::HeatnetPaper,
        stages: &[TEACHER_RGB, adversarial("v5", RgbT)],
        teacher_stage: Some("teacher-rgb"),
        night_teacher_stage: None,
    },
    Recipe {
        name: "heatnet-v6",
        procedure: "pipeline",
        description: "Tab. II V6 (HeatNet): two-stage — stage 1 RGB day teacher + thermal night teacher, stage 2 continues with the critic and without the night teacher",
        source: "HeatNet §III-A.1, Tab. II",
        schedule: Schedule::HeatnetPaper,
        stages: &[TEACHER_RGB, TEACHER_IR, STAGE1, STAGE2],
        teacher_stage: Some("teacher-rgb"),
        night_teacher_stage: Some("teacher-ir"),
    },
    Recipe {
        name: "heatnet-distill",
        procedure: "pipeline",
        description: "RGB-T → RGB distillation: an RGB-only student learns the RGB teacher's labels by day and the RGB-T HeatNet's (V6; or --night-teacher) by night",
        source: "HeatNet §III-A.2",
        schedule: Schedule::HeatnetPaper,
        stages: &[
            TEACHER_RGB,
            TEACHER_IR,
            STAGE1,
            STAGE2,
            stage(
                "distill",
                TeacherStudent {
                    day: "teacher-rgb",
                    night: Some("stage2"),
                },
                Rgb,
                None,
            ),
        ],
        teacher_stage: Some("teacher-rgb"),
        night_teacher_stage: Some("stage2"),
    },
];

impl Recipe {
    /// The network the recipe ends with by default (the paper's), None when `--model` must
    /// name it; and the channels its last stage sees.
    pub fn final_network(&self) -> (Option<&'static str>, Modality) {
        let last = self.stages.last().expect("a recipe has stages");
        let name = match (last.role, last.inputs) {
            (Role::Network, _) => None,
            (Role::HeatNet, Rgb) => Some("heatnet-rgb"),
            (Role::HeatNet, Thermal) => Some("heatnet-ir"),
            (Role::HeatNet, RgbT) => Some("heatnet"),
        };
        (name, last.inputs)
    }
}

/// `rtf recipes` reads this.
pub fn recipe(name: &str) -> Result<&'static Recipe, RecipeError> {
    RECIPES.iter().find(|r| r.name == name).ok_or_else(|| {
        RecipeError(format!(
            "unknown recipe `{name}` (known: {})",
            RECIPES
                .iter()
                .map(|r| r.name)
                .collect::<Vec<_>>()
                .join(", ")
        ))
    })
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct RecipeError(pub String);

/// What a user gives a recipe.
#[derive(Debug, Clone)]
pub struct RecipeInputs {
    pub dataset: DatasetConfig,
    pub num_classes: i64,
    /// One network for every role (`--model`); None = the paper's networks.
    pub model: Option<String>,
    pub teacher: Option<TeacherRef>,
    pub night_teacher: Option<TeacherRef>,
}

impl Schedule {
    fn apply(self, cfg: &mut TrainConfig, freiburg: bool) {
        match self {
            Schedule::MfnetPaper => {}
            Schedule::RtfnetCode => {
                cfg.learning.optimizer.lr_decay = 0.95;
                cfg.schedule.batch_size = 2;
                cfg.schedule.epochs = 100;
                cfg.data.augment.crop = Some(0.1);
            }
            Schedule::HeatnetPaper => {
                cfg.learning.optimizer = OptimizerConfig::heatnet_paper();
                cfg.schedule.batch_size = 8;
                cfg.schedule.epochs = 100;
                cfg.data.augment = AugmentConfig {
                    hflip: true,
                    rotation_deg: Some(20.0),
                    ir_scale: Some((0.1, 1.0)),
                    ..Default::default()
                };
            }
            Schedule::CmxCode => {
                cfg.learning.optimizer = OptimizerConfig::cmx_code();
                cfg.schedule.batch_size = 8;
                cfg.schedule.epochs = 500;
                let model = &cfg.network.model;
                cfg.data.augment = AugmentConfig {
                    hflip: true,
                    scale_crop: Some(ScaleCrop::cmx(model.normalised_zero())),
                    ..Default::default()
                };
                cfg.network.model = model.with_decoder_bn_eps(CMX_DECODER_BN_EPS);
            }
        }
        // The reference preprocessing leaves 700×320; HeatNet trains on a 640×320 window
        // (CMX's scale and crop take the frame as it is).
        if freiburg && cfg.data.resize.is_none() && cfg.data.augment.scale_crop.is_none() {
            cfg.data.augment.window = Some((640, 320));
        }
    }
}

fn network_for(
    role: Role,
    inputs: Modality,
    inputs_: &RecipeInputs,
) -> Result<ModelConfig, RecipeError> {
    let name = match (&inputs_.model, role) {
        (Some(m), _) => m.clone(),
        (None, Role::Network) => {
            return Err(RecipeError(
                "this recipe trains the network --model names: give --model".into(),
            ))
        }
        (None, Role::HeatNet) => match inputs {
            Rgb => "heatnet-rgb".into(),
            Thermal => "heatnet-ir".into(),
            RgbT => "heatnet".into(),
        },
    };
    ModelConfig::from_name(&name, inputs_.num_classes).map_err(|e| RecipeError(e.to_string()))
}

/// The run a recipe describes for `inputs`: one stage → a single training, several → a
/// pipeline. Flags applied afterwards override (`rtf train`).
pub fn instantiate(recipe: &Recipe, inputs: &RecipeInputs) -> Result<RunConfig, RecipeError> {
    let external = external_teachers(recipe, inputs)?;
    let needed = needed_stages(recipe, &external);
    let freiburg = matches!(inputs.dataset, DatasetConfig::Freiburg { .. });
    let teacher = |name: &str| -> TeacherRef {
        external
            .get(name)
            .cloned()
            .unwrap_or_else(|| TeacherRef::Stage(name.to_string()))
    };
    let mut stages = Vec::new();
    for spec in recipe.stages {
        if !needed.contains(&spec.name) || external.contains_key(spec.name) {
            continue;
        }
        let mut cfg = TrainConfig::mfnet_paper(PathBuf::new());
        cfg.network.model = network_for(spec.role, spec.inputs, inputs)?;
        cfg.data.dataset = inputs.dataset.clone();
        cfg.network.inputs = spec.inputs;
        recipe.schedule.apply(&mut cfg, freiburg);
        cfg.learning.procedure = match spec.procedure {
            Supervised => Procedure::Supervised,
            TeacherStudent { day, night } => Procedure::TeacherStudent {
                day_teacher: teacher(day),
                night_teacher: night.map(teacher),
                targets: TargetOptions::default(),
            },
            Adversarial { day } => Procedure::Adversarial {
                day_teacher: teacher(day),
                night_teacher: None,
                targets: TargetOptions::default(),
                critic: CriticOptions::default(),
            },
        };
        cfg.network.init_from = spec.init_from.map(|s| WeightsRef::Stage(s.to_string()));
        stages.push(StageConfig {
            name: spec.name.to_string(),
            config: cfg,
        });
    }
    Ok(match stages.len() {
        1 if recipe.stages.len() == 1 => RunConfig::Single(Box::new(stages.remove(0).config)),
        _ => RunConfig::Pipeline(PipelineConfig {
            recipe: Some(recipe.name.to_string()),
            stages,
        }),
    })
}

/// The stages the user brings as teachers (`--teacher`, `--night-teacher`), by stage name.
fn external_teachers(
    recipe: &Recipe,
    inputs: &RecipeInputs,
) -> Result<BTreeMap<&'static str, TeacherRef>, RecipeError> {
    let mut external = BTreeMap::new();
    for (given, stage, flag) in [
        (&inputs.teacher, recipe.teacher_stage, "--teacher"),
        (
            &inputs.night_teacher,
            recipe.night_teacher_stage,
            "--night-teacher",
        ),
    ] {
        match (given, stage) {
            (Some(t), Some(s)) => {
                external.insert(s, t.clone());
            }
            (Some(_), None) => {
                return Err(RecipeError(format!(
                    "recipe `{}` takes no {flag}",
                    recipe.name
                )))
            }
            (None, _) => {}
        }
    }
    Ok(external)
}

/// The stages the last one needs (as teachers or starting weights), minus those the user
/// brought.
fn needed_stages(
    recipe: &Recipe,
    external: &BTreeMap<&'static str, TeacherRef>,
) -> Vec<&'static str> {
    let mut needed = vec![recipe.stages.last().expect("a recipe has stages").name];
    for spec in recipe.stages.iter().rev() {
        if !needed.contains(&spec.name) || external.contains_key(spec.name) {
            continue;
        }
        let refs = match spec.procedure {
            Supervised => vec![],
            TeacherStudent { day, night } => std::iter::once(day).chain(night).collect(),
            Adversarial { day } => vec![day],
        };
        needed.extend(refs.into_iter().chain(spec.init_from));
    }
    needed
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inputs(teacher: Option<TeacherRef>) -> RecipeInputs {
        RecipeInputs {
            dataset: DatasetConfig::freiburg("data/fr".into(), true),
            num_classes: 13,
            model: None,
            teacher,
            night_teacher: None,
        }
    }

    fn stage_names(cfg: &RunConfig) -> Vec<String> {
        cfg.stages().iter().map(|(n, _)| n.to_string()).collect()
    }

    #[test]
    fn every_recipe_instantiates_and_validates() {
        for r in RECIPES {
            let mut given = inputs(None);
            if r.stages.iter().any(|s| s.role == Role::Network) {
                given.model = Some("mfnet".into());
                given.num_classes = 13;
            }
            let cfg = instantiate(r, &given).unwrap_or_else(|e| panic!("{}: {e}", r.name));
            cfg.validate().unwrap_or_else(|e| panic!("{}: {e}", r.name));
        }
    }

    /// `cmx-mf` on an MF root: CMX's optimiser, schedule, batch, epochs, augmentation with the
    /// network's normalised zero as padding, and the decoder's training eps; BatchNorm momentum
    /// is PyTorch's 0.1 as in the official config.
    #[test]
    fn cmx_mf_sets_the_official_training() {
        let given = RecipeInputs {
            dataset: DatasetConfig::Mf {
                root: "data/mf".into(),
                train_split: "train".into(),
                val_split: Some("val".into()),
            },
            num_classes: 9,
            model: Some("cmx-mit-b2".into()),
            teacher: None,
            night_teacher: None,
        };
        let RunConfig::Single(cfg) = instantiate(recipe("cmx-mf").unwrap(), &given).unwrap() else {
            panic!("one stage")
        };
        cfg.validate().unwrap();
        assert_eq!(cfg.learning.optimizer, OptimizerConfig::cmx_code());
        assert_eq!((cfg.schedule.batch_size, cfg.schedule.epochs), (8, 500));
        let sc = cfg.data.augment.scale_crop.as_ref().unwrap();
        assert_eq!(sc.scales, [0.5, 0.75, 1.0, 1.25, 1.5, 1.75]);
        assert_eq!(sc.size, None, "MF's 640×480 frame is the official crop");
        assert_eq!(sc.fill, cfg.network.model.normalised_zero());
        assert!(cfg.data.augment.hflip && cfg.data.augment.window.is_none());
        let rtf_models::ModelConfig::Cmx(c) = &cfg.network.model else {
            panic!("a CMX network")
        };
        assert_eq!(
            (c.size, c.decoder_bn_eps),
            (rtf_models::cmx::Size::B2, 1e-3)
        );
        assert_eq!(rtf_models::layers::BN_MOMENTUM, 0.1);
        // Any other network trains by the same recipe, padded with its own zero.
        let mfnet = RecipeInputs {
            model: Some("mfnet".into()),
            ..given
        };
        let cfg = instantiate(recipe("cmx-mf").unwrap(), &mfnet).unwrap();
        let (_, stage) = cfg.stages()[0];
        assert_eq!(
            stage.data.augment.scale_crop.as_ref().unwrap().fill,
            [0.0; 4]
        );
    }

    #[test]
    fn table_two_follows_the_check_marks() {
        let inputs_of = |name: &str| {
            let cfg = instantiate(recipe(name).unwrap(), &inputs(None)).unwrap();
            let (_, last) = *cfg.stages().last().unwrap();
            (
                last.network.inputs,
                last.network.model.name(),
                last.learning.procedure.name(),
            )
        };
        assert_eq!(
            inputs_of("heatnet-v1"),
            (Thermal, "heatnet-ir".into(), "teacher_student")
        );
        assert_eq!(
            inputs_of("heatnet-v2"),
            (Rgb, "heatnet-rgb".into(), "teacher_student")
        );
        assert_eq!(
            inputs_of("heatnet-v3"),
            (RgbT, "heatnet".into(), "teacher_student")
        );
        assert_eq!(
            inputs_of("heatnet-v4"),
            (Rgb, "heatnet-rgb".into(), "adversarial")
        );
        assert_eq!(
            inputs_of("heatnet-v5"),
            (RgbT, "heatnet".into(), "adversarial")
        );
        assert_eq!(
            inputs_of("heatnet-v6"),
            (RgbT, "heatnet".into(), "adversarial")
        );
    }

    #[test]
    fn given_teachers_replace_their_stages_and_what_only_they_needed() {
        let v6 = recipe("heatnet-v6").unwrap();
        let full = instantiate(v6, &inputs(None)).unwrap();
        assert_eq!(
            stage_names(&full),
            ["teacher-rgb", "teacher-ir", "stage1", "stage2"]
        );
        let given = TeacherRef::Weights {
            path: "t.safetensors".into(),
            model: ModelConfig::from_name("heatnet-rgb", 13).unwrap(),
            inputs: Rgb,
        };
        let with_teacher = instantiate(v6, &inputs(Some(given.clone()))).unwrap();
        assert_eq!(
            stage_names(&with_teacher),
            ["teacher-ir", "stage1", "stage2"]
        );
        let RunConfig::Pipeline(p) = &with_teacher else {
            panic!()
        };
        assert!(matches!(&p.stages[0].config.learning.procedure,
            Procedure::TeacherStudent { day_teacher, .. } if *day_teacher == given));
        let distill = recipe("heatnet-distill").unwrap();
        let mut both = inputs(Some(given));
        both.night_teacher = Some(TeacherRef::Weights {
            path: "heatnet.safetensors".into(),
            model: ModelConfig::from_name("heatnet", 13).unwrap(),
            inputs: RgbT,
        });
        let cfg = instantiate(distill, &both).unwrap();
        assert_eq!(stage_names(&cfg), ["distill"]);
        // One stage left, still a pipeline: the run folder layout does not depend on flags.
        assert!(matches!(cfg, RunConfig::Pipeline(_)));
        let err = instantiate(
            recipe("heatnet-v3").unwrap(),
            &RecipeInputs {
                night_teacher: both.night_teacher.clone(),
                ..inputs(None)
            },
        )
        .unwrap_err();
        assert!(err.0.contains("--night-teacher"), "{err}");
    }

    #[test]
    fn one_model_in_every_role_and_unknown_names_are_clear() {
        let mut light = inputs(None);
        light.model = Some("mfnet".into());
        let cfg = instantiate(recipe("heatnet-v5").unwrap(), &light).unwrap();
        assert!(cfg
            .stages()
            .iter()
            .all(|(_, c)| c.network.model.name() == "mfnet"));
        let err = recipe("heatnet-v7").unwrap_err().0;
        assert!(
            err.contains("heatnet-v7") && err.contains("heatnet-v6"),
            "{err}"
        );
    }
}
