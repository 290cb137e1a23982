//! Learning-rate schedules: the papers' per-epoch step decay (MFNet, RTFNet, HeatNet) and CMX's
//! per-step linear warm-up then polynomial decay (huaaaliu/RGBX_Semantic_Segmentation,
//! `utils/lr_policy.py` `WarmUpPolyLR`, driven by `train.py` over
//! `nepochs × niters_per_epoch` iterations with `niters_per_epoch × warm_up_epoch` warm-up
//! iterations).

use serde::{Deserialize, Serialize};

/// How the learning rate moves over a run (in [`super::OptimizerConfig`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LrSchedule {
    /// `lr × lr_decay^⌊epoch / decay_every⌋`, constant within an epoch (MFNet: ×0.94 every
    /// epoch; HeatNet: ×0.5 every 30).
    #[default]
    StepDecay,
    /// CMX: per step `i` of `N = epochs × steps per epoch`, with `W = warmup_epochs × steps per
    /// epoch`: `lr · i / W` while `i < W`, then `lr · (1 − i / N)^power` (official: power 0.9,
    /// 10 warm-up epochs). The rate is set before each step from its own index; the official
    /// loop sets it after each step from that step's index, so its first step runs at the base
    /// rate and every later one at the rate of the step before.
    WarmupPoly { power: f64, warmup_epochs: usize },
}

impl LrSchedule {
    pub fn is_step_decay(&self) -> bool {
        *self == LrSchedule::StepDecay
    }

    /// CMX's: power 0.9 after 10 warm-up epochs (`config.py`: `lr_power`, `warm_up_epoch`).
    pub fn cmx_code() -> Self {
        LrSchedule::WarmupPoly {
            power: 0.9,
            warmup_epochs: 10,
        }
    }
}

/// Where a step is in its run: what a per-step schedule needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepAt {
    /// 0-based epoch.
    pub epoch: usize,
    /// 0-based step inside the epoch.
    pub step: usize,
    pub steps_per_epoch: usize,
    /// Epochs of the whole run.
    pub epochs: usize,
}

impl StepAt {
    /// The first step of `epoch`, for callers that count epochs only (a per-epoch schedule's
    /// rate; the whole run taken as ending with that epoch, one step each).
    pub fn start_of(epoch: usize) -> Self {
        Self {
            epoch,
            step: 0,
            steps_per_epoch: 1,
            epochs: epoch + 1,
        }
    }

    /// The step's 0-based index in the run.
    pub fn global(&self) -> usize {
        self.epoch * self.steps_per_epoch + self.step
    }

    /// Steps of the whole run.
    pub fn total(&self) -> usize {
        self.epochs * self.steps_per_epoch
    }
}

/// `WarmUpPolyLR.get_lr(iteration)` for a `base` rate: linear from 0 over `warmup` steps, then
/// `(1 − iteration / total)^power` (0 at or past the end).
pub fn warmup_poly(base: f64, power: f64, warmup: usize, total: usize, iteration: usize) -> f64 {
    if iteration < warmup {
        return base * iteration as f64 / warmup as f64;
    }
    let left = 1.0 - iteration as f64 / total.max(1) as f64;
    base * left.max(0.0).powf(power)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The official rule (`lr_policy.py`) written out: 10 warm-up epochs of 99 steps, 500
    /// epochs (the official MF run's 49,500 iterations).
    #[test]
    fn warmup_then_poly_follows_the_official_policy() {
        let (base, warmup, total) = (6e-5, 990, 49_500);
        let at = |i| warmup_poly(base, 0.9, warmup, total, i);
        assert_eq!(at(0), 0.0);
        assert!(
            (at(495) - 3e-5).abs() < 1e-18,
            "half-way through the warm-up"
        );
        let poly = |i: usize| base * (1.0 - i as f64 / total as f64).powf(0.9);
        for i in [990, 1000, 20_000, 49_499] {
            assert!((at(i) - poly(i)).abs() < 1e-18, "step {i}");
        }
        // Not continuous: the poly branch starts at its own value, below the warm-up's last.
        assert!(at(989) > at(990) && at(990) > 0.98 * base);
        assert_eq!(at(49_500), 0.0);
        assert_eq!(warmup_poly(base, 0.9, 0, 10, 0), base, "no warm-up");
    }

    #[test]
    fn step_positions_count_the_run() {
        let at = StepAt {
            epoch: 2,
            step: 3,
            steps_per_epoch: 5,
            epochs: 4,
        };
        assert_eq!((at.global(), at.total()), (13, 20));
        assert_eq!(StepAt::start_of(7).global(), 7);
    }

    #[test]
    fn schedules_round_trip_and_default_to_step_decay() {
        let cmx = LrSchedule::cmx_code();
        let json = serde_json::to_string(&cmx).unwrap();
        assert_eq!(
            json,
            r#"{"kind":"warmup_poly","power":0.9,"warmup_epochs":10}"#
        );
        assert_eq!(serde_json::from_str::<LrSchedule>(&json).unwrap(), cmx);
        assert!(LrSchedule::default().is_step_decay());
    }
}
