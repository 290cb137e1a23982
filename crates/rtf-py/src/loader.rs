//! `Dataset.loader`: rtf's loader threads (the loader `rtf train` builds for the same options:
//! rtf_train::trainer::training_loader) as a Python iterable of torch `(x, y)` batches. Each
//! `iter()` is the next epoch (from `epoch`, 0 by default, as training counts them); the
//! batches of an epoch depend only on (seed, epoch).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use crate::tensor::PyTensor;
use crossbeam_channel::Receiver;
use pyo3::prelude::*;
use rtf_data::{Batch, DataError, Loader};
use rtf_train::setup::{NewRun, Overrides};
use std::path::Path;

use crate::errors::{input, PyResultExt};

/// Batches of a split, epoch after epoch.
#[pyclass(module = "rtf", name = "Loader", frozen)]
pub struct PyLoader {
    loader: Arc<Loader>,
    next_epoch: AtomicU64,
}

/// What `Dataset.loader` was asked for (see its docs in dataset.rs): `rtf train`'s options
/// that decide its training batches.
pub struct LoaderRequest<'a> {
    pub root: &'a Path,
    /// Freiburg Thermal trains on its training tree (`train`), never a named split.
    pub freiburg: bool,
    pub split: &'a str,
    pub model: Option<&'a str>,
    pub recipe: Option<&'a str>,
    pub batch_size: usize,
    pub shuffle: bool,
    pub augment: bool,
    pub workers: usize,
    pub seed: u64,
    pub size: Option<(usize, usize)>,
    pub epoch: u64,
}

impl LoaderRequest<'_> {
    /// The run `rtf train --data ROOT --train-split SPLIT --val-split none` with these options
    /// would make (rtf_train::setup): its configuration decides the loader.
    fn new_run(&self) -> PyResult<NewRun> {
        let train_split = match (self.freiburg, self.split) {
            (false, split) => Some(split.to_owned()),
            (true, "train") => None,
            (true, other) => {
                return Err(input(format!(
                    "split {other:?}: a Freiburg Thermal root trains on its training tree only \
                     (split \"train\"); read the {other:?} frames with Dataset.split"
                )))
            }
        };
        Ok(NewRun {
            recipe: self.recipe.map(str::to_owned),
            data: Some(self.root.to_path_buf()),
            train_split,
            val_split: Some("none".into()),
            overrides: Overrides {
                model: self.model.map(str::to_owned),
                batch_size: Some(self.batch_size),
                seed: Some(self.seed),
                workers: Some(self.workers),
                no_shuffle: !self.shuffle,
                no_augment: !self.augment,
                resize: self.size,
                ..Default::default()
            },
            ..Default::default()
        })
    }

    /// The trainer's loader of that run (rtf_train::trainer::training_loader; of its last
    /// stage for a multi-stage recipe).
    pub fn open(self, py: Python<'_>) -> PyResult<PyLoader> {
        if self.batch_size == 0 {
            return Err(input("batch_size: expected at least 1, got 0"));
        }
        let asked = self.new_run()?;
        let loader = py.allow_threads(|| -> PyResult<Loader> {
            let cfg = rtf_train::setup::new_run(&asked).py()?;
            let stages = cfg.stages();
            let (_, last) = stages
                .last()
                .ok_or_else(|| input("the recipe has no stage"))?;
            rtf_train::trainer::training_loader(last).py()
        })?;
        Ok(PyLoader {
            loader: Arc::new(loader),
            next_epoch: AtomicU64::new(self.epoch),
        })
    }
}

#[pymethods]
impl PyLoader {
    /// Batches per epoch.
    fn __len__(&self) -> usize {
        self.loader.num_batches()
    }

    /// The next epoch's batches.
    fn __iter__(&self) -> PyEpoch {
        let epoch = self.next_epoch.fetch_add(1, Ordering::SeqCst);
        self.epoch(epoch)
    }

    /// The batches of epoch `epoch` (0 = the first, as `rtf train` counts).
    fn epoch(&self, epoch: u64) -> PyEpoch {
        // The loader's epoch iterator borrows the loader: a thread owns both and hands the
        // batches over (its own queue holds one; the loader's threads prefetch the rest).
        let (tx, rx) = crossbeam_channel::bounded(1);
        let loader = self.loader.clone();
        std::thread::spawn(move || {
            for batch in loader.epoch(epoch) {
                if tx.send(batch).is_err() {
                    break;
                }
            }
        });
        PyEpoch { rx, epoch }
    }
}

/// One epoch's batches (an iterator).
#[pyclass(module = "rtf", name = "Epoch", frozen)]
pub struct PyEpoch {
    rx: Receiver<Result<Batch, DataError>>,
    #[pyo3(get)]
    epoch: u64,
}

#[pymethods]
impl PyEpoch {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    /// The next `(x, y)`, waited for with the GIL released.
    fn __next__(&self, py: Python<'_>) -> PyResult<Option<(PyTensor, PyTensor)>> {
        match py.allow_threads(|| self.rx.recv()) {
            Ok(batch) => {
                let batch = batch.py()?;
                Ok(Some((PyTensor(batch.input), PyTensor(batch.target))))
            }
            Err(_) => Ok(None),
        }
    }
}
