//! Atomic file output for the reproduction's results: every JSON, Markdown, CSV and PNG is
//! written to `<path>.tmp` and renamed, so an interrupted `cargo xtask reproduce` never leaves a
//! half-written result that a re-run would take for a finished one. Below every other module of
//! `reproduce` (cells, figure, report, speed and the driver all write through it).

use anyhow::{Context as _, Result};
use serde_json::Value;
use std::path::{Path, PathBuf};

/// Writes JSON (pretty-printed) through a temporary file and a rename.
pub fn write_json(path: &Path, v: &Value) -> Result<()> {
    write_atomic(path, serde_json::to_string_pretty(v)?.as_bytes())
}

/// Writes `bytes` to `<path>.tmp`, then renames it over `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_through_a_temporary_file_and_leaves_none_behind() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("t.json");
        std::fs::write(&path, "old").unwrap();
        write_json(&path, &serde_json::json!({"a": 1})).unwrap();
        let back: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        assert_eq!(back, serde_json::json!({"a": 1}));
        assert!(!tmp.path().join("t.json.tmp").exists());
        let missing = tmp.path().join("no-such-dir/t.md");
        let err = write_atomic(&missing, b"x").unwrap_err();
        assert!(format!("{err:#}").contains("no-such-dir"), "{err:#}");
    }
}
