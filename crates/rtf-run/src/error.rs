//! The errors of reading a run folder: each names the file (and line) it is about.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The folder is not there, or holds no run.
    #[error("{path}: {message}")]
    Folder { path: PathBuf, message: String },
    /// A file of the run could not be read.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// `config.json` is not JSON, or not a configuration of the asked type.
    #[error("{path}: {message}")]
    Config { path: PathBuf, message: String },
    /// A line of `log.jsonl` is not an epoch record.
    #[error("{path}:{line}: {message}")]
    Log {
        path: PathBuf,
        /// 1-based.
        line: usize,
        message: String,
    },
}
