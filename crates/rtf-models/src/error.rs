//! Typed errors of rtf-models; every message names the file or the network it is about.

use std::path::PathBuf;

/// A tensor whose shape in a weights file differs from the network's.
#[derive(Debug, Clone, PartialEq)]
pub struct ShapeMismatch {
    pub name: String,
    pub expected: Vec<i64>,
    pub found: Vec<i64>,
}

impl std::fmt::Display for ShapeMismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} (network {:?}, file {:?})",
            self.name, self.expected, self.found
        )
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("unknown model {name:?}; known models: {known}")]
    UnknownModel { name: String, known: String },
    #[error("invalid {network} configuration: {reason}")]
    InvalidConfig { network: String, reason: String },
    #[error("{network}: input of shape {shape:?} is invalid: {reason}")]
    InvalidInput {
        network: String,
        shape: Vec<i64>,
        reason: String,
    },
    #[error("{}: cannot read weights: {message}", path.display())]
    Read { path: PathBuf, message: String },
    #[error("{}: cannot write weights: {message}", path.display())]
    Write { path: PathBuf, message: String },
    #[error("{}: weights do not match the network:{}", path.display(), describe_mismatch(missing, unexpected, mismatched))]
    Mismatch {
        path: PathBuf,
        missing: Vec<String>,
        unexpected: Vec<String>,
        mismatched: Vec<ShapeMismatch>,
    },
    #[error("{}: tensor `{name}`: {message}", path.display())]
    BadTensor {
        path: PathBuf,
        name: String,
        message: String,
    },
    #[error(
        "{}: these weights were saved for `{saved}` but `{requested}` was asked for (variants \
         can share tensor names, so they would load silently); pass the right --model, or \
         --foreign-weights to load them anyway",
        path.display()
    )]
    WrongModel {
        path: PathBuf,
        saved: String,
        requested: String,
    },
    #[error(
        "{}: the network was trained on `{saved}` inputs; --inputs {asked} would score it on \
         others (drop --inputs, use --drop for missing-modality scores, or --foreign-weights to \
         force it)",
        path.display()
    )]
    InputsContradict {
        path: PathBuf,
        saved: String,
        asked: String,
    },
    #[error("{context}: {source}")]
    Torch {
        context: String,
        source: tch::TchError,
    },
}

fn describe_mismatch(
    missing: &[String],
    unexpected: &[String],
    mismatched: &[ShapeMismatch],
) -> String {
    let mut out = String::new();
    if !missing.is_empty() {
        out.push_str(&format!(
            "\n  missing ({}): {}",
            missing.len(),
            missing.join(", ")
        ));
    }
    if !unexpected.is_empty() {
        out.push_str(&format!(
            "\n  unexpected ({}): {}",
            unexpected.len(),
            unexpected.join(", ")
        ));
    }
    if !mismatched.is_empty() {
        let list: Vec<String> = mismatched.iter().map(|m| m.to_string()).collect();
        out.push_str(&format!(
            "\n  shape mismatch ({}): {}",
            mismatched.len(),
            list.join(", ")
        ));
    }
    out
}

/// `Ok` when a strict load found nothing missing, unexpected or misshaped; otherwise the
/// [`ModelError::Mismatch`] naming `path` and every such tensor.
pub(crate) fn check_names(
    path: &std::path::Path,
    missing: Vec<String>,
    unexpected: Vec<String>,
    mismatched: Vec<ShapeMismatch>,
) -> Result<(), ModelError> {
    if missing.is_empty() && unexpected.is_empty() && mismatched.is_empty() {
        return Ok(());
    }
    Err(ModelError::Mismatch {
        path: path.to_path_buf(),
        missing,
        unexpected,
        mismatched,
    })
}

/// A network configuration's error (rtf-config) as the networks' own.
impl From<rtf_config::network::NetworkConfigError> for ModelError {
    fn from(e: rtf_config::network::NetworkConfigError) -> Self {
        use rtf_config::network::NetworkConfigError as E;
        match e {
            E::Unknown { name, known } => ModelError::UnknownModel { name, known },
            E::Invalid { network, reason } => ModelError::InvalidConfig { network, reason },
        }
    }
}
