//! Outputs are written to a temporary file beside the target and renamed, so a crash or an
//! error never leaves a partial file under the final name.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum AtomicWriteError<E: std::fmt::Display + std::fmt::Debug> {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Write { path: PathBuf, source: E },
}

/// Calls `write` with a temporary path in the target's directory (same extension, so
/// format-by-extension writers still work), then renames it over `path`. On error the
/// temporary file is removed.
pub fn write_atomic<E, F>(path: &Path, write: F) -> Result<(), AtomicWriteError<E>>
where
    E: std::fmt::Display + std::fmt::Debug,
    F: FnOnce(&Path) -> Result<(), E>,
{
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|source| AtomicWriteError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let file_name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(
        ".{}.tmp-{}.{}",
        file_name,
        std::process::id(),
        extension(path)
    ));
    if let Err(source) = write(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(AtomicWriteError::Write {
            path: path.to_path_buf(),
            source,
        });
    }
    // Durable, not only atomic: the bytes reach the disk before the rename makes them the
    // file, and the rename itself reaches it before we return (a power cut keeps old or new).
    let synced = std::fs::File::open(&tmp).and_then(|f| f.sync_all());
    if let Err(source) = synced {
        let _ = std::fs::remove_file(&tmp);
        return Err(AtomicWriteError::Io {
            path: path.to_path_buf(),
            source,
        });
    }
    std::fs::rename(&tmp, path).map_err(|source| {
        let _ = std::fs::remove_file(&tmp);
        AtomicWriteError::Io {
            path: path.to_path_buf(),
            source,
        }
    })?;
    // Directories cannot be opened for syncing everywhere; where they can, sync this one.
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Convenience for byte contents.
pub fn write_bytes_atomic(
    path: &Path,
    bytes: &[u8],
) -> Result<(), AtomicWriteError<std::io::Error>> {
    write_atomic(path, |tmp| std::fs::write(tmp, bytes))
}

/// `path` made absolute through its deepest existing ancestor (symbolic links resolved), so
/// that two spellings of one file compare equal whether or not it exists yet. The part below
/// that ancestor does not exist, so it holds no links and its `..` and `.` are taken
/// lexically: `run/new-dir/../log.jsonl` is `run/log.jsonl`, which it becomes once the writer
/// creates `new-dir`.
pub fn resolved(path: &Path) -> PathBuf {
    let mut missing = Vec::new();
    let mut existing = path;
    let base = loop {
        if let Ok(canonical) = existing.canonicalize() {
            break canonical;
        }
        match (existing.parent(), existing.file_name()) {
            (Some(parent), Some(name)) => {
                missing.push(name.to_os_string());
                existing = parent;
            }
            // `..` or `.` as the last component: keep it for the lexical walk below.
            (Some(parent), None) => {
                missing.extend(
                    existing
                        .components()
                        .next_back()
                        .map(|c| c.as_os_str().to_os_string()),
                );
                existing = parent;
            }
            _ => break std::env::current_dir().unwrap_or_default(),
        }
        if existing.as_os_str().is_empty() {
            break std::env::current_dir().unwrap_or_default();
        }
    };
    missing.iter().rev().fold(base, |mut at, part| {
        match part.to_str() {
            Some("..") => {
                at.pop();
            }
            Some(".") => {}
            _ => at.push(part),
        }
        at
    })
}

fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_else(|| "tmp".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resolved_paths_compare_equal_through_missing_folders_dots_and_links() {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("run/log.jsonl");
        std::fs::create_dir_all(log.parent().unwrap()).unwrap();
        std::fs::write(&log, b"{}").unwrap();
        let real = resolved(&log);
        // Through a folder that does not exist yet: the writer creates it, then `..` leaves it.
        let through_missing = dir.path().join("run/new-dir/../log.jsonl");
        assert_eq!(resolved(&through_missing), real);
        let through_two = dir.path().join("run/a/b/../../././log.jsonl");
        assert_eq!(resolved(&through_two), real);
        // A file not written yet, under an existing folder, and one that leaves the missing part.
        let fresh = dir.path().join("run/missing/../new.html");
        assert_eq!(resolved(&fresh), real.parent().unwrap().join("new.html"));
        assert_ne!(resolved(&dir.path().join("run/missing/log.jsonl")), real);
        #[cfg(unix)]
        {
            let link = dir.path().join("link");
            std::os::unix::fs::symlink(dir.path().join("run"), &link).unwrap();
            assert_eq!(resolved(&link.join("x/../log.jsonl")), real);
        }
    }

    #[test]
    fn writes_and_renames() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.json");
        write_bytes_atomic(&target, b"{}").unwrap();
        assert_eq!(std::fs::read(&target).unwrap(), b"{}");
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "no temp file left"
        );
    }

    #[test]
    fn failure_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.bin");
        let r = write_atomic(&target, |tmp| {
            std::fs::write(tmp, b"partial").unwrap();
            Err::<(), _>("boom")
        });
        assert!(r.unwrap_err().to_string().contains("boom"));
        assert!(!target.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
