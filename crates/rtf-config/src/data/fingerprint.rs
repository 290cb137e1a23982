//! A dataset's content fingerprint as results record it (a run's config.json, eval JSON):
//! rtf-data's `fingerprint` computes it.

use serde::{Deserialize, Serialize};

use super::DatasetFormat;

/// The hash algorithm named in every fingerprint.
pub const ALGORITHM: &str = "sha256";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SplitFingerprint {
    pub name: String,
    pub frames: usize,
    /// Hex SHA-256 over the split's frames (module docs).
    pub hash: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fingerprint {
    pub format: DatasetFormat,
    pub algorithm: String,
    /// Hex SHA-256 over every split's name and hash.
    pub hash: String,
    pub splits: Vec<SplitFingerprint>,
    /// Distinct files hashed and their total size.
    pub files: usize,
    pub bytes: u64,
}

impl Fingerprint {
    /// The split named `name`, if the dataset has it.
    pub fn split(&self, name: &str) -> Option<&SplitFingerprint> {
        self.splits.iter().find(|s| s.name == name)
    }
}
