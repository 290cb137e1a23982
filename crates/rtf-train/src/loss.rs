//! Losses: anything mapping (logits, target) to a scalar. The training loop takes any of them.

use tch::{Device, Kind, Reduction, Tensor};

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

/// Instantiates the loss `config` names, its tensors on `device` (made once: from host memory
/// at every step they would be a copy to the GPU at every step); `ignore_id` comes from the
/// dataset's class set.
pub fn build(config: &LossConfig, ignore_id: Option<u8>, device: Device) -> Box<dyn Loss> {
    match config {
        LossConfig::CrossEntropy { class_weights } => Box::new(CrossEntropy {
            class_weights: class_weights
                .as_ref()
                .map(|w| Tensor::from_slice(w).to_kind(Kind::Float).to_device(device)),
            // PyTorch's default -100: no label takes it, but the loader's padding of a set
            // without an ignore id does (rtf_data::loader::NO_LABEL).
            ignore_index: ignore_id.map_or(rtf_data::loader::NO_LABEL, i64::from),
        }),
    }
}

/// The label value pseudo-label targets use for "no target here" (PyTorch's default ignore).
pub const PSEUDO_IGNORE: i64 = rtf_data::loader::NO_LABEL;

/// A frozen teacher's output turned into the student's target (HeatNet eq. 1).
pub struct PseudoTargets {
    /// [B, H, W] int64 arg-max ids; pixels under the confidence threshold are
    /// [`PSEUDO_IGNORE`].
    pub ids: Tensor,
    /// [B, C, H, W] the teacher's softmax (soft targets).
    pub probs: Tensor,
    /// [B, H, W] the teacher's confidence (max softmax).
    pub confidence: Tensor,
}

impl PseudoTargets {
    /// From teacher logits [B, C, H, W] (float).
    pub fn from_logits(logits: &Tensor, threshold: Option<f64>) -> Self {
        let probs = logits.to_kind(Kind::Float).softmax(1, Kind::Float);
        let (confidence, ids) = probs.max_dim(1, false);
        let ids = match threshold {
            Some(t) => ids.masked_fill(&confidence.lt(t), PSEUDO_IGNORE),
            None => ids,
        };
        Self {
            ids,
            probs,
            confidence,
        }
    }

    /// Targets read from a batch's labels (a label cache): `ignore` pixels carry none; every
    /// other pixel has confidence 1. Hard targets only.
    pub fn from_labels(labels: &Tensor, ignore: i64) -> Self {
        let ids = labels.masked_fill(&labels.eq(ignore), PSEUDO_IGNORE);
        let confidence = ids.ne(PSEUDO_IGNORE).to_kind(Kind::Float);
        Self {
            ids,
            probs: Tensor::new(),
            confidence,
        }
    }

    /// Pixels that carry a target [B, H, W] bool.
    pub fn counted(&self) -> Tensor {
        self.ids.ne(PSEUDO_IGNORE)
    }
}

/// Pixel-wise cross-entropy against `ids` [B, H, W] (pixels equal to `ignore` skipped), each
/// pixel weighted by `weights` [B, H, W] if given; mean over the counted pixels, 0 when none is.
pub fn weighted_cross_entropy(
    logits: &Tensor,
    ids: &Tensor,
    ignore: i64,
    weights: Option<&Tensor>,
) -> Tensor {
    let per_pixel = logits.to_kind(Kind::Float).cross_entropy_loss(
        ids,
        None::<&Tensor>,
        Reduction::None,
        ignore,
        0.0,
    );
    let counted = ids.ne(ignore).to_kind(Kind::Float);
    let weighted = match weights {
        Some(w) => per_pixel * w * &counted,
        None => per_pixel * &counted,
    };
    weighted.sum(Kind::Float) / counted.sum(Kind::Float).clamp_min(1.0)
}

/// Soft cross-entropy −Σ_c p_c log softmax(logits)_c against the teacher's probabilities
/// `probs` [B, C, H, W], mean over the pixels where `counted` [B, H, W] holds.
pub fn soft_cross_entropy(logits: &Tensor, probs: &Tensor, counted: &Tensor) -> Tensor {
    let log_p = logits.to_kind(Kind::Float).log_softmax(1, Kind::Float);
    let per_pixel = -(probs * log_p).sum_dim_intlist([1i64].as_slice(), false, Kind::Float);
    let counted = counted.to_kind(Kind::Float);
    (per_pixel * &counted).sum(Kind::Float) / counted.sum(Kind::Float).clamp_min(1.0)
}

