//! The error every part of training returns. Its own module at the bottom of the crate's
//! layers: the run folder, the procedures, data-parallel training and the trainer all return
//! it, so none of them has to reach up into the trainer for it.

use std::path::PathBuf;

use rtf_data::DataError;
use rtf_eval::EvalError;
use rtf_models::ModelError;

use crate::checkpoint::CheckpointError;
use crate::config::ConfigError;

/// The data and evaluation errors are boxed: they are the largest, and every `Result` of
/// training carries this type.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Data(Box<DataError>),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Eval(Box<EvalError>),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Folder(#[from] rtf_run::RunError),
    #[error("{path}: {message}")]
    Run { path: PathBuf, message: String },
    #[error("{0}")]
    Config(String),
    #[error("invalid configuration: {0}")]
    Invalid(#[from] ConfigError),
    #[error(transparent)]
    Distributed(#[from] rtf_dist::DistError),
    #[error("training diverged at epoch {epoch}, step {step}: {what}")]
    Diverged {
        epoch: usize,
        step: u64,
        what: String,
    },
}

impl From<DataError> for TrainError {
    fn from(e: DataError) -> Self {
        TrainError::Data(Box::new(e))
    }
}

impl From<EvalError> for TrainError {
    fn from(e: EvalError) -> Self {
        TrainError::Eval(Box::new(e))
    }
}
