//! Adversarial day/night adaptation (HeatNet §III-A, eq. 2–3; spec §5). Each iteration takes
//! one day batch and one night batch and alternates
//! 1. a segmentation step: day cross-entropy against the day teacher's labels plus
//!    λ·(0 − C(S_N))², the critic's score of the student's night output pushed toward "day";
//!    the critic is frozen (its variables take no gradient and its optimiser does not step);
//! 2. critic step(s): least squares with day → 0 and night → 1 on the student's outputs,
//!    detached, so only the critic learns.
//!
//! Options from the published code: the critic reads raw logits instead of the softmax;
//! `multidir` also pushes day outputs toward the night target; a night teacher adds its
//! cross-entropy weighted by its confidence, and weights the adversarial term per pixel by
//! (1 − confidence).

use std::collections::BTreeMap;

use rtf_models::heatnet::{Critic, CriticConfig};
use tch::{nn::ModuleT, Device, Kind, Tensor};

use super::teacher_student::distillation_loss;
use super::{Labeller, Procedure, StepBatches, StepReport, Student, Trained, CRITIC};
use crate::config::{CriticInput, CriticOptions, TargetOptions};
use crate::error::TrainError;
use crate::loss::least_squares;

/// The critic's target for day outputs (paper eq. 2; the published code flips both).
const DAY: f64 = 0.0;
const NIGHT: f64 = 1.0;

pub struct Adversarial {
    pub student: Student,
    pub critic: Trained,
    critic_net: Critic,
    day_teacher: Labeller,
    night_teacher: Option<Labeller>,
    targets: TargetOptions,
    options: CriticOptions,
}

impl Adversarial {
    pub fn new(
        student: Student,
        day_teacher: Labeller,
        night_teacher: Option<Labeller>,
        targets: TargetOptions,
        options: CriticOptions,
        device: Device,
    ) -> Result<Self, TrainError> {
        // The critic trains in the student's arithmetic.
        let critic =
            Trained::new(CRITIC, device, &options.optimizer).mixed(student.trained.precision)?;
        let critic_net = Critic::new(
            critic.vs.root(),
            &CriticConfig {
                in_channels: student.net.inner.num_classes(),
            },
        )?;
        critic.channels_last_weights();
        Ok(Self {
            student,
            critic,
            critic_net,
            day_teacher,
            night_teacher,
            targets,
            options,
        })
    }

    /// The critic's score map [B, 1, H, W] of segmentation logits [B, C, H, W].
    fn critic_scores(&self, logits: &Tensor) -> Tensor {
        let x = match self.options.input {
            CriticInput::Softmax => logits.softmax(1, Kind::Float),
            CriticInput::Logits => logits.to_kind(Kind::Float),
        };
        let (h, w) = (logits.size()[2], logits.size()[3]);
        let scores = self.critic.autocast(|| {
            let scores = self.critic_net.forward_t(&x, true);
            match scores.size()[2..] == [h, w] {
                true => scores,
                // Sizes that are not multiples of the critic's stride (32) come back resized.
                false => scores.upsample_bilinear2d([h, w], false, None, None),
            }
        });
        // fp32 scores under mixed precision (a no-op in fp32), so the losses are fp32.
        match self.critic.precision {
            crate::config::Precision::Fp32 => scores,
            _ => scores.to_kind(Kind::Float),
        }
    }