/// Least squares (target − score)² over a critic's map `scores` [B, 1, H, W] (HeatNet eq. 2–3),
/// weighted per pixel by `weights` [B, H, W] if given; mean over pixels.
pub fn least_squares(scores: &Tensor, target: f64, weights: Option<&Tensor>) -> Tensor {
    let squared = (scores.to_kind(Kind::Float) - target).square();
    match weights {
        Some(w) => (squared * w.unsqueeze(1)).mean(Kind::Float),
        None => squared.mean(Kind::Float),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pseudo_targets_threshold_and_weighted_cross_entropy() {
        // Two pixels, two classes: one confident (class 0), one unsure.
        let logits = Tensor::from_slice(&[5.0f32, 0.1, 0.0, 0.0]).view([1, 2, 1, 2]);
        let t = PseudoTargets::from_logits(&logits, Some(0.9));
        assert_eq!(
            Vec::<i64>::try_from(t.ids.flatten(0, -1)).unwrap(),
            vec![0, PSEUDO_IGNORE]
        );
        let plain = PseudoTargets::from_logits(&logits, None);
        assert_eq!(
            Vec::<i64>::try_from(plain.ids.flatten(0, -1)).unwrap()[0],
            0
        );
        // The student agreeing with the confident pixel: small loss; the unsure pixel is skipped.
        let student = Tensor::from_slice(&[10.0f32, -10.0, 0.0, 10.0]).view([1, 2, 1, 2]);
        let ce = f64::try_from(weighted_cross_entropy(
            &student,
            &t.ids,
            PSEUDO_IGNORE,
            None,
        ))
        .unwrap();
        assert!(ce < 1e-3, "{ce}");
        // Nothing counted: 0, not NaN.
        let none = Tensor::full([1, 1, 2], PSEUDO_IGNORE, (Kind::Int64, tch::Device::Cpu));
        let zero =
            f64::try_from(weighted_cross_entropy(&student, &none, PSEUDO_IGNORE, None)).unwrap();
        assert_eq!(zero, 0.0);
        // Weights scale the counted pixels' terms.
        let w = Tensor::from_slice(&[0.5f32, 1.0]).view([1, 1, 2]);
        let wrong = Tensor::from_slice(&[1i64, PSEUDO_IGNORE]).view([1, 1, 2]);
        let full = f64::try_from(weighted_cross_entropy(
            &student,
            &wrong,
            PSEUDO_IGNORE,
            None,
        ))
        .unwrap();
        let half = f64::try_from(weighted_cross_entropy(
            &student,
            &wrong,
            PSEUDO_IGNORE,
            Some(&w),
        ))
        .unwrap();
        assert!((half - 0.5 * full).abs() < 1e-6 * full, "{half} vs {full}");
    }

    #[test]
    fn soft_cross_entropy_equals_hard_for_one_hot_targets() {
        let logits = Tensor::from_slice(&[1.0f32, 2.0, 0.5, -1.0]).view([1, 2, 1, 2]);
        let ids = Tensor::from_slice(&[1i64, 0]).view([1, 1, 2]);
        let one_hot = ids.one_hot(2).permute([0, 3, 1, 2]).to_kind(Kind::Float);
        let counted = ids.ge(0);
        let soft = f64::try_from(soft_cross_entropy(&logits, &one_hot, &counted)).unwrap();
        let hard =
            f64::try_from(weighted_cross_entropy(&logits, &ids, PSEUDO_IGNORE, None)).unwrap();
        assert!((soft - hard).abs() < 1e-6, "{soft} vs {hard}");
    }

    #[test]
    fn least_squares_is_the_mean_squared_distance_to_the_target() {
        let scores = Tensor::from_slice(&[0.0f32, 1.0, 0.5, 0.5]).view([1, 1, 2, 2]);
        let v = f64::try_from(least_squares(&scores, 1.0, None)).unwrap();
        assert!((v - (1.0 + 0.0 + 0.25 + 0.25) / 4.0).abs() < 1e-7);
        let w = Tensor::from_slice(&[0.0f32, 0.0, 1.0, 1.0]).view([1, 2, 2]);
        let v = f64::try_from(least_squares(&scores, 1.0, Some(&w))).unwrap();
        assert!((v - 0.5 / 4.0).abs() < 1e-7);
    }

    #[test]
    fn cross_entropy_of_confident_right_answer_is_small_and_ignore_skips() {
        // [1, 2, 1, 2] logits; pixel 0 class 0 (right), pixel 1 class 13 (ignored).
        let logits = Tensor::from_slice(&[10.0f32, 0.0, -10.0, 0.0]).view([1, 2, 1, 2]);
        let target = Tensor::from_slice(&[0i64, 13]).view([1, 1, 2]);
        let loss = build(
            &LossConfig::CrossEntropy {
                class_weights: None,
            },
            Some(13),
            Device::Cpu,
        );
        let value = f64::try_from(loss.compute(&logits, &target)).unwrap();
        assert!((0.0..1e-3).contains(&value), "{value}");
        let wrong = Tensor::from_slice(&[1i64, 13]).view([1, 1, 2]);
        assert!(f64::try_from(loss.compute(&logits, &wrong)).unwrap() > 5.0);
    }
}
