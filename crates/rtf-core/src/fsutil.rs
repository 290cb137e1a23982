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

fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_else(|| "tmp".into())
}

#[cfg(test)]
mod tests {
    use super::*;

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
