//! The errors of making a report: each names the file or the step it is about.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// A run folder (or a stage's) that cannot be read.
    #[error(transparent)]
    Run(#[from] rtf_run::RunError),
    /// An input file that is not what the report reads (a run folder's part, an eval file).
    #[error("{path}: {message}")]
    Input { path: PathBuf, message: String },
    /// `--out` names a file the report reads.
    #[error("--out {out}: is {input}, which the report reads; refusing to overwrite it")]
    Overwrite { out: PathBuf, input: PathBuf },
    /// No font to lay the charts' text out with.
    #[error("{0}")]
    Font(String),
    #[error("drawing a chart: {0}")]
    Chart(String),
    #[error("writing the page: {0}")]
    Format(#[from] std::fmt::Error),
    #[error("writing {path}: {message}")]
    Write { path: PathBuf, message: String },
}

impl ReportError {
    pub(crate) fn input(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        ReportError::Input {
            path: path.into(),
            message: message.into(),
        }
    }
}
