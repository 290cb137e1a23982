//! How a network expects its input scaled; carried in every model config so that `predict` and
//! `eval` feed each network what it was trained on.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum InputConvention {
    /// MFNet / RTFNet reference: pixel / 255 in [0, 1], channels R, G, B, T, no mean/std.
    #[default]
    UnitRange,
    /// HeatNet reference: (pixel in [0, 1] - mean) / std per modality, mean = std = 0.5.
    MeanStd { mean: f32, std: f32 },
}

impl InputConvention {
    /// Maps a value already in [0, 1] to the network's input range.
    pub fn apply(&self, unit: f32) -> f32 {
        match *self {
            Self::UnitRange => unit,
            Self::MeanStd { mean, std } => (unit - mean) / std,
        }
    }

    /// Inverse of [`apply`](Self::apply): network input back to [0, 1] (for drawing).
    pub fn invert(&self, value: f32) -> f32 {
        match *self {
            Self::UnitRange => value,
            Self::MeanStd { mean, std } => value * std + mean,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_std_maps_to_minus_one_one() {
        let c = InputConvention::MeanStd {
            mean: 0.5,
            std: 0.5,
        };
        assert_eq!(c.apply(0.0), -1.0);
        assert_eq!(c.apply(1.0), 1.0);
        assert!((c.invert(c.apply(0.3)) - 0.3).abs() < 1e-6);
        assert_eq!(InputConvention::UnitRange.apply(0.25), 0.25);
    }

    #[test]
    fn serde_round_trip() {
        let c = InputConvention::MeanStd {
            mean: 0.5,
            std: 0.5,
        };
        let s = serde_json::to_string(&c).unwrap();
        assert_eq!(serde_json::from_str::<InputConvention>(&s).unwrap(), c);
    }
}
