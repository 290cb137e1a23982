//! rtf-train: one supervised training loop for any network and loss, writing a run folder
//! (config before the first step, a JSON-lines log, atomic checkpoints) that `--resume`
//! continues exactly.

pub mod checkpoint;
pub mod config;
pub mod loss;
pub mod optim;
pub mod tensorboard;
pub mod trainer;

pub use config::{DatasetConfig, LossConfig, OptimizerConfig, OptimizerKind, TrainConfig};
pub use loss::Loss;
pub use optim::Optimizer;
pub use trainer::{train, EpochRecord, TrainError, TrainOutcome};
