//! rtf-eval: metrics (confusion matrix, per-class Acc/IoU in the papers' conventions),
//! evaluation of any network on a split, figures.

pub mod class_map;
pub mod device;
pub mod evaluate;
pub mod figure;
pub mod kernels;
pub mod metrics;
pub mod predict;
pub mod scores_file;
pub mod speed;

/// Schema tag of the scores `rtf eval --json` writes (`rtf report` checks it).
pub const EVAL_SCHEMA: &str = "rtf-eval/1";

/// Whole image, sliding windows, scales and flip (a part of [`evaluate`]).
pub use evaluate::inference;

pub use class_map::{ClassMap, ClassMapError, ClassMapScores, ClassMapping, OtherPixels};
pub use evaluate::{
    evaluate, evaluate_mapped, evaluate_with_drop, DropFill, EvalError, EvalOptions, EvalReport,
    Modality, ModalityDrop,
};
pub use inference::{Inference, InferenceOptions};
pub use metrics::{ClassScore, ConfusionMatrix, Scores};

/// Resident memory is process-wide: a test that estimates a forward pass's memory from it
/// (evaluate::estimate_forward_bytes) and a test that allocates a lot at once hold this, so
/// that neither runs while the other measures.
#[cfg(test)]
pub(crate) fn memory_lock() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// libtorch's generator is process-wide: a test that seeds it and expects the same draws
/// holds this while it draws, so tests running in parallel cannot interleave theirs.
#[cfg(test)]
pub(crate) fn seeded_rng_lock() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}
