//! rtf-eval: metrics (confusion matrix, per-class Acc/IoU in the papers' conventions),
//! evaluation of any network on a split, figures.

pub mod evaluate;
pub mod figure;
pub mod metrics;
pub mod speed;

pub use evaluate::{
    evaluate, evaluate_with_drop, DropFill, EvalError, EvalOptions, EvalReport, Modality,
    ModalityDrop,
};
pub use metrics::{ClassScore, ConfusionMatrix, Scores};
