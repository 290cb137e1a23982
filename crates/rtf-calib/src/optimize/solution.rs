//! What an optimiser run reports: [`Progress`] after each iteration, the [`Solution`] before
//! its assessment ([`crate::solve::Outcome`]) and the summary of the default recipe's
//! wrong-basin check ([`Restarts`], issue 12), which calib.yaml carries.

use crate::camera::Calibration;

/// Progress report after each optimiser iteration.
#[derive(Debug, Clone)]
pub struct Progress {
    pub stage: String,
    pub step: usize,
    pub total: usize,
    pub loss: f64,
}

#[derive(Debug, Clone)]
/// What an optimiser run found, before its assessment ([`crate::solve::Outcome`]).
pub struct Solution {
    pub initial: Calibration,
    pub calibration: Calibration,
    /// Final loss of the finest stage (mean squared blurred residual).
    pub loss: f64,
    pub frames_used: usize,
    pub iterations: usize,
    /// Why the optimiser stopped early (NaN, divergence), if it did; the best parameters are kept.
    pub stopped: Option<String>,
    /// Indices (into the frames given) of the frames the optimiser used.
    pub used: Vec<usize>,
    /// The wrong-basin check of the default recipe
    /// ([`Pipeline::restart`](super::Pipeline::restart)).
    pub restarts: Option<Restarts>,
}

/// The wrong-basin check of the default recipe
/// ([`Pipeline::restart`](super::Pipeline::restart)): the solution perturbed and refined
/// again from several starts.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Restarts {
    /// Solutions compared (the continued main solution and the perturbed restarts).
    pub count: usize,
    /// Rounds of restarts run (a second round runs around a clearly better solution).
    pub rounds: usize,
    /// Perturbation of the starts (full-resolution thermal px).
    pub perturbation_px: f64,
    /// Mean distance (px) between the main run's map and the chosen one (0: it stood).
    pub improved_px: f64,
    /// Relative cost drop from the main run's solution to the best restart.
    pub cost_drop: f64,
    /// Largest distance (px) from the best solution to any solution of about the same cost.
    pub spread_px: f64,
    /// False if the last round still found a clearly better, distinct solution.
    pub settled: bool,
}
