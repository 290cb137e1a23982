//! Supervised training: cross-entropy on the dataset's labels (MFNet §III, RTFNet §IV; the
//! RGB teacher of HeatNet when no Vistas-trained teacher is given).

use std::collections::BTreeMap;

use super::{Procedure, StepBatches, StepReport, Student, Trained};
use crate::config::StepAt;
use crate::error::TrainError;
use crate::loss::Loss;

pub struct Supervised {
    pub student: Student,
    pub loss: Box<dyn Loss>,
}

impl Procedure for Supervised {
    fn trained(&self) -> Vec<&Trained> {
        vec![&self.student.trained]
    }
    fn trained_mut(&mut self) -> Vec<&mut Trained> {
        vec![&mut self.student.trained]
    }
    fn student(&self) -> &Student {
        &self.student
    }

    fn step(&mut self, batches: &StepBatches, at: StepAt) -> Result<StepReport, TrainError> {
        let batch = &batches.main;
        let logits = self.student.logits(&batch.input);
        let loss = self.loss.compute(&logits, &batch.target);
        self.student.trained.minimise(&loss, at);
        let value = f64::try_from(&loss).unwrap_or(f64::NAN);
        Ok(StepReport {
            total: value,
            terms: BTreeMap::from([("ce".to_string(), value)]),
            metrics: BTreeMap::new(),
        })
    }
}
