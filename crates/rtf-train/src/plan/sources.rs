//! Where a run's frames come from: its dataset opened once, by rtf-data as the kind the run
//! recorded, and split by what the procedure reads ([`Sources`]).
use std::path::Path;
use std::sync::Arc;

use rtf_core::Daytime;
use rtf_data::dataset::{DatasetFormat, RecordedKind};
use rtf_data::frame::Subset;
use rtf_data::{FrameSource, TrainedOn};

use crate::config::{DatasetConfig, Procedure as ProcedureConfig};
use crate::error::TrainError;

pub type Source = Arc<dyn FrameSource>;

/// Where a run's frames come from: the main stream (labelled frames for supervised training,
/// day frames for the label-free procedures), the night stream if the procedure uses one, and
/// validation (never the test split).
pub struct Sources {
    pub main: Source,
    pub night: Option<Source>,
    pub val: Option<Source>,
    pub ignore_id: Option<u8>,
    /// The dataset, opened once (its layout says whether validation scores HeatNet's
    /// convention; its fingerprint goes in config.json).
    pub dataset: rtf_data::Dataset,
    /// The class set and thermal rule the weights record (rtf_data::trained_on).
    pub trained_on: TrainedOn,
}

/// A dataset's training frames, validation frames, the opened dataset, and what the weights
/// trained on it record.
type Opened = (Source, Option<Source>, rtf_data::Dataset, TrainedOn);

#[cfg(test)]
thread_local! {
    /// How many times this thread opened a dataset root here (the plan's tests).
    pub(super) static OPENED: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// Whether `opened` is the root `dataset` names, opened as the kind it records.
fn is_opened(opened: &rtf_data::Dataset, dataset: &DatasetConfig, kind: RecordedKind) -> bool {
    let format = opened.format();
    let as_kind = match kind {
        RecordedKind::Mf => format == DatasetFormat::Mf,
        RecordedKind::Freiburg => format == DatasetFormat::Freiburg,
        RecordedKind::Described => format.is_described(),
    };
    as_kind && opened.root() == dataset.root()
}

/// A dataset's training frames (labelled ones when `labels`) and the rest of [`Opened`]: the
/// root opened once by rtf-data as the kind the run recorded (`opened`, when it is that root
/// opened so already: `rtf train`'s setup opened it). A root whose classes differ from those
/// recorded when the run started is refused.
fn open_dataset(
    dataset: &DatasetConfig,
    labels: bool,
    opened: Option<rtf_data::Dataset>,
) -> Result<Opened, TrainError> {
    let choice = dataset.choice();
    let opened = match opened.filter(|d| is_opened(d, dataset, choice.kind)) {
        Some(opened) => opened,
        None => {
            #[cfg(test)]
            OPENED.with(|n| n.set(n.get() + 1));
            rtf_data::Dataset::open_recorded(dataset.root(), choice.kind)?
        }
    };
    let trained_on = opened.trained_on();
    if let Some(recorded) = dataset.recorded() {
        let hint = "the dataset's classes changed since the run started (its config.json \
                    records them): restore them, or start a new run";
        rtf_data::trained_on::check_data(
            recorded,
            Path::new(rtf_run::CONFIG_FILE),
            opened.origin(),
            &trained_on.classes,
            hint,
        )?;
    }
    let frames = opened.training(&choice, labels)?;
    Ok((frames.train, frames.val, opened, trained_on))
}

/// The run's frame streams: `dataset` opened, split by what `procedure` reads.
pub fn open_sources(
    dataset: &DatasetConfig,
    procedure: &ProcedureConfig,
) -> Result<Sources, TrainError> {
    open_sources_in(dataset, procedure, None)
}

/// [`open_sources`] from the root already `opened`, when it is the one `dataset` names.
pub fn open_sources_in(
    dataset: &DatasetConfig,
    procedure: &ProcedureConfig,
    opened: Option<rtf_data::Dataset>,
) -> Result<Sources, TrainError> {
    let labels = procedure.reads_labels();
    let (train, val, dataset, trained_on) = open_dataset(dataset, labels, opened)?;
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
