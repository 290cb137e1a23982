//! Teacher → student (HeatNet §III-A, eq. 1): the student learns the labels a frozen teacher
//! gives the day frames, and, with a night teacher, those it gives the night frames — HeatNet's
//! first training stage (RGB day teacher + thermal night teacher), the thermal teacher itself
//! (day frames only), and RGB-T → RGB distillation (§III-A.2). No dataset label is read.

use std::collections::BTreeMap;

use tch::Tensor;

use super::{Labeller, Procedure, StepBatches, StepReport, Student, Trained};
use crate::config::{StepAt, TargetOptions};
use crate::error::TrainError;
use crate::loss::{soft_cross_entropy, weighted_cross_entropy, PseudoTargets, PSEUDO_IGNORE};

pub struct TeacherStudent {
    pub student: Student,
    pub day_teacher: Labeller,
    pub night_teacher: Option<Labeller>,
    pub targets: TargetOptions,
}

/// The student's loss against a teacher's targets: cross-entropy on the arg-max (pixels under
/// the threshold ignored) or on the softmax, each pixel weighted by `weights` if given.
pub(super) fn distillation_loss(
    logits: &Tensor,
    targets: &PseudoTargets,
    options: &TargetOptions,
    weights: Option<&Tensor>,
) -> Tensor {
    match options.soft {
        false => weighted_cross_entropy(logits, &targets.ids, PSEUDO_IGNORE, weights),
        true => {
            let counted = match weights {
                Some(w) => targets.counted().to_kind(tch::Kind::Float) * w,
                None => targets.counted().to_kind(tch::Kind::Float),
            };
            soft_cross_entropy(logits, &targets.probs, &counted)
        }
    }
}

impl Procedure for TeacherStudent {
    fn trained(&self) -> Vec<&Trained> {
        vec![&self.student.trained]
    }
    fn trained_mut(&mut self) -> Vec<&mut Trained> {
        vec![&mut self.student.trained]
    }
    fn student(&self) -> &Student {
        &self.student
    }
    fn labellers(&self) -> (Option<&Labeller>, Option<&Labeller>) {
        (Some(&self.day_teacher), self.night_teacher.as_ref())
    }

    // `x = x * y` on tensors, not `x *= y`: the compound forms are in-place ops, which autograd
    // cannot differentiate through.
    #[allow(clippy::assign_op_pattern)]
    fn step(&mut self, batches: &StepBatches, at: StepAt) -> Result<StepReport, TrainError> {
        let threshold = self.targets.threshold;
        // Day: the day teacher's labels (eq. 1).
        let day = &batches.main;
        let day_targets = self.day_teacher.targets(day, threshold);
        let ce_day = distillation_loss(
            &self.student.logits(&day.input),
            &day_targets,
            &self.targets,
            None,
        );
        let mut terms = BTreeMap::new();
        terms.insert(
            "ce_day".to_string(),
            f64::try_from(&ce_day).unwrap_or(f64::NAN),
        );
        let mut loss = ce_day;
        // Night: the night teacher's labels (the thermal teacher in stage 1; the RGB-T model
        // when distilling into an RGB-only student).
        if let (Some(teacher), Some(night)) = (&self.night_teacher, &batches.night) {
            let night_targets = teacher.targets(night, threshold);
            let ce_night = distillation_loss(
                &self.student.logits(&night.input),
                &night_targets,
                &self.targets,
                None,
            );
            terms.insert(
                "ce_night".to_string(),
                f64::try_from(&ce_night).unwrap_or(f64::NAN),
            );
            loss = loss + ce_night;
        }
        self.student.trained.minimise(&loss, at);
        Ok(StepReport {
            total: f64::try_from(&loss).unwrap_or(f64::NAN),
            terms,
            metrics: BTreeMap::new(),
        })
    }
}
