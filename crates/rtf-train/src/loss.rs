//! Losses: anything mapping (logits, target) to a scalar. The training loop takes any of them.

use tch::{Kind, Reduction, Tensor};

use crate::config::LossConfig;

pub trait Loss {
    /// `logits` [B, C, H, W], `target` [B, H, W] int64 → scalar.
    fn compute(&self, logits: &Tensor, target: &Tensor) -> Tensor;
}

/// Pixel-wise cross-entropy, mean over counted pixels; `ignore_index` pixels are skipped.
pub struct CrossEntropy {
    pub class_weights: Option<Tensor>,
    pub ignore_index: i64,
}

impl Loss for CrossEntropy {
    fn compute(&self, logits: &Tensor, target: &Tensor) -> Tensor {
        let weights = self
            .class_weights
            .as_ref()
            .map(|w| w.to_device(logits.device()));
        logits.to_kind(Kind::Float).cross_entropy_loss(
            target,
            weights.as_ref(),
            Reduction::Mean,
            self.ignore_index,
            0.0,
        )
    }
}

impl LossConfig {
    /// Instantiates the loss; `ignore_id` comes from the dataset's class set.
    pub fn build(&self, ignore_id: Option<u8>) -> Box<dyn Loss> {
        match self {
            LossConfig::CrossEntropy { class_weights } => Box::new(CrossEntropy {
                class_weights: class_weights
                    .as_ref()
                    .map(|w| Tensor::from_slice(w).to_kind(Kind::Float)),
                // -100 is PyTorch's default: no label takes it.
                ignore_index: ignore_id.map_or(-100, i64::from),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cross_entropy_of_confident_right_answer_is_small_and_ignore_skips() {
        // [1, 2, 1, 2] logits; pixel 0 class 0 (right), pixel 1 class 13 (ignored).
        let logits = Tensor::from_slice(&[10.0f32, 0.0, -10.0, 0.0]).view([1, 2, 1, 2]);
        let target = Tensor::from_slice(&[0i64, 13]).view([1, 1, 2]);
        let loss = LossConfig::CrossEntropy {
            class_weights: None,
        }
        .build(Some(13));
        let value = f64::try_from(loss.compute(&logits, &target)).unwrap();
        assert!((0.0..1e-3).contains(&value), "{value}");
        let wrong = Tensor::from_slice(&[1i64, 13]).view([1, 1, 2]);
        assert!(f64::try_from(loss.compute(&logits, &wrong)).unwrap() > 5.0);
    }
}
