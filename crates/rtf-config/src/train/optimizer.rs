//! The optimiser: update rules ([`OptimizerKind`]), weight decay's scope ([`DecayScope`]),
//! [`OptimizerConfig`] with the papers' presets, its learning rate per step, and its checks.
use serde::{Deserialize, Serialize};

use super::{one, ConfigError, LrSchedule, StepAt};

/// Which update rule rtf-train's optimiser applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OptimizerKind {
    /// SGD with momentum (MFNet, RTFNet).
    #[default]
    Sgd,
    /// RMSprop (HeatNet).
    Rmsprop,
    /// AdamW (CMX): Adam with weight decay decoupled from the gradient.
    Adamw,
}

impl OptimizerKind {
    /// `sgd`, `rmsprop` or `adamw` (command-line flags).
    pub fn parse(text: &str) -> Result<Self, String> {
        match text {
            "sgd" => Ok(OptimizerKind::Sgd),
            "rmsprop" => Ok(OptimizerKind::Rmsprop),
            "adamw" => Ok(OptimizerKind::Adamw),
            other => Err(format!(
                "unknown optimizer `{other}` (expected sgd, rmsprop or adamw)"
            )),
        }
    }
}

/// Which trainable tensors weight decay applies to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DecayScope {
    /// Every trainable tensor (PyTorch's optimisers given `model.parameters()`).
    #[default]
    All,
    /// Convolution and linear weights only, none on normalisation layers' weights nor on any
    /// bias (CMX: `utils/init_func.py` `group_weight`, whose no-decay group holds the biases
    /// and every BatchNorm/LayerNorm/GroupNorm parameter). Decided by shape: a tensor decays
    /// when it has two or more dimensions. Convolution and linear weights are the only such
    /// trainable tensors of rtf's networks; norm weights and biases are 1-D.
    ConvAndLinearWeights,
}

impl DecayScope {
    pub fn is_all(&self) -> bool {
        *self == DecayScope::All
    }

    /// Whether weight decay applies to a parameter of `dims` dimensions.
    pub fn decays(self, dims: usize) -> bool {
        match self {
            DecayScope::All => true,
            DecayScope::ConvAndLinearWeights => dims >= 2,
        }
    }
}

/// Optimiser and learning-rate schedule. With the default [`LrSchedule::StepDecay`] the rate is
/// multiplied by `lr_decay` every `decay_every` epochs (MFNet: ×0.94 every epoch; HeatNet: ×0.5
/// every 30). SGD reads `momentum`; RMSprop `momentum`, `alpha`, `eps`; AdamW `betas`, `eps`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizerConfig {
    #[serde(default)]
    pub kind: OptimizerKind,
    pub lr: f64,
    pub momentum: f64,
    pub weight_decay: f64,
    pub lr_decay: f64,
    #[serde(default = "one")]
    pub decay_every: usize,
    /// RMSprop's smoothing constant (PyTorch: 0.99).
    #[serde(default = "rmsprop_alpha")]
    pub alpha: f64,
    /// RMSprop's and AdamW's denominator term (PyTorch: 1e-8 both).
    #[serde(default = "rmsprop_eps")]
    pub eps: f64,
    /// AdamW's (β1, β2) (PyTorch's and CMX's: 0.9, 0.999). Written only when not those.
    #[serde(default = "adam_betas", skip_serializing_if = "is_adam_betas")]
    pub betas: (f64, f64),
    /// Which tensors `weight_decay` applies to. Written only when not all.
    #[serde(default, skip_serializing_if = "DecayScope::is_all")]
    pub decay_scope: DecayScope,
    /// The learning-rate schedule. Written only when not the per-epoch step decay.
    #[serde(default, skip_serializing_if = "LrSchedule::is_step_decay")]
    pub schedule: LrSchedule,
}

fn rmsprop_alpha() -> f64 {
    0.99
}
fn rmsprop_eps() -> f64 {
    1e-8
}
fn adam_betas() -> (f64, f64) {
    (0.9, 0.999)
}
fn is_adam_betas(betas: &(f64, f64)) -> bool {
    *betas == adam_betas()
}

impl OptimizerConfig {
    /// MFNet paper: SGD, lr 0.01, momentum 0.9, weight decay 5e-4, ×0.94 per epoch.
    pub fn mfnet_paper() -> Self {
        Self {
            kind: OptimizerKind::Sgd,
            lr: 0.01,
            momentum: 0.9,
            weight_decay: 5e-4,
            lr_decay: 0.94,
            decay_every: 1,
            alpha: rmsprop_alpha(),
            eps: rmsprop_eps(),
            betas: adam_betas(),
            decay_scope: DecayScope::All,
            schedule: LrSchedule::StepDecay,
        }
    }

