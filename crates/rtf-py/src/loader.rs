//! `Dataset.loader`: rtf's loader threads (rtf_data::Loader, configured as `rtf train`
//! configures its training loader) as a Python iterable of torch `(x, y)` batches. Each
//! `iter()` is the next epoch (from `epoch`, 0 by default, as training counts them); the
//! batches of an epoch depend only on (seed, epoch).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use crate::tensor::PyTensor;
use crossbeam_channel::Receiver;
use pyo3::prelude::*;
use rtf_data::{AugmentConfig, Batch, DataError, Loader, LoaderConfig};
use rtf_models::ModelConfig;

use crate::errors::{input, PyResultExt};

/// Batches of a split, epoch after epoch.
#[pyclass(module = "rtf", name = "Loader", frozen)]
pub struct PyLoader {
    loader: Arc<Loader>,
    next_epoch: AtomicU64,
}

/// The loader `rtf train` builds for its training frames (trainer.rs `loader`): the batch
/// size, shuffling, seed, worker threads, a prefetch of 2, the augmentation and resize.
fn training_loader(
    data: &rtf_data::Dataset,
    split: &str,
    cfg: LoaderConfig,
    model: &str,
) -> PyResult<Loader> {
    let source = data.split(split, true).py()?;
    let classes = source.class_set().len() as i64;
    let convention = ModelConfig::from_name(model, classes)
        .py()?
        .input_convention();
    Ok(Loader::new(source, cfg, convention))
}

/// What `Dataset.loader` was asked for (see its docs in dataset.rs).
pub struct LoaderRequest<'a> {
    pub split: &'a str,
    pub model: &'a str,
    pub cfg: LoaderConfig,
    pub epoch: u64,
}

impl LoaderRequest<'_> {
    /// The loader's configuration from `Dataset.loader`'s arguments: `augment` is the
    /// horizontal flips of MFNet's and RTFNet's recipes.
    pub fn config(
        batch_size: usize,
        shuffle: bool,
        augment: bool,
        workers: usize,
        seed: u64,
        size: Option<(usize, usize)>,
    ) -> PyResult<LoaderConfig> {
        if batch_size == 0 {
            return Err(input("batch_size: expected at least 1, got 0"));
        }
        Ok(LoaderConfig {
            batch_size,
            shuffle,
            drop_last: false,
            seed,
            workers,
            prefetch: 2,
            augment: AugmentConfig {
                hflip: augment,
                ..Default::default()
            },
            resize: size,
        })
    }

    pub fn open(self, data: &rtf_data::Dataset) -> PyResult<PyLoader> {
        Ok(PyLoader {
            loader: Arc::new(training_loader(data, self.split, self.cfg, self.model)?),
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
