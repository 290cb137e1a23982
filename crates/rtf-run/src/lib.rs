//! rtf-run: a run folder as `rtf train` writes it ([`write`]: its lock, `config.json`, the
//! log), read back in one place, typed.
//!
//! A run folder holds `config.json` (written before the first step), `log.jsonl` (one
//! [`EpochRecord`] per finished epoch), `checkpoint.safetensors`, `best.safetensors` and
//! `final.safetensors` ([`files`]). A multi-stage run (HeatNet's teachers, two-stage training,
//! distillation) keeps each stage in an ordinary run folder `RUN/<stage>/` and lists the stages
//! in its own `config.json`.
//!
//! [`RunFolder::open`] reads a folder once: its configuration document (the flat layout of
//! older builds and today's sections alike; the typed configuration is rtf-train's, parsed
//! through [`RunFolder::config`]; what a reader needs of it without those types, through
//! [`RunFolder::training`]), its stages, its epochs and its weights. Every reader of a
//! run folder (`rtf report`, `export`, `train --resume`, `cargo xtask reproduce`) goes through
//! it, so a renamed field is an error naming the file, not a silently empty chart.
//!
//! No libtorch here: xtask, which builds before libtorch exists, reads run folders too. The
//! typed configuration (`TrainConfig`, its networks and datasets) lives with the code that
//! trains it (rtf-train), which builds on this crate.

mod error;
pub mod files;
mod folder;
pub mod log;
pub mod record;
mod settings;
pub mod view;
pub mod write;

pub use error::RunError;
pub use files::{
    holds_run, BEST_FILE, CHECKPOINT_FILE, CONFIG_FILE, FINAL_FILE, LOCK_FILE, LOG_FILE,
};
pub use folder::{RunFolder, Weights};
pub use record::{EpochRecord, ValRecord};
pub use view::{DatasetView, TrainingView};
pub use write::{OwnedFolder, RunLock};
