//! Typed errors of rtf-data. Every variant names the file (or directory) at fault.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not a readable PNG: {message}")]
    Png { path: PathBuf, message: String },
    #[error("{path}: expected {expected} channel(s) ({what}), found {found}")]
    Channels {
        path: PathBuf,
        what: &'static str,
        expected: String,
        found: usize,
    },
    #[error("{path}: expected {expected}-bit samples, found {found}-bit")]
    BitDepth {
        path: PathBuf,
        expected: String,
        found: u8,
    },
    #[error("{label}: label is {label_w}x{label_h} but image {image} is {image_w}x{image_h}")]
    SizeMismatch {
        image: PathBuf,
        label: PathBuf,
        image_w: usize,
        image_h: usize,
        label_w: usize,
        label_h: usize,
    },
    #[error("{path}: label id {id} at (x {x}, y {y}) is not a class id (the {class_set} set has {classes} classes{ignore})")]
    LabelOutOfRange {
        path: PathBuf,
        id: u16,
        x: usize,
        y: usize,
        class_set: String,
        classes: usize,
        ignore: String,
    },
    #[error("{split_file}, line {line}: frame '{name}' is missing: {missing} does not exist")]
    MissingFrame {
        split_file: PathBuf,
        line: usize,
        name: String,
        missing: PathBuf,
    },
    #[error("{path}: split is empty (no frame names)")]
    EmptySplit { path: PathBuf },
    #[error("{root}: {message}")]
    Layout { root: PathBuf, message: String },
    #[error("{root}: no split '{name}' (available: {available})")]
    UnknownSplit {
        root: PathBuf,
        name: String,
        available: String,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error("{path}: {bits}-bit thermal needs a normalisation: give `thermal: {{range: [lo, hi]}}` or `thermal: {{percentile: [1, 99]}}` (or min_max: true) in dataset.yaml")]
    ThermalNormalisation { path: PathBuf, bits: u8 },
    /// A dataset.yaml (or a built-in layout) that cannot be used; `message` starts with the
    /// line when the problem has one.
    #[error("{path}: {message}")]
    Description { path: PathBuf, message: String },
    #[error("{path}: colour [{}, {}, {}] at (x {x}, y {y}) is not in the palette of the {class_set} class set", color[0], color[1], color[2])]
    LabelColor {
        path: PathBuf,
        color: [u8; 3],
        x: usize,
        y: usize,
        class_set: String,
    },
    #[error("{path}: no {what} partner: {partner} does not exist")]
    MissingPartner {
        path: PathBuf,
        what: &'static str,
        partner: PathBuf,
    },
    #[error("{partner}: is {partner_w}x{partner_h} but its partner {path} is {w}x{h}")]
    PartnerSize {
        path: PathBuf,
        partner: PathBuf,
        w: usize,
        h: usize,
        partner_w: usize,
        partner_h: usize,
    },
    /// Weights (or a run) trained on one class set, data with another.
    #[error("{weights}: trained on {trained}, but {data} has {found}: {hint}")]
    ClassSetMismatch {
        weights: PathBuf,
        data: PathBuf,
        trained: String,
        found: String,
        hint: String,
    },
    #[error("invalid configuration: {0}")]
    Config(String),
    #[error("frame '{name}': {message}")]
    Frame { name: String, message: String },
    #[error("tensor: {0}")]
    Tensor(#[from] tch::TchError),
    #[error("{path}: cannot write: {message}")]
    Write { path: PathBuf, message: String },
    #[error("data loader worker stopped unexpectedly")]
    WorkerGone,
}

impl DataError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}

impl<E: std::fmt::Display + std::fmt::Debug> From<rtf_core::AtomicWriteError<E>> for DataError {
    fn from(e: rtf_core::AtomicWriteError<E>) -> Self {
        match e {
            rtf_core::AtomicWriteError::Io { path, source } => Self::Io { path, source },
            rtf_core::AtomicWriteError::Write { path, source } => Self::Write {
                path,
                message: source.to_string(),
            },
        }
    }
}
