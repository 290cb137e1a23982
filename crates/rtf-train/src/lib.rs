//! rtf-train: every training procedure of the three papers on one training core. The loop
//! mechanics live once ([`trainer`]); each procedure is a step body over the networks it trains
//! ([`procedure`]); a run of several stages (HeatNet's teachers, two-stage training,
//! distillation) is a pipeline of ordinary runs ([`pipeline`]); the papers' recipes are data
//! ([`recipe`]). Every run folder has its full config before the first step, a JSON-lines log,
//! atomic checkpoints, and `--resume` continues it exactly.

#[cfg(feature = "cli")]
pub mod args;
pub mod bench;
pub mod checkpoint;
pub mod config;
pub mod ddp;
pub mod error;
pub mod folder;
pub mod init;
pub mod kernels;
pub mod label_cache;
pub mod launch;
pub mod loss;
pub mod optim;
pub mod pipeline;
pub mod plan;
pub mod procedure;
pub mod progress;
pub mod recipe;
pub mod resume;
pub mod run;
/// Learning-rate schedules: rtf-config's, with the optimiser settings they belong to.
pub use rtf_config::train::schedule;
pub mod setup;
pub mod step_log;
pub mod tensorboard;
pub mod trainer;

pub use config::{
    DatasetConfig, LossConfig, Modality, OptimizerConfig, OptimizerKind, PipelineConfig, Procedure,
    RunConfig, TrainConfig,
};
pub use error::TrainError;
pub use folder::TrainedRun;
pub use loss::Loss;
pub use optim::Optimizer;
pub use trainer::{train, EpochRecord, TrainOutcome};
