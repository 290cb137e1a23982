//! A run folder written: opened for writing by the one process that owns it
//! ([`OwnedFolder`]: created, locked with [`RunLock`], orphaned temp files removed), its
//! `config.json` written atomically, and its `log.jsonl` appended to and restored on resume.
//! rtf-train writes through here what [`crate::RunFolder`] reads back.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::RunError;
use crate::files::{holds_run, CONFIG_FILE, LOCK_FILE, LOG_FILE};
use crate::log::line_epoch;
use crate::record::EpochRecord;

fn run_error(path: &Path, message: impl Into<String>) -> RunError {
    RunError::Folder {
        path: path.to_path_buf(),
        message: message.into(),
    }
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
    pub fn acquire(dir: &Path) -> Result<Self, RunError> {
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

/// Refuses to start a new run in `dir` where it already holds one (a fresh start there would
/// mix two runs); a resume continues it instead.
pub fn refuse_existing_run(dir: &Path) -> Result<(), RunError> {
    match holds_run(dir) {
        true => Err(run_error(
            dir,
            "already holds a run; use --resume to continue it or choose another output folder",
        )),
        false => Ok(()),
    }
}

/// A run folder opened for writing by the process that owns it, for as long as the value
/// lives: the folder created if absent, its lock held ([`RunLock`]), temporary files of dead
/// writers removed. The trainer writes a run's files through it; a multi-stage run's own
/// folder (its `config.json` listing the stages) is owned so too.
#[derive(Debug)]
pub struct OwnedFolder {
    dir: PathBuf,
    _lock: RunLock,
}

impl OwnedFolder {
    /// Creates `dir` if absent and takes its lock. Whether a run may start there is the
    /// caller's check ([`refuse_existing_run`] for a new run).
    pub fn open(dir: &Path) -> Result<Self, RunError> {
        std::fs::create_dir_all(dir).map_err(|e| run_error(dir, format!("cannot create: {e}")))?;
        let lock = RunLock::acquire(dir)?;
        remove_orphan_temp_files(dir);
        Ok(Self {
            dir: dir.to_path_buf(),
            _lock: lock,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes the run's `config.json` atomically.
    pub fn write_config<T: serde::Serialize>(&self, config: &T) -> Result<(), RunError> {
        write_json_atomic(&self.dir.join(CONFIG_FILE), config)
    }

    /// Appends one epoch's record to `log.jsonl` ([`append_log`]).
    pub fn append_log<T: serde::Serialize>(&self, record: &T) -> Result<(), RunError> {
        append_log(&self.dir, record)
    }

    /// Restores `log.jsonl` on resume ([`restore_log`]).
    pub fn restore_log(
        &self,
        epochs_done: usize,
        carried: &[EpochRecord],
    ) -> Result<Vec<usize>, RunError> {
        restore_log(&self.dir, epochs_done, carried)
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

pub fn write_json_atomic<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), RunError> {
    let json = serde_json::to_string_pretty(value).expect("serialises");
    rtf_core::write_bytes_atomic(path, json.as_bytes()).map_err(|e| run_error(path, e.to_string()))
}

/// Appends one JSON line to `log.jsonl` and syncs it.
pub fn append_log<T: serde::Serialize>(run_dir: &Path, record: &T) -> Result<(), RunError> {
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

/// The text of `log.jsonl` (empty before the first epoch has ended: no log yet).
pub fn read_log(run_dir: &Path) -> Result<String, RunError> {
    let path = run_dir.join(LOG_FILE);
    match std::fs::read_to_string(&path) {
        Ok(text) => Ok(text),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(String::new()),
        Err(e) => Err(run_error(&path, format!("cannot read: {e}"))),
    }
}

/// Restores `log.jsonl` on resume to the epochs a checkpoint has done. The checkpoint carries
/// only its last finished epoch's record (the log is appended after the checkpoint's rename,
/// so a kill between the two loses at most that line; carrying every record made memory and
/// the checkpoint grow with each epoch, issue 30). The log keeps its own lines of the epochs
/// before the carried ones, in order; lines of later epochs (a log ahead of its checkpoint),
/// duplicates and unreadable lines go; the carried records follow. Returns the epochs before
/// the carried records that the log lacked (edited or truncated by hand): they cannot come back.
pub fn restore_log(
    run_dir: &Path,
    epochs_done: usize,
    carried: &[EpochRecord],
) -> Result<Vec<usize>, RunError> {
    let path = run_dir.join(LOG_FILE);
    let first_carried = carried.first().map_or(epochs_done, |r| r.epoch);
    let old = read_log(run_dir)?;
    let mut text = String::new();
    let mut kept = Vec::new();
    for line in old.lines() {
        let epoch = line_epoch(line);
        if let Some(epoch) = epoch.filter(|&e| e < first_carried && kept.last() < Some(&e)) {
            kept.push(epoch);
            text.push_str(line);
            text.push('\n');
        }
    }
    for r in carried {
        text.push_str(&serde_json::to_string(r).expect("record serialises"));
        text.push('\n');
    }
    rtf_core::write_bytes_atomic(&path, text.as_bytes())
        .map_err(|e| run_error(&path, e.to_string()))?;
    Ok((0..first_carried).filter(|e| !kept.contains(e)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A log record of `epoch` (training loss 0.1 + epoch).
    fn record(epoch: usize) -> EpochRecord {
        EpochRecord {
            epoch,
            lr: 0.01,
            train_loss: 0.1 + epoch as f64,
            images: 2,
            seconds: 1.0,
            images_per_s: 2.0,
            data_wait_fraction: 0.0,
            val_miou: None,
            val_macc: None,
            losses: Default::default(),
            lrs: Default::default(),
            metrics: Default::default(),
            val: None,
        }
    }

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
    fn an_owned_folder_is_created_locked_and_refuses_a_second_owner() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("run");
        refuse_existing_run(&dir).unwrap();
        let owned = OwnedFolder::open(&dir).unwrap();
        assert!(dir.join(LOCK_FILE).exists());
        let err = OwnedFolder::open(&dir).unwrap_err().to_string();
        assert!(err.contains("another rtf process"), "{err}");
        owned.write_config(&serde_json::json!({"seed": 1})).unwrap();
        owned.append_log(&record(0)).unwrap();
        let err = refuse_existing_run(&dir).unwrap_err().to_string();
        assert!(
            err.contains("already holds a run") && err.contains("run"),
            "{err}"
        );
        drop(owned);
        assert!(!dir.join(LOCK_FILE).exists());
        assert_eq!(log_epochs(&dir), [0]);
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
    fn log_epochs(dir: &Path) -> Vec<usize> {
        let log = crate::log::read(&dir.join(LOG_FILE)).unwrap();
        log.iter().map(|r| r.epoch).collect()
    }

    #[test]
    fn the_log_is_restored_to_the_checkpoint_from_its_lines_and_the_carried_record() {
        let dir = tempfile::tempdir().unwrap();
        let log =
            |lines: &[String]| std::fs::write(dir.path().join(LOG_FILE), lines.join("\n")).unwrap();
        let line = |e: usize| serde_json::to_string(&record(e)).unwrap();
        // A kill between the checkpoint (3 epochs done) and the log's append of epoch 2.
        log(&[line(0), line(1)]);
        let lacking = restore_log(dir.path(), 3, &[record(2)]).unwrap();
        assert_eq!((log_epochs(dir.path()), lacking), (vec![0, 1, 2], vec![]));
        // A log ahead of its checkpoint, a garbage line and a duplicate: those lines go.
        log(&[
            line(0),
            "{not json".into(),
            line(0),
            line(1),
            line(2),
            line(3),
        ]);
        restore_log(dir.path(), 3, &[record(2)]).unwrap();
        assert_eq!(log_epochs(dir.path()), [0, 1, 2]);
        // A log that lost an early line by hand: the gap is reported, not invented.
        log(&[line(1)]);
        let lacking = restore_log(dir.path(), 3, &[record(2)]).unwrap();
        assert_eq!((log_epochs(dir.path()), lacking), (vec![1, 2], vec![0]));
        // A checkpoint of an older version carries every record: they replace the log.
        log(&[line(0)]);
        restore_log(dir.path(), 2, &[record(0), record(1)]).unwrap();
        assert_eq!(log_epochs(dir.path()), [0, 1]);
        // The kept lines stay as they were written, to the last bit.
        let exact = r#"{"epoch":0,"train_loss":0.30000000000000004}"#;
        std::fs::write(dir.path().join(LOG_FILE), format!("{exact}\n")).unwrap();
        restore_log(dir.path(), 2, &[record(1)]).unwrap();
        let text = std::fs::read_to_string(dir.path().join(LOG_FILE)).unwrap();
        assert_eq!(text.lines().next(), Some(exact));
    }
}
