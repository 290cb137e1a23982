//! The flat `config.json` layout written before [`TrainConfig`] had sections (every setting at
//! the top level). Run folders started then keep resuming: their config reads through this
//! type into the sections (and is written back in sections when a resume records it).

use std::path::PathBuf;

use crate::data::AugmentConfig;
use crate::network::ModelConfig;
use serde::Deserialize;

use super::{
    yes, ComputeConfig, DataConfig, DatasetConfig, LearningConfig, LossConfig, Modality,
    NetworkConfig, OptimizerConfig, Precision, Procedure, ScheduleConfig, SelectMetric,
    TrainConfig, WeightsRef,
};

/// Today's fields, with the defaults they had; any other key is refused.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct LegacyFlatConfig {
    model: ModelConfig,
    dataset: DatasetConfig,
    epochs: usize,
    batch_size: usize,
    seed: u64,
    optimizer: OptimizerConfig,
    loss: LossConfig,
    augment: AugmentConfig,
    #[serde(default = "yes")]
    shuffle: bool,
    resize: Option<(usize, usize)>,
    max_steps_per_epoch: Option<usize>,
    #[serde(default)]
    checkpoint_every: Option<usize>,
    workers: usize,
    device: String,
    #[serde(default)]
    backbone_weights: Option<PathBuf>,
    #[serde(default)]
    procedure: Procedure,
    #[serde(default)]
    inputs: Modality,
    #[serde(default)]
    init_from: Option<WeightsRef>,
    #[serde(default)]
    init_reset_head: bool,
    #[serde(default)]
    select_by: Option<SelectMetric>,
    #[serde(default)]
    tb_images_every: Option<usize>,
    #[serde(default)]
    precision: Precision,
    #[serde(default)]
    sync_batch_norm: bool,
    #[serde(default)]
    data_fingerprint: Option<crate::data::Fingerprint>,
    #[serde(default)]
    world_size: Option<usize>,
}

impl From<LegacyFlatConfig> for TrainConfig {
    fn from(f: LegacyFlatConfig) -> Self {
        TrainConfig {
            network: NetworkConfig {
                model: f.model,
                inputs: f.inputs,
                init_from: f.init_from,
                init_reset_head: f.init_reset_head,
                backbone_weights: f.backbone_weights,
                sync_batch_norm: f.sync_batch_norm,
            },
            data: DataConfig {
                dataset: f.dataset,
                resize: f.resize,
                augment: f.augment,
                shuffle: f.shuffle,
                workers: f.workers,
                fingerprint: f.data_fingerprint,
            },
            learning: LearningConfig {
                procedure: f.procedure,
                optimizer: f.optimizer,
                loss: f.loss,
                precision: f.precision,
            },
            schedule: ScheduleConfig {
                epochs: f.epochs,
                batch_size: f.batch_size,
                seed: f.seed,
                max_steps_per_epoch: f.max_steps_per_epoch,
                checkpoint_every: f.checkpoint_every,
                select_by: f.select_by,
                tb_images_every: f.tb_images_every,
            },
            compute: ComputeConfig {
                device: f.device,
                world_size: f.world_size,
                bf16_convolutions: None,
                fp32_layout: None,
                winograd: crate::compute::Forms::All,
            },
        }
    }
}
