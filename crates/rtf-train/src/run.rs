//! The run folder as the trainer writes it: its lock, its config and log. A run folder holds
//! `config.json` (written before the first step), `log.jsonl` (one record per epoch),
//! `checkpoint.safetensors` (every trained network, optimisers and progress; the last epoch's
//! log record too, so a log line lost to a kill is written back on resume), `best.safetensors`
//! and `final.safetensors` (the student's weights under reference names), and `run.lock` while
//! a process trains in it. Its files are named, written and read back by rtf-run's run folder
//! ([`rtf_run::RunFolder`], [`rtf_run::write`]); this module names them for the trainer.

use std::path::Path;

use crate::error::TrainError;

pub use rtf_run::files::{
    holds_run, BEST_FILE, CHECKPOINT_FILE, CONFIG_FILE, FINAL_FILE, LOCK_FILE, LOG_FILE,
};
pub use rtf_run::write::{
    append_log, read_log, remove_orphan_temp_files, restore_log, write_json_atomic, RunLock,
};

pub(crate) fn run_error(path: &Path, message: impl Into<String>) -> TrainError {
    TrainError::Run {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use rtf_run::EpochRecord;

    /// A log record of `epoch` (training loss 0.1 + epoch).
    pub(crate) fn record(epoch: usize) -> EpochRecord {
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
}
