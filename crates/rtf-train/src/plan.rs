//! A run plan: what one training's configuration resolves to before its run folder is
//! touched, each part resolved once. The dataset is opened once (its frames split by what the
//! procedure reads, [`Sources`]) and fingerprinted from that opened dataset; the teachers are
//! checked once against the student ([`Teachers`]); the device is found; and the
//! configuration `config.json` records is made (the fingerprint filled in). The trainer and
//! the procedures then take the plan's parts, not the whole configuration, and recording the
//! configuration only writes ([`RunPlan::record`]).
//!
//! Everything here can refuse the run, and does so before anything is written: a missing
//! dataset, a teacher that cannot teach the student, a class count the network does not have.

mod sources;
pub mod teachers;
#[cfg(test)]
mod tests;

use crate::config::{
    available_device, ComputeConfig, DataConfig, LearningConfig, NetworkConfig, ScheduleConfig,
    TrainConfig,
};
use crate::error::TrainError;

pub use sources::{open_sources, open_sources_in, Source, Sources};
pub use teachers::{check_teachers, CheckedTeacher, Teachers};

/// One training, resolved: the sections the loop reads, and what was opened and checked for
/// it. Built by [`RunPlan::resolve`].
pub struct RunPlan<'a> {
    /// The student's network, inputs and starting weights.
    pub network: &'a NetworkConfig,
    /// How its loaders read the frames (resize, augmentation, shuffle, workers).
    pub data: &'a DataConfig,
    /// Procedure, optimiser, loss and arithmetic.
    pub learning: &'a LearningConfig,
    /// Epochs, batches, seed, checkpoints and hooks.
    pub schedule: &'a ScheduleConfig,
    /// Where it runs (the device below is `compute.device`, found on this machine).
    pub compute: &'a ComputeConfig,
    pub device: tch::Device,
    /// The dataset, opened once, and its frames split by what the procedure reads.
    pub sources: Sources,
    /// The teachers given as weights files, checked once against the student.
    pub teachers: Teachers,
    /// The configuration as `config.json` records it: the fingerprint of `sources.dataset`
    /// filled in (the number of processes is the run folder's, set when it is written).
    pub record: TrainConfig,
}

impl<'a> RunPlan<'a> {
    /// Resolves `cfg`: checks its values, finds its device, checks its teachers, opens its
    /// dataset (refused when the network has another class count) and fingerprints it.
    pub fn resolve(cfg: &'a TrainConfig) -> Result<Self, TrainError> {
        Self::resolve_opened(cfg, None)
    }

    /// [`RunPlan::resolve`] on a dataset root already `opened` (by `rtf train`'s setup), used
    /// when it is the root `cfg` names, opened as the kind it records (else the root is
    /// opened here).
    pub fn resolve_opened(
        cfg: &'a TrainConfig,
        opened: Option<rtf_data::Dataset>,
    ) -> Result<Self, TrainError> {
        cfg.validate()?;
        let device = available_device(&cfg.compute.device).map_err(TrainError::Config)?;
        let teachers = Teachers::check(&cfg.learning.procedure, &cfg.network.model)?;
        let sources = open_sources_in(&cfg.data.dataset, &cfg.learning.procedure, opened)?;
        let classes = sources.main.class_set().len() as i64;
        if classes != cfg.network.model.num_classes() {
            return Err(TrainError::Config(format!(
                "the dataset has {classes} classes but the model is configured for {}",
                cfg.network.model.num_classes()
            )));
        }
        let record = recorded(cfg, &sources.dataset)?;
        Ok(Self {
            network: &cfg.network,
            data: &cfg.data,
            learning: &cfg.learning,
            schedule: &cfg.schedule,
            compute: &cfg.compute,
            device,
            sources,
            teachers,
            record,
        })
    }

    /// The configuration `config.json` records for a run trained by `world` processes
    /// (data-parallel; None: one).
    pub fn record(&self, world: Option<usize>) -> TrainConfig {
        let mut record = self.record.clone();
        if world.is_some() {
            record.compute.world_size = world;
        }
        record
    }
}

/// `cfg` with the fingerprint of the `dataset` it opened (which data the run used: a resume
/// on changed data says so on stderr).
fn recorded(cfg: &TrainConfig, dataset: &rtf_data::Dataset) -> Result<TrainConfig, TrainError> {
    let fingerprint = rtf_data::fingerprint::fingerprint_opened(dataset)?;
    let before = cfg.data.fingerprint.as_ref();
    if let Some(before) = before.filter(|f| f.hash != fingerprint.hash) {
        eprintln!(
            "warning: {} changed since this run started (data hash {} then, {} now)",
            dataset.root().display(),
            &before.hash[..12.min(before.hash.len())],
            &fingerprint.hash[..12.min(fingerprint.hash.len())]
        );
    }
    let mut record = cfg.clone();
    record.data.fingerprint = Some(fingerprint);
    Ok(record)
}