    /// HeatNet paper (spec §5): RMSprop, lr 1e-4, halved every 30 epochs; PyTorch's RMSprop
    /// defaults otherwise (no momentum, no weight decay).
    pub fn heatnet_paper() -> Self {
        Self {
            kind: OptimizerKind::Rmsprop,
            lr: 1e-4,
            momentum: 0.0,
            weight_decay: 0.0,
            lr_decay: 0.5,
            decay_every: 30,
            ..Self::mfnet_paper()
        }
    }

    /// CMX's official training (huaaaliu/RGBX_Semantic_Segmentation: `config.py`, `train.py`,
    /// `utils/init_func.py` `group_weight`): AdamW, lr 6e-5, betas (0.9, 0.999), eps 1e-8,
    /// weight decay 0.01 on convolution and linear weights only, linear warm-up over 10 epochs
    /// then poly decay with power 0.9 per step. `momentum`, `lr_decay` and `decay_every` are
    /// not read (0, 1, 1).
    pub fn cmx_code() -> Self {
        Self {
            kind: OptimizerKind::Adamw,
            lr: 6e-5,
            momentum: 0.0,
            weight_decay: 0.01,
            lr_decay: 1.0,
            decay_every: 1,
            decay_scope: DecayScope::ConvAndLinearWeights,
            schedule: LrSchedule::cmx_code(),
            ..Self::mfnet_paper()
        }
    }

    /// The paper's optimiser and schedule of a kind: SGD → MFNet's, RMSprop → HeatNet's, AdamW
    /// → CMX's.
    pub fn paper_default(kind: OptimizerKind) -> Self {
        match kind {
            OptimizerKind::Sgd => Self::mfnet_paper(),
            OptimizerKind::Rmsprop => Self::heatnet_paper(),
            OptimizerKind::Adamw => Self::cmx_code(),
        }
    }

    /// Learning rate of the step `at` ([`LrSchedule`]).
    pub fn lr_at(&self, at: StepAt) -> f64 {
        match self.schedule {
            LrSchedule::StepDecay => {
                let decays = at.epoch / self.decay_every.max(1);
                self.lr * self.lr_decay.powi(decays as i32)
            }
            LrSchedule::WarmupPoly {
                power,
                warmup_epochs,
            } => super::schedule::warmup_poly(
                self.lr,
                power,
                warmup_epochs * at.steps_per_epoch,
                at.total(),
                at.global(),
            ),
        }
    }
}

impl OptimizerConfig {
    /// Values the update rules can work with; `prefix` names the field in errors.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        let bad = |field: &str, message: String| {
            Err(ConfigError {
                field: format!("{prefix}.{field}"),
                message,
            })
        };
        if !(self.lr.is_finite() && self.lr > 0.0) {
            return bad("lr", format!("must be a positive number, got {}", self.lr));
        }
        if !(self.momentum.is_finite() && (0.0..1.0).contains(&self.momentum)) {
            return bad(
                "momentum",
                format!("must be in [0, 1), got {}", self.momentum),
            );
        }
        if !(self.weight_decay.is_finite() && self.weight_decay >= 0.0) {
            return bad(
                "weight_decay",
                format!("must be ≥ 0, got {}", self.weight_decay),
            );
        }
        if !(self.lr_decay.is_finite() && self.lr_decay > 0.0 && self.lr_decay <= 1.0) {
            return bad(
                "lr_decay",
                format!("must be in (0, 1], got {}", self.lr_decay),
            );
        }
        if self.decay_every == 0 {
            return bad("decay_every", "must be at least 1".into());
        }
        if !(self.alpha.is_finite() && self.alpha > 0.0 && self.alpha < 1.0) {
            return bad("alpha", format!("must be in (0, 1), got {}", self.alpha));
        }
        if !(self.eps.is_finite() && self.eps > 0.0) {
            return bad("eps", format!("must be > 0, got {}", self.eps));
        }
        self.validate_adamw_and_schedule(prefix)
    }

    /// The AdamW betas and the warm-up-poly power.
    fn validate_adamw_and_schedule(&self, prefix: &str) -> Result<(), ConfigError> {
        let (b1, b2) = self.betas;
        if ![b1, b2]
            .iter()
            .all(|b| b.is_finite() && (0.0..1.0).contains(b))
        {
            return Err(ConfigError {
                field: format!("{prefix}.betas"),
                message: format!("must both be in [0, 1), got ({b1}, {b2})"),
            });
        }
        match self.schedule {
            LrSchedule::WarmupPoly { power, .. } if !(power.is_finite() && power > 0.0) => {
                Err(ConfigError {
                    field: format!("{prefix}.schedule.power"),
                    message: format!("must be > 0, got {power}"),
                })
            }
            _ => Ok(()),
        }
    }
}
