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
//! (1 − confidence); `flip_targets` (day → 1, night → 0); `day_term` (the segmentation step
//! also keeps day outputs on the day side); `alternate` (the code's loop: each step is either
//! a critic step or a segmentation step, on its own batches, critic first).

use std::collections::BTreeMap;

use rtf_models::heatnet::{Critic, CriticConfig};
use tch::{nn::ModuleT, Device, Kind, Tensor};

use super::teacher_student::distillation_loss;
use super::{Labeller, Procedure, StepBatches, StepReport, Student, Trained, CRITIC};
use crate::config::{CriticInput, CriticOptions, StepAt, TargetOptions};
use crate::error::TrainError;
use crate::loss::least_squares;

/// The critic's target for day outputs (paper eq. 2; the published code flips both:
/// `flip_targets`).
const DAY: f64 = 0.0;

pub struct Adversarial {
    pub student: Student,
    pub critic: Trained,
    critic_net: Critic,
    day_teacher: Labeller,
    night_teacher: Option<Labeller>,
    targets: TargetOptions,
    options: CriticOptions,
    /// Steps taken (resumed runs: set by [`Procedure::resume_at`]); picks the phase under
    /// `alternate`.
    steps: u64,
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
        let critic = Trained::new(CRITIC, device, &options.optimizer)
            .computing(student.trained.kernels.clone())
            .mixed(student.trained.precision)?;
        let mut critic = critic;
        let critic_net = Critic::new(
            rtf_models::layers::Path::new(critic.vs.root(), &critic.build_options()),
            &CriticConfig {
                in_channels: student.net.inner.num_classes(),
            },
        )?;
        if let Some(path) = &options.init {
            let tensors = rtf_models::io::weights::read_safetensors(path)?;
            rtf_models::io::weights::load_named_except(
                &mut critic.vs,
                tensors,
                path,
                &Default::default(),
            )?;
        }
        critic.channels_last_weights();
        Ok(Self {
            student,
            critic,
            critic_net,
            day_teacher,
            night_teacher,
            targets,
            options,
            steps: 0,
        })
    }

    /// The critic's targets for day and night outputs.
    fn day_night(&self) -> (f64, f64) {
        match self.options.flip_targets {
            false => (DAY, 1.0 - DAY),
            true => (1.0 - DAY, DAY),
        }
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
    // `x = x * y` on tensors, not `x *= y`: the compound forms are in-place ops, which autograd
    // cannot differentiate through.
    #[allow(clippy::assign_op_pattern)]
    pub fn segmentation_step(
        &mut self,
        batches: &StepBatches,
        at: StepAt,
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
        let loss = loss
            + self.adversarial_terms(
                &night_logits,
                &day_logits,
                adversarial_weights.as_ref(),
                &mut terms,
            );
        self.student.trained.minimise(&loss, at);
        self.critic.vs.unfreeze();
        let total = f64::try_from(&loss).unwrap_or(f64::NAN);
        Ok((total, terms, night_logits, day_logits))
    }

    /// The segmentation step's critic terms, each recorded in `terms`: eq. 3's λ·(0 − C(S_N))²
    /// (night outputs should look like day to the critic), weighted per pixel if given, and the
    /// day outputs toward the night target (`multidir`) or kept on the day side (`day_term`).
    fn adversarial_terms(
        &self,
        night_logits: &Tensor,
        day_logits: &Tensor,
        weights: Option<&Tensor>,
        terms: &mut BTreeMap<String, f64>,
    ) -> Tensor {
        let (day, night) = self.day_night();
        let lambda = self.options.lambda;
        let adv = least_squares(&self.critic_scores(night_logits), day, weights) * lambda;
        terms.insert("adv".to_string(), f64::try_from(&adv).unwrap_or(f64::NAN));
        let day_term = match (self.options.multidir, self.options.day_term) {
            (true, _) => Some(night),
            (false, true) => Some(day),
            (false, false) => None,
        };
        match day_term {
            None => adv,
            Some(target) => {
                let adv_day = least_squares(&self.critic_scores(day_logits), target, None) * lambda;
                terms.insert(
                    "adv_day".to_string(),
                    f64::try_from(&adv_day).unwrap_or(f64::NAN),
                );
                adv + adv_day
            }
        }
    }

    /// Step 2: the critic learns from the student's outputs, detached (eq. 2), `steps` times.
    /// Returns the critic's loss and its day / night accuracy (score on the right side of 0.5).
    pub fn critic_step(
        &mut self,
        day_logits: &Tensor,
        night_logits: &Tensor,
        at: StepAt,
    ) -> (f64, f64, f64) {
        let (day, night) = (day_logits.detach(), night_logits.detach());
        let mut last = (f64::NAN, f64::NAN, f64::NAN);
        for _ in 0..self.options.steps {
            last = self.critic_update(&day, &night, at);
        }
        last
    }

    /// One critic update on detached outputs: (loss, day accuracy, night accuracy).
    fn critic_update(&mut self, day: &Tensor, night: &Tensor, at: StepAt) -> (f64, f64, f64) {
        let (day_target, night_target) = self.day_night();
        let day_scores = self.critic_scores(day);
        let night_scores = self.critic_scores(night);
        let loss = least_squares(&day_scores, day_target, None)
            + least_squares(&night_scores, night_target, None);
        self.critic.minimise(&loss, at);
        let middle = (day_target + night_target) / 2.0;
        // The share of pixels the critic puts on the right side of the middle.
        let right_side = |scores: &Tensor, target: f64| {
            let side = match target > middle {
                true => scores.ge(middle),
                false => scores.lt(middle),
            };
            f64::try_from(side.to_kind(Kind::Float).mean(Kind::Float)).unwrap_or(f64::NAN)
        };
        let loss = f64::try_from(&loss).unwrap_or(f64::NAN);
        (
            loss,
            right_side(&day_scores, day_target),
            right_side(&night_scores, night_target),
        )
    }

    /// The published code's critic step (`alternate`): the student, frozen, runs its own
    /// training-mode forward pass on this step's batches (its BatchNorm statistics move, as in
    /// the code), and the critic learns from those outputs once.
    fn critic_phase(
        &mut self,
        batches: &StepBatches,
        at: StepAt,
    ) -> Result<StepReport, TrainError> {
        let night = batches.night.as_ref().ok_or_else(|| {
            TrainError::Config("the adversarial procedure needs night frames".into())
        })?;
        let (day_logits, night_logits) = tch::no_grad(|| {
            let day = self.student.logits(&batches.main.input);
            (day, self.student.logits(&night.input))
        });
        let (loss, acc_day, acc_night) = self.critic_update(&day_logits, &night_logits, at);
        Ok(StepReport {
            total: loss,
            terms: BTreeMap::from([("critic".to_string(), loss)]),
            metrics: accuracies(acc_day, acc_night),
        })
    }

    /// Whether this step is a critic step under `alternate`: `steps` critic steps, then one
    /// segmentation step, from the run's first step on.
    fn critic_turn(&self) -> bool {
        let cycle = self.options.steps as u64 + 1;
        self.steps % cycle < cycle - 1
    }

    /// The paper's step: a segmentation step, then the critic's on the same outputs.
    fn paper_step(&mut self, batches: &StepBatches, at: StepAt) -> Result<StepReport, TrainError> {
        let (total, mut terms, night_logits, day_logits) = self.segmentation_step(batches, at)?;
        let (critic_loss, acc_day, acc_night) = self.critic_step(&day_logits, &night_logits, at);
        terms.insert("critic".to_string(), critic_loss);
        Ok(StepReport {
            total,
            terms,
            metrics: accuracies(acc_day, acc_night),
        })
    }
}

fn accuracies(day: f64, night: f64) -> BTreeMap<String, f64> {
    BTreeMap::from([
        ("critic_acc_day".to_string(), day),
        ("critic_acc_night".to_string(), night),
    ])
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

    fn step(&mut self, batches: &StepBatches, at: StepAt) -> Result<StepReport, TrainError> {
        let report = match (self.options.alternate, self.critic_turn()) {
            (false, _) => self.paper_step(batches, at),
            (true, true) => self.critic_phase(batches, at),
            (true, false) => {
                let (total, terms, _, _) = self.segmentation_step(batches, at)?;
                Ok(StepReport {
                    total,
                    terms,
                    metrics: BTreeMap::new(),
                })
            }
        };
        self.steps += 1;
        report
    }

    fn resume_at(&mut self, steps_done: u64) {
        self.steps = steps_done;
    }
}
