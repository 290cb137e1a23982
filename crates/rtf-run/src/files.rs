//! The files of a run folder, by name.

use std::path::Path;

/// The run's configuration, written before the first step.
pub const CONFIG_FILE: &str = "config.json";
/// One JSON line per finished epoch ([`crate::EpochRecord`]).
pub const LOG_FILE: &str = "log.jsonl";
/// Every trained network, optimisers and progress (rtf-train's `checkpoint`).
pub const CHECKPOINT_FILE: &str = "checkpoint.safetensors";
/// The student's weights at its best validation score.
pub const BEST_FILE: &str = "best.safetensors";
/// The student's weights after the last epoch.
pub const FINAL_FILE: &str = "final.safetensors";
/// Held while a process trains in the folder.
pub const LOCK_FILE: &str = "run.lock";

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
