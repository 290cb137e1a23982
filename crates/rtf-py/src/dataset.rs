//! `rtf.open_dataset`: a dataset root opened by the readers `rtf train` and `rtf eval` use
//! (rtf_data::dataset), its splits and frames as NumPy arrays.

use std::path::PathBuf;
use std::sync::Arc;

use pyo3::exceptions::PyIndexError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rtf_data::{Dataset, Frame, FrameSource};
use tch::Tensor;

use crate::arrays::{class_records, to_numpy};
use crate::errors::PyResultExt;
use crate::loader::LoaderRequest;

/// A dataset root (`rtf.open_dataset`): MF, Freiburg Thermal or a described layout
/// (dataset.yaml, MSRS, PST900, FMB).
#[pyclass(module = "rtf", name = "Dataset", frozen)]
pub struct PyDataset {
    pub dataset: Dataset,
    #[pyo3(get)]
    pub root: PathBuf,
}

/// Opens the dataset at `root` as `rtf train` and `rtf eval` do (a described root's inferred
/// layout, classes and thermal rule announced on stderr).
#[pyfunction]
pub fn open_dataset(py: Python<'_>, root: PathBuf) -> PyResult<PyDataset> {
    let root = rtf_data::dataset::root_of(&root);
    let dataset = py
        .allow_threads(|| rtf_data::dataset::open_for(&root, "a dataset"))
        .py()?;
    if let Some(line) = dataset.announcement() {
        eprintln!("data: {line}");
    }
    Ok(PyDataset { dataset, root })
}

#[pymethods]
impl PyDataset {
    /// The classes (output order) with their label values.
    #[getter]
    fn classes<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        class_records(py, &self.dataset.class_set())
    }

    /// The label id the loss and the metrics ignore, if the set has one.
    #[getter]
    fn ignore_id(&self) -> Option<u8> {
        self.dataset.class_set().ignore_id
    }

    /// The layout's name (mf, freiburg, dataset.yaml, msrs, ...).
    #[getter]
    fn layout(&self) -> &'static str {
        self.dataset.layout_name()
    }

    /// The split names.
    #[getter]
    fn splits(&self) -> PyResult<Vec<String>> {
        self.dataset.split_names().py()
    }

    /// The frames of split `name` with their labels (`labels=False`: images only).
    #[pyo3(signature = (name, labels=true))]
    fn split(&self, py: Python<'_>, name: &str, labels: bool) -> PyResult<PySplit> {
        let source = py.allow_threads(|| self.dataset.split(name, labels)).py()?;
        Ok(PySplit {
            source,
            name: name.to_string(),
        })
    }

    /// An iterable of `(x, y)` torch batches of `split`: the training batches of
    /// `rtf train --data ROOT --train-split SPLIT` with these options (the trainer's own loader:
    /// frames, order, augmentation and input convention), `x` float32 [B, 4, H, W] (R, G, B, T
    /// after the network's input convention), `y` int64 [B, H, W] (output indices, the ignore
    /// id where the loss ignores). `augment`: the recipe's or network's augmentation (False:
    /// `--no-augment`); `shuffle` (False: `--no-shuffle`); `size`: (width, height) every frame
    /// is resized to; `seed`: `--seed`; `model` (default mfnet) and `recipe`: as `rtf train`'s.
    /// Each `iter()` is the next epoch from `epoch`; `loader.epoch(e)` is epoch `e`.
    #[pyo3(signature = (split, batch_size, shuffle=true, augment=true, workers=2, seed=0, size=None, model=None, epoch=0, recipe=None))]
    #[allow(clippy::too_many_arguments)]
    fn loader(
        &self,
        py: Python<'_>,
        split: &str,
        batch_size: usize,
        shuffle: bool,
        augment: bool,
        workers: usize,
        seed: u64,
        size: Option<(usize, usize)>,
        model: Option<&str>,
        epoch: u64,
        recipe: Option<&str>,
    ) -> PyResult<crate::loader::PyLoader> {
        let request = LoaderRequest {
            root: &self.root,
            freiburg: matches!(self.dataset.layout(), rtf_data::dataset::Layout::Freiburg),
            split,
            model,
            recipe,
            batch_size,
            shuffle,
            augment,
            workers,
            seed,
            size,
            epoch,
        };
        request.open(py)
    }

    fn __repr__(&self) -> String {
        format!(
            "rtf.Dataset({:?}, layout={}, classes={})",
            self.root.display().to_string(),
            self.dataset.layout_name(),
            self.dataset.class_set().len()
        )
    }
}

/// The frames of one split: `len(split)`, `split[i]`.
#[pyclass(module = "rtf", name = "Split", frozen)]
pub struct PySplit {
    pub source: Arc<dyn FrameSource>,
    #[pyo3(get)]
    pub name: String,
}

#[pymethods]
impl PySplit {
    fn __len__(&self) -> usize {
        self.source.len()
    }

    /// Frame `index` (negative from the end), read by the dataset's readers.
    fn __getitem__(&self, py: Python<'_>, index: isize) -> PyResult<PyFrame> {
        let len = self.source.len() as isize;
        let i = if index < 0 { index + len } else { index };
        if !(0..len).contains(&i) {
            return Err(PyIndexError::new_err(format!(
                "frame {index} of split `{}` with {len} frames",
                self.name
            )));
        }
        let frame = py.allow_threads(|| self.source.load(i as usize)).py()?;
        PyFrame::new(py, frame)
    }

    /// The frame names, in order.
    #[getter]
    fn names(&self) -> Vec<String> {
        (0..self.source.len())
            .map(|i| self.source.frame_name(i).to_string())
            .collect()
    }

    fn __repr__(&self) -> String {
        format!("rtf.Split({:?}, frames={})", self.name, self.source.len())
    }
}

/// One frame: `name`, `daytime` ("day", "night" or None), `rgb` H×W×3 uint8, `thermal` H×W
/// float32 in [0, 1] (the dataset's thermal rule applied), `label` H×W uint8 output indices
/// (the ignore id where the loss ignores a pixel) or None.
#[pyclass(module = "rtf", name = "Frame", frozen, get_all)]
pub struct PyFrame {
    pub name: String,
    pub daytime: Option<String>,
    pub rgb: PyObject,
    pub thermal: PyObject,
    pub label: Option<PyObject>,
}

impl PyFrame {
    fn new(py: Python<'_>, frame: Frame) -> PyResult<Self> {
        let (h, w) = (frame.height as i64, frame.width as i64);
        let array = |t: Tensor| to_numpy(py, t).map(Bound::unbind);
        Ok(PyFrame {
            daytime: frame.daytime.map(|d| format!("{d:?}").to_lowercase()),
            rgb: array(Tensor::from_slice(&frame.rgb).view([h, w, 3]))?,
            thermal: array(Tensor::from_slice(&frame.thermal).view([h, w]))?,
            label: frame
                .label
                .map(|l| array(Tensor::from_slice(&l).view([h, w])))
                .transpose()?,
            name: frame.name,
        })
    }
}
