//! Typed errors of rtf-calib: every message names the file or field at fault.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Rig { path: PathBuf, message: String },
    #[error("{path}: cannot decode image: {message}")]
    Image { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    BadFrame { path: PathBuf, message: String },
    #[error("only {usable} usable frame(s), at least {minimum} needed (skipped: {skipped})")]
    TooFewFrames {
        usable: usize,
        minimum: usize,
        skipped: String,
    },
    #[error("{path}: cannot write: {message}")]
    Write { path: PathBuf, message: String },
    #[error("invalid setting: {0}")]
    Setting(String),
    /// An output path that is an input of the rig (the message names both).
    #[error("{0}")]
    OverwritesInput(String),
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),
}

pub type Result<T> = std::result::Result<T, CalibError>;

impl CalibError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}
