//! The run folder: its files, its lock, its log. A run folder holds `config.json` (written
//! before the first step), `log.jsonl` (one record per epoch), `checkpoint.safetensors` (every
//! trained network, optimisers and progress; the log's records too, so a log line lost to a
//! kill is written back on resume), `best.safetensors` and `final.safetensors` (the student's
//! weights under reference names), and `run.lock` while a process trains in it.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::TrainError;

pub const CONFIG_FILE: &str = "config.json";
pub const LOG_FILE: &str = "log.jsonl";
pub const CHECKPOINT_FILE: &str = "checkpoint.safetensors";
pub const BEST_FILE: &str = "best.safetensors";
pub const FINAL_FILE: &str = "final.safetensors";
pub const LOCK_FILE: &str = "run.lock";

pub(crate) fn run_error(path: &Path, message: impl Into<String>) -> TrainError {
    TrainError::Run {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Files whose presence means a folder holds a run (a fresh start there would mix two runs).
pub fn holds_run(dir: &Path) -> bool {
    [
        CONFIG_FILE,
        LOG_FILE,
        CHECKPOINT_FILE,
        BEST_FILE,
        FINAL_FILE,
    ]
    .iter()
    .any(|f| dir.join(f).exists())
}

/// Exclusive ownership of a run folder for a process's lifetime: `run.lock` holds the owner's
/// pid and host. A lock whose process is gone (same host) is stale and taken over; a live one
/// is a clear error naming the holder.
#[derive(Debug)]
pub struct RunLock {
    path: PathBuf,
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_else(|_| "unknown-host".into())
}

fn pid_alive(pid: u32) -> bool {
    Path::new(&format!("/proc/{pid}")).exists()
}

impl RunLock {
    pub fn acquire(dir: &Path) -> Result<Self, TrainError> {
        let path = dir.join(LOCK_FILE);
        let me = format!("{} {}\n", std::process::id(), host_name());
        for _ in 0..2 {
            match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&path)
            {
                Ok(mut f) => {
                    f.write_all(me.as_bytes())
                        .and_then(|_| f.sync_all())
                        .map_err(|e| run_error(&path, format!("cannot write the lock: {e}")))?;
                    return Ok(Self { path });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let holder = std::fs::read_to_string(&path).unwrap_or_default();
                    let mut words = holder.split_whitespace();
                    let pid: Option<u32> = words.next().and_then(|p| p.parse().ok());
                    let host = words.next().unwrap_or("").to_string();
                    let stale = host == host_name() && pid.is_none_or(|p| !pid_alive(p));
                    if !stale {
                        return Err(run_error(
                            dir,
                            format!(
                                "another rtf process (pid {}, host {host}) is training in this \
                                 folder; wait for it, or remove {} if that process is gone",
                                pid.map_or("?".into(), |p| p.to_string()),
                                path.display()
                            ),
                        ));
                    }
                    eprintln!(
                        "{}: taking over a stale lock of pid {} (no longer running)",
                        path.display(),
                        pid.map_or("?".into(), |p| p.to_string())
                    );
                    std::fs::remove_file(&path).map_err(|e| {
                        run_error(&path, format!("cannot remove a stale lock: {e}"))
                    })?;
                }
                Err(e) => return Err(run_error(&path, format!("cannot create the lock: {e}"))),
            }
        }
        Err(run_error(&path, "could not take the lock"))
    }
}

impl Drop for RunLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Removes temporary files (`.<name>.tmp-<pid>.<ext>`, see `rtf_core::fsutil`) left in `dir` by
/// writers that died before their rename.
pub fn remove_orphan_temp_files(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(rest) = name.strip_prefix('.').and_then(|n| n.split(".tmp-").nth(1)) else {
            continue;
        };
        let pid: Option<u32> = rest.split('.').next().and_then(|p| p.parse().ok());
        if pid.is_some_and(|p| p != std::process::id() && !pid_alive(p)) {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

pub fn write_json_atomic<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), TrainError> {
    let json = serde_json::to_string_pretty(value).expect("serialises");
    rtf_core::write_bytes_atomic(path, json.as_bytes()).map_err(|e| run_error(path, e.to_string()))
}

/// Appends one JSON line to `log.jsonl` and syncs it.
pub fn append_log<T: serde::Serialize>(run_dir: &Path, record: &T) -> Result<(), TrainError> {
    let path = run_dir.join(LOG_FILE);
    let line = serde_json::to_string(record).expect("record serialises");
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .and_then(|mut f| {
            writeln!(f, "{line}")?;
            f.sync_data()
        })
        .map_err(|e| run_error(&path, format!("cannot append: {e}")))
}

/// Rewrites `log.jsonl` from the records a checkpoint carries (repairs a log that lost its last
/// line to a kill, or holds lines of epochs the checkpoint does not have).
pub fn rewrite_log(run_dir: &Path, records: &[serde_json::Value]) -> Result<(), TrainError> {
    let path = run_dir.join(LOG_FILE);
    let mut text = String::new();
    for r in records {
        text.push_str(&serde_json::to_string(r).expect("record serialises"));
        text.push('\n');
    }
    rtf_core::write_bytes_atomic(&path, text.as_bytes())
        .map_err(|e| run_error(&path, e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_is_refused_and_a_stale_one_taken_over() {
        let dir = tempfile::tempdir().unwrap();
        let lock = RunLock::acquire(dir.path()).unwrap();
        let err = RunLock::acquire(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains("another rtf process") && err.contains(&std::process::id().to_string()),
            "{err}"
        );
        drop(lock);
        assert!(!dir.path().join(LOCK_FILE).exists());
        // A lock left by a process that is gone (pid beyond pid_max) is stale.
        std::fs::write(
            dir.path().join(LOCK_FILE),
            format!("4194999 {}\n", host_name()),
        )
        .unwrap();
        let _lock = RunLock::acquire(dir.path()).unwrap();
    }

    #[test]
    fn orphan_temp_files_of_dead_writers_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let dead = dir
            .path()
            .join(".checkpoint.safetensors.tmp-4194999.safetensors");
        let mine = dir
            .path()
            .join(format!(".log.jsonl.tmp-{}.jsonl", std::process::id()));
        let other = dir.path().join("notes.tmp-1.txt");
        for p in [&dead, &mine, &other] {
            std::fs::write(p, b"x").unwrap();
        }
        remove_orphan_temp_files(dir.path());
        assert!(!dead.exists());
        assert!(mine.exists() && other.exists());
    }
}
