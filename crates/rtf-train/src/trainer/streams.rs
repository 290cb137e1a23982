//! Where a run's frames come from and the loaders over them: the dataset opened and split by
//! what the procedure reads ([`Sources`]), the training and validation loaders, and the
//! batches a run trains on ([`Streams`]).
use std::path::Path;
use std::sync::Arc;

use rtf_core::Daytime;
use rtf_data::frame::Subset;
use rtf_data::{FrameSource, Loader, LoaderConfig, TrainedOn};
use rtf_eval::EvalOptions;

use crate::config::{
    DataConfig, DatasetConfig, Procedure as ProcedureConfig, ScheduleConfig, TrainConfig,
};
use crate::ddp::Ddp;
use crate::error::TrainError;
use crate::run as rundir;

pub(super) type Source = Arc<dyn FrameSource>;

/// Where a run's frames come from: the main stream (labelled frames for supervised training,
/// day frames for the label-free procedures), the night stream if the procedure uses one, and
/// validation (never the test split).
pub(super) struct Sources {
    pub(super) main: Source,
    pub(super) night: Option<Source>,
    pub(super) val: Option<Source>,
    pub(super) ignore_id: Option<u8>,
    /// The dataset, opened once.
    pub(super) dataset: rtf_data::Dataset,
    /// The class set and thermal rule the weights record (rtf_data::trained_on).
    pub(super) trained_on: TrainedOn,
}

/// A dataset's training frames, validation frames, the opened dataset (its layout says
/// whether validation scores HeatNet's convention; its fingerprint goes in config.json), and
/// what the weights trained on it record.
type Opened = (Source, Option<Source>, rtf_data::Dataset, TrainedOn);

/// A dataset's training frames (labelled ones when `labels`) and the rest of [`Opened`]: the
/// root opened once by rtf-data as the kind the run recorded. A root whose classes differ from
/// those recorded when the run started is refused.
fn open_dataset(dataset: &DatasetConfig, labels: bool) -> Result<Opened, TrainError> {
    let choice = dataset.choice();
    let opened = rtf_data::Dataset::open_recorded(dataset.root(), choice.kind)?;
    let trained_on = opened.trained_on();
    if let Some(recorded) = dataset.recorded() {
        let hint = "the dataset's classes changed since the run started (its config.json \
                    records them): restore them, or start a new run";
        recorded.check_data(
            Path::new(rundir::CONFIG_FILE),
            opened.origin(),
            &trained_on.classes,
            hint,
        )?;
    }
    let frames = opened.training(&choice, labels)?;
    Ok((frames.train, frames.val, opened, trained_on))
}

/// The run's frame streams: `dataset` opened, split by what `procedure` reads.
pub(super) fn open_sources(
    dataset: &DatasetConfig,
    procedure: &ProcedureConfig,
) -> Result<Sources, TrainError> {
    let labels = procedure.reads_labels();
    let (train, val, dataset, trained_on) = open_dataset(dataset, labels)?;
    let ignore_id = train.class_set().ignore_id;
    if labels {
        return Ok(Sources {
            main: train,
            night: None,
            val,
            ignore_id,
            dataset,
            trained_on,
        });
    }
    let day: Source = Arc::new(Subset::of_daytime(train.clone(), Daytime::Day, false));
    if day.is_empty() {
        return Err(TrainError::Config(
            "the training frames hold no day frame (MF: names ending in D; Freiburg: paths without `night`)".into(),
        ));
    }
    let night = match procedure.uses_night() {
        true => {
            let night: Source = Arc::new(Subset::of_daytime(train, Daytime::Night, false));
            if night.is_empty() {
                return Err(TrainError::Config(format!(
                    "the {} procedure needs night frames; the training frames hold none",
                    procedure.name()
                )));
            }
            Some(night)
        }
        false => None,
    };
    Ok(Sources {
        // Unlabelled subsets of MF gain an ignore id: label caches mark low confidence with it.
        ignore_id: day.class_set().ignore_id,
        main: day,
        night,
        val,
        dataset,
        trained_on,
    })
}

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
