//! What a run reports while it trains, beside its files: every step's losses (as
//! `steps.jsonl` holds them) and every epoch's record (as `log.jsonl` holds it), on rank 0.
//! `rtf train` prints the epochs; the Python package hands both to the user's callback.

use rtf_run::EpochRecord;

use crate::step_log::StepRecord;

/// Receives a run's steps and epochs as they end. `stage` is the stage's name in a
/// multi-stage run, "" otherwise.
pub trait Progress {
    fn epoch(&mut self, stage: &str, record: &EpochRecord);

    fn step(&mut self, _stage: &str, _record: &StepRecord) {}
}

/// Epoch records only, to a closure of (stage, record).
pub struct Epochs<F>(pub F);

impl<F: FnMut(&str, &EpochRecord)> Progress for Epochs<F> {
    fn epoch(&mut self, stage: &str, record: &EpochRecord) {
        (self.0)(stage, record)
    }
}

/// A stage's reports, named by the stage (a trainer knows no stage of its own).
pub(crate) struct InStage<'a> {
    pub stage: &'a str,
    pub inner: &'a mut dyn Progress,
}

impl Progress for InStage<'_> {
    fn epoch(&mut self, _: &str, record: &EpochRecord) {
        self.inner.epoch(self.stage, record)
    }

    fn step(&mut self, _: &str, record: &StepRecord) {
        self.inner.step(self.stage, record)
    }
}
