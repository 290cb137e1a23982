//! The loaders over a run's frames (the plan's [`Sources`]): the training and validation
//! loaders, and the batches a run trains on ([`Streams`]).
use std::sync::Arc;

use rtf_data::{Loader, LoaderConfig};
use rtf_eval::EvalOptions;

use crate::config::{DataConfig, ScheduleConfig, TrainConfig};
use crate::ddp::Ddp;
use crate::error::TrainError;
use crate::plan::{open_sources, Source, Sources};

fn loader(
    data: &DataConfig,
    batch_size: usize,
    source: Source,
    seed: u64,
    input: rtf_core::InputConvention,
) -> Loader {
    Loader::new(
        source,
        LoaderConfig {
            batch_size,
            shuffle: data.shuffle,
            drop_last: false,
            seed,
            workers: data.workers,
            prefetch: 2,
            augment: data.augment.clone(),
            resize: data.resize,
        },
        input,
    )
}

/// The loader of the main stream `cfg` trains on (its first epoch is epoch 0), built as the
/// trainer builds it: the same frames, order, augmentation and input convention for a seed.
/// The Python package's `Dataset.loader` is this loader.
pub fn training_loader(cfg: &TrainConfig) -> Result<Loader, TrainError> {
    let sources = open_sources(&cfg.data.dataset, &cfg.learning.procedure)?;
    let input = cfg.network.model.input_convention();
    let seed = cfg.schedule.seed;
    Ok(loader(
        &cfg.data,
        cfg.schedule.batch_size,
        sources.main,
        seed,
        input,
    ))
}

/// The run's one validation loader: the validation frames as evaluation reads them, at the
/// training batch size, size and workers.
pub(super) fn val_loader(
    data: &DataConfig,
    batch_size: usize,
    val: Source,
    input: rtf_core::InputConvention,
) -> Loader {
    let options = EvalOptions {
        batch_size,
        resize: data.resize,
        workers: data.workers,
        ..Default::default()
    };
    rtf_eval::evaluate::split_loader(val, &options, input)
}

/// The batches a run trains on: the main stream and the night stream (its own order, cycling
/// when it is the shorter one); a data-parallel rank loads only its shard of each.
pub(super) struct Streams {
    pub(super) main: Loader,
    pub(super) main_shard: Option<Arc<crate::ddp::EpochShard>>,
    pub(super) night: Option<Loader>,
    pub(super) night_shard: Option<Arc<crate::ddp::EpochShard>>,
}

impl Streams {
    pub(super) fn open(
        data: &DataConfig,
        schedule: &ScheduleConfig,
        sources: &Sources,
        input: rtf_core::InputConvention,
        ddp: Option<&Ddp>,
    ) -> Result<Self, TrainError> {
        let batch = schedule.batch_size;
        let main = loader(data, batch, sources.main.clone(), schedule.seed, input);
        let night_seed = rtf_data::loader::mix(schedule.seed, 0x6e69676874, 0);
        let night = sources
            .night
            .clone()
            .map(|s| loader(data, batch, s, night_seed, input));
        let Some(d) = ddp else {
            return Ok(Self {
                main,
                main_shard: None,
                night,
                night_shard: None,
            });
        };
        let shard =
            |l: Loader| crate::ddp::shard_loader(l.source().clone(), l.config().clone(), input, d);
        let (main, main_shard) = shard(main)?;
        let (night, night_shard) = match night.map(shard).transpose()? {
            Some((l, s)) => (Some(l), Some(s)),
            None => (None, None),
        };
        Ok(Self {
            main,
            main_shard: Some(main_shard),
            night,
            night_shard,
        })
    }

    /// The night batches from run-wide step `global` on: night batch g of the run is batch
    /// g mod n of night epoch g div n.
    pub(super) fn night_from(
        &self,
        global: usize,
    ) -> Option<impl Iterator<Item = Result<rtf_data::Batch, rtf_data::DataError>> + '_> {
        self.night.as_ref().map(move |n| {
            let per_epoch = n.num_batches().max(1);
            let (start_epoch, start_batch) = (global / per_epoch, global % per_epoch);
            let shard = self.night_shard.clone();
            (start_epoch..).flat_map(move |e| {
                if let Some(shard) = &shard {
                    shard.set_epoch(e as u64);
                }
                n.epoch_from(e as u64, if e == start_epoch { start_batch } else { 0 })
            })
        })
    }
}
