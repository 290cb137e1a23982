//! What the optimiser is asked to do: the recipe (`paper`: HeatNet §IV-A as published;
//! `default`: ours, see the [module doc](super)) and its settings, resolved flags > rig.yaml
//! `optimizer:` > the recipe's defaults (docs/src/calibration.md, "Settings").

use crate::error::{CalibError, Result};
use crate::rig::OptimizerOverrides;

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Recipe {
    Default,
    Paper,
}

/// Resolved optimiser settings (flags > rig.yaml `optimizer:` > recipe).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    pub recipe: Recipe,
    /// paper: Adam iterations; default: Levenberg-Marquardt iterations per pyramid level.
    pub iterations: usize,
    /// paper: pairs per Adam step; default: frames used per level (a seeded random subset).
    pub batch_size: usize,
    /// paper: initial Adam step (pixel-scaled units); default: sets the first
    /// Levenberg-Marquardt damping λ₀ = 10⁻⁵ / learning_rate (λ adapts afterwards, so any
    /// sensible value works, including a rig.yaml written for Adam).
    pub learning_rate: f64,
    pub seed: u64,
    /// Development output on stderr: each iteration of a synthetic run
    /// ([`crate::synth_run::calibrate_synthetic`]) and each walk of the bound
    /// ([`crate::bound`]). Off from [`Settings::resolve`]; a binary may turn it on (`rtf
    /// calibrate` and the lab's probes do with `RTF_CALIB_DEBUG` set).
    pub debug: bool,
}

impl Settings {
    pub fn recipe_defaults(recipe: Recipe) -> OptimizerOverrides {
        match recipe {
            Recipe::Paper => OptimizerOverrides {
                iterations: Some(8000),
                batch_size: Some(10),
                learning_rate: Some(0.1),
            },
            Recipe::Default => OptimizerOverrides {
                iterations: Some(20),
                batch_size: Some(20),
                learning_rate: Some(0.01),
            },
        }
    }

    pub fn resolve(
        recipe: Recipe,
        flags: OptimizerOverrides,
        file: Option<OptimizerOverrides>,
        seed: u64,
    ) -> Result<Self> {
        let s = flags
            .or(file.unwrap_or_default())
            .or(Self::recipe_defaults(recipe));
        let settings = Settings {
            recipe,
            iterations: s.iterations.unwrap_or(1),
            batch_size: s.batch_size.unwrap_or(1),
            learning_rate: s.learning_rate.unwrap_or(1.0),
            seed,
            debug: false,
        };
        if settings.iterations == 0 || settings.batch_size == 0 {
            return Err(CalibError::Setting(
                "iterations and batch size must be at least 1".into(),
            ));
        }
        if !(settings.learning_rate.is_finite() && settings.learning_rate > 0.0) {
            return Err(CalibError::Setting(format!(
                "learning rate must be positive, got {}",
                settings.learning_rate
            )));
        }
        Ok(settings)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_follow_flags_then_file_then_recipe() {
        let file = OptimizerOverrides {
            iterations: Some(5),
            batch_size: Some(3),
            learning_rate: None,
        };
        let flags = OptimizerOverrides {
            batch_size: Some(7),
            ..Default::default()
        };
        let s = Settings::resolve(Recipe::Paper, flags, Some(file), 9).unwrap();
        assert_eq!(
            (s.iterations, s.batch_size, s.learning_rate, s.seed),
            (5, 7, 0.1, 9)
        );
        assert!(Settings::resolve(
            Recipe::Default,
            OptimizerOverrides {
                learning_rate: Some(-1.0),
                ..Default::default()
            },
            None,
            0
        )
        .is_err());
    }
}