    /// Step 1: the student learns; the critic is frozen. Returns (total, terms, night logits,
    /// day logits), the logits for the critic step.
    pub fn segmentation_step(
        &mut self,
        batches: &StepBatches,
        epoch: usize,
    ) -> Result<(f64, BTreeMap<String, f64>, Tensor, Tensor), TrainError> {
        let night = batches.night.as_ref().ok_or_else(|| {
            TrainError::Config("the adversarial procedure needs night frames".into())
        })?;
        let threshold = self.targets.threshold;
        self.critic.vs.freeze();
        let day_logits = self.student.logits(&batches.main.input);
        let day_targets = self.day_teacher.targets(&batches.main, threshold);
        let ce_day = distillation_loss(&day_logits, &day_targets, &self.targets, None);
        let night_logits = self.student.logits(&night.input);
        let mut terms = BTreeMap::new();
        terms.insert(
            "ce_day".to_string(),
            f64::try_from(&ce_day).unwrap_or(f64::NAN),
        );
        let mut loss = ce_day;
        // Night teacher (published code): its cross-entropy weighted by its confidence, and
        // the adversarial term by the rest.
        let mut adversarial_weights = None;
        if let Some(teacher) = &self.night_teacher {
            let night_targets = teacher.targets(night, threshold);
            let confidence = night_targets.confidence.shallow_clone();
            let ce_night = distillation_loss(
                &night_logits,
                &night_targets,
                &self.targets,
                self.options.confidence_weighting.then_some(&confidence),
            );
            terms.insert(
                "ce_night".to_string(),
                f64::try_from(&ce_night).unwrap_or(f64::NAN),
            );
            loss = loss + ce_night;
            if self.options.confidence_weighting {
                adversarial_weights = Some(1.0 - confidence);
            }
        }
        // Eq. 3: λ·(0 − C(S_N))² — night outputs should look like day to the critic.
        let adv = least_squares(
            &self.critic_scores(&night_logits),
            DAY,
            adversarial_weights.as_ref(),
        ) * self.options.lambda;
        terms.insert("adv".to_string(), f64::try_from(&adv).unwrap_or(f64::NAN));
        loss = loss + adv;
        if self.options.multidir {
            let adv_day =
                least_squares(&self.critic_scores(&day_logits), NIGHT, None) * self.options.lambda;
            terms.insert(
                "adv_day".to_string(),
                f64::try_from(&adv_day).unwrap_or(f64::NAN),
            );
            loss = loss + adv_day;
        }
        self.student.trained.minimise(&loss, epoch);
        self.critic.vs.unfreeze();
        let total = f64::try_from(&loss).unwrap_or(f64::NAN);
        Ok((total, terms, night_logits, day_logits))
    }

    /// Step 2: the critic learns from the student's outputs, detached (eq. 2). Returns the
    /// critic's loss and its day / night accuracy (score on the right side of 0.5).
    pub fn critic_step(
        &mut self,
        day_logits: &Tensor,
        night_logits: &Tensor,
        epoch: usize,
    ) -> (f64, f64, f64) {
        let (day, night) = (day_logits.detach(), night_logits.detach());
        let (mut loss_value, mut acc_day, mut acc_night) = (0.0, 0.0, 0.0);
        for _ in 0..self.options.steps {
            let day_scores = self.critic_scores(&day);
            let night_scores = self.critic_scores(&night);
            let loss =
                least_squares(&day_scores, DAY, None) + least_squares(&night_scores, NIGHT, None);
            self.critic.minimise(&loss, epoch);
            loss_value = f64::try_from(&loss).unwrap_or(f64::NAN);
            let middle = (DAY + NIGHT) / 2.0;
            acc_day = f64::try_from(day_scores.lt(middle).to_kind(Kind::Float).mean(Kind::Float))
                .unwrap_or(f64::NAN);
            acc_night = f64::try_from(
                night_scores
                    .ge(middle)
                    .to_kind(Kind::Float)
                    .mean(Kind::Float),
            )
            .unwrap_or(f64::NAN);
        }
        (loss_value, acc_day, acc_night)
    }
}

impl Procedure for Adversarial {
    fn trained(&self) -> Vec<&Trained> {
        vec![&self.student.trained, &self.critic]
    }
    fn trained_mut(&mut self) -> Vec<&mut Trained> {
        vec![&mut self.student.trained, &mut self.critic]
    }
    fn student(&self) -> &Student {
        &self.student
    }
    fn labellers(&self) -> (Option<&Labeller>, Option<&Labeller>) {
        (Some(&self.day_teacher), self.night_teacher.as_ref())
    }

    fn step(&mut self, batches: &StepBatches, epoch: usize) -> Result<StepReport, TrainError> {
        let (total, mut terms, night_logits, day_logits) =
            self.segmentation_step(batches, epoch)?;
        let (critic_loss, acc_day, acc_night) = self.critic_step(&day_logits, &night_logits, epoch);
        terms.insert("critic".to_string(), critic_loss);
        let metrics = BTreeMap::from([
            ("critic_acc_day".to_string(), acc_day),
            ("critic_acc_night".to_string(), acc_night),
        ]);
        Ok(StepReport {
            total,
            terms,
            metrics,
        })
    }
}
