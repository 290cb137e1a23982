//! rtf-run: a run folder as `rtf train` writes it ([`mod@write`]: its lock, `config.json`, the
//! log), read back in one place, typed.
//!
//! A run folder holds `config.json` (written before the first step), `log.jsonl` (one
//! [`EpochRecord`] per finished epoch), `checkpoint.safetensors`, `best.safetensors` and
//! `final.safetensors` ([`files`]). A multi-stage run (HeatNet's teachers, two-stage training,
//! distillation) keeps each stage in an ordinary run folder `RUN/<stage>/` and lists the stages
//! in its own `config.json`.
//!
//! [`RunFolder::open`] reads a folder once: its configuration (the flat layout of older
//! builds and today's sections alike, typed by rtf-config's schema: [`RunFolder::config`],
//! one training's [`RunFolder::training`]; checked as a new run's is: [`TrainedRun`]), its
//! stages, its epochs and its weights. Every reader of a run folder (`rtf report`, `export`,
//! `train --resume`, `--teacher RUN`, `cargo xtask reproduce`, the Python package) goes
//! through it, so a renamed field is an error naming the file, not a silently empty chart.
//!
//! No libtorch here (nor in rtf-config's schema): xtask, which builds before libtorch exists,
//! reads run folders too.

mod error;
pub mod files;
mod folder;
pub mod log;
pub mod record;
mod settings;
pub mod trained;
pub mod write;

pub use error::RunError;
pub use files::{
    holds_run, BEST_FILE, CHECKPOINT_FILE, CONFIG_FILE, FINAL_FILE, LOCK_FILE, LOG_FILE,
};
pub use folder::{RunFolder, Weights};
pub use record::{EpochRecord, ValRecord};
pub use trained::{read_config, TrainedRun};
pub use write::{OwnedFolder, RunLock};
