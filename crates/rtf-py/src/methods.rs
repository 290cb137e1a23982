//! The network object's methods (`net.logits`, `net.predict`, `net(x)`, `net.classes`,
//! `net.colorize`, `net.parameters`, `net.train` / `net.eval`).

use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};

use crate::tensor::PyTensor;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rtf_data::Frame;
use rtf_eval::predict::{self, PairSamples};
use tch::{Kind, Tensor};

use crate::arrays::{self, to_numpy};
use crate::errors::{input, PyResultExt, TorchError};
use crate::network::PyNetwork;

fn check_range(range: Option<(f64, f64)>) -> PyResult<Option<(f64, f64)>> {
    match range {
        Some((lo, hi)) if !(lo.is_finite() && hi.is_finite() && lo < hi) => Err(input(format!(
            "thermal_range: expected (lo, hi) with lo < hi, got ({lo}, {hi})"
        ))),
        range => Ok(range),
    }
}

impl PyNetwork {
    /// The frame `rtf predict --rgb --thermal` reads from files, from arrays: the same thermal
    /// rule (`thermal_range`, else the weights', else the model's default).
    fn frame(
        &self,
        rgb: &Bound<'_, PyAny>,
        thermal: &Bound<'_, PyAny>,
        thermal_range: Option<(f64, f64)>,
    ) -> PyResult<Frame> {
        let range = check_range(thermal_range)?;
        let (rgb, width, height) = arrays::rgb(rgb)?;
        let (samples, tw, th) = arrays::thermal(thermal)?;
        if (tw, th) != (width, height) {
            return Err(input(format!(
                "thermal is {tw}x{th} (W x H) but rgb is {width}x{height}: the pair must be \
                 registered at the same size"
            )));
        }
        let rule = predict::thermal_rule(range, &self.name, self.trained.as_ref());
        let pair = PairSamples {
            name: "array".into(),
            width,
            height,
            rgb,
            thermal: &samples,
        };
        pair.into_frame(rule, Path::new("thermal (array)")).py()
    }

    /// `rtf_eval::predict::frame_logits` with the GIL released: [C, H, W] float32.
    fn frame_logits(&self, py: Python<'_>, frame: &Frame) -> PyResult<Tensor> {
        let device = self.device;
        py.allow_threads(|| {
            let held = self.held.lock().unwrap_or_else(|e| e.into_inner());
            let net = held.net.as_ref();
            rtf_eval::evaluate::check_memory(net, 1, frame.height, frame.width, device)?;
            predict::frame_logits(net, frame, device)
        })
        .py()
    }

    /// The tensor of `x`, refused unless a floating-point torch tensor [B, 4, H, W] on the
    /// network's device (asked of torch: tch knows only the devices it can run on).
    fn tensor_of(&self, x: &Bound<'_, PyAny>) -> PyResult<Tensor> {
        let device = x
            .getattr("device")
            .and_then(|d| d.str().map(|s| s.to_string()))
            .ok();
        let tensor = x
            .extract::<PyTensor>()
            .map_err(|_| input(format!("x: expected a torch.Tensor, got {}", x.get_type())))?
            .0;
        let shape = tensor.size();
        let float = matches!(
            tensor.kind(),
            Kind::Float | Kind::Double | Kind::Half | Kind::BFloat16
        );
        if shape.len() != 4 || shape[1] != 4 || !float {
            return Err(input(format!(
                "x: expected a floating-point tensor of shape [B, 4, H, W] (R, G, B, T), got \
                 {:?} of shape {shape:?}",
                tensor.kind()
            )));
        }
        let here = self.device();
        let matches = device.as_deref() == Some(here.as_str())
            || (here == "cuda:0" && device.as_deref() == Some("cuda"));
        if !matches {
            return Err(input(format!(
                "x is on {} but the network is on {here}: move one (x.to(...)) first",
                device.as_deref().unwrap_or("an unknown device")
            )));
        }
        Ok(tensor)
    }
}

#[pymethods]
impl PyNetwork {
    /// Logits [classes, H, W] float32 (NumPy) of one frame: `rgb` H×W×3 uint8, `thermal` H×W
    /// uint8 / uint16 / float32 mapped to [0, 1] by `thermal_range` (lo, hi), else the rule the
    /// weights record, else the model's default. Equal to `rtf predict --logits`.
    #[pyo3(signature = (rgb, thermal, thermal_range=None))]
    fn logits<'py>(
        &self,
        py: Python<'py>,
        rgb: &Bound<'py, PyAny>,
        thermal: &Bound<'py, PyAny>,
        thermal_range: Option<(f64, f64)>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let frame = self.frame(rgb, thermal, thermal_range)?;
        let logits = self.frame_logits(py, &frame)?;
        to_numpy(py, logits)
    }

    /// Class ids H×W uint8 (NumPy) of one frame, in the dataset's own label values (the
    /// `<stem>.png` `rtf predict` writes).
    #[pyo3(signature = (rgb, thermal, thermal_range=None))]
    fn predict<'py>(
        &self,
        py: Python<'py>,
        rgb: &Bound<'py, PyAny>,
        thermal: &Bound<'py, PyAny>,
        thermal_range: Option<(f64, f64)>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let frame = self.frame(rgb, thermal, thermal_range)?;
        let logits = self.frame_logits(py, &frame)?;
        let ids = predict::class_ids(&logits).py()?;
        let values: Vec<u8> = ids.iter().map(|&i| self.classes.label_value(i)).collect();
        let shape = [frame.height as i64, frame.width as i64];
        to_numpy(py, Tensor::from_slice(&values).view(shape))
    }

    /// The forward pass on a torch tensor [B, 4, H, W] (channels R, G, B, T after the
    /// network's input convention) on the network's device; torch logits [B, classes, H, W].
    /// In eval mode (the default) as `rtf eval` runs it (padded to the size multiple, no
    /// autograd); after `train()` the plain forward in training mode, with autograd.
    fn __call__(&self, py: Python<'_>, x: &Bound<'_, PyAny>) -> PyResult<PyTensor> {
        let x = self.tensor_of(x)?;
        let training = self.training;
        rtf_eval::evaluate::install_quiet_panic_hook();
        // The tensor moves into the closure: tch tensors are Send, not Sync.
        let out = py.allow_threads(move || {
            let held = self.held.lock().unwrap_or_else(|e| e.into_inner());
            let net = held.net.as_ref();
            if !training {
                return rtf_eval::evaluate::logits(net, &x).py();
            }
            std::panic::catch_unwind(AssertUnwindSafe(|| net.forward_t(&x, true)))
                .map_err(|p| TorchError::new_err(crate::panic_message(&p)))
        });
        out.map(PyTensor)
    }

    /// The classes, in output order: id (output index), name, colour (RGB), label value (the
    /// dataset's id for it).
    #[getter]
    fn classes<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        arrays::class_records(py, &self.classes)
    }

    /// The device the network is on (`cpu`, `cuda:0`, ...).
    #[getter]
    fn device(&self) -> String {
        match self.device {
            tch::Device::Cuda(i) => format!("cuda:{i}"),
            _ => "cpu".into(),
        }
    }

    /// Palette colours H×W×3 uint8 of class ids H×W uint8 as `predict` returns them (the
    /// dataset's label values); values outside the set are white.
    fn colorize<'py>(
        &self,
        py: Python<'py>,
        ids: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let (values, width, height) = arrays::ids(ids)?;
        let lookup = self.classes.label_values.as_ref().map(|v| v.lookup(None));
        let outputs: Vec<u8> = values
            .iter()
            .map(|&v| lookup.map_or(v, |table| table[v as usize].unwrap_or(u8::MAX)))
            .collect();
        let colours = self.classes.colorize(&outputs);
        to_numpy(
            py,
            Tensor::from_slice(&colours).view([height as i64, width as i64, 3]),
        )
    }

    /// The trainable parameters as torch tensors (the network's own storage), for a torch
    /// optimiser.
    fn parameters(&self) -> Vec<PyTensor> {
        let held = self.held.lock().unwrap_or_else(|e| e.into_inner());
        held.vs
            .trainable_variables()
            .into_iter()
            .map(PyTensor)
            .collect()
    }

    /// Writes the weights as `rtf train` does (safetensors, reference names, the network and
    /// its inputs in the metadata; temp file + rename). Refuses an existing file unless
    /// `overwrite`, and a network on the fast path (its plain weights are released).
    #[pyo3(signature = (path, overwrite=false))]
    fn save(&self, py: Python<'_>, path: PathBuf, overwrite: bool) -> PyResult<()> {
        if self.built.precision.is_some() {
            return Err(input(
                "save: a network loaded with a precision (the fast path) keeps only its folded \
                 weights; load it with precision=None to save it",
            ));
        }
        if path.exists() && !overwrite {
            return Err(input(format!(
                "save: {} exists (overwrite=True replaces it)",
                path.display()
            )));
        }
        if self.weights.as_deref() == Some(path.as_path()) {
            return Err(input(format!(
                "save: {} is the file these weights were read from",
                path.display()
            )));
        }
        let built = &self.built;
        py.allow_threads(|| {
            let held = self.held.lock().unwrap_or_else(|e| e.into_inner());
            rtf_models::io::weights::save_safetensors(&held.vs, &built.cfg, built.modality, &path)
        })
        .py()
    }

    /// Training mode for `net(x)` (batch statistics, dropout, autograd). Returns the network.
    #[pyo3(signature = (mode=true))]
    fn train(mut slf: PyRefMut<'_, Self>, mode: bool) -> PyRefMut<'_, Self> {
        slf.training = mode;
        slf
    }

    /// Eval mode for `net(x)` (the default). Returns the network.
    fn eval(mut slf: PyRefMut<'_, Self>) -> PyRefMut<'_, Self> {
        slf.training = false;
        slf
    }

    fn __repr__(&self) -> String {
        format!(
            "rtf.Network({:?}, classes={}, inputs={}, device={})",
            self.name,
            self.classes.len(),
            self.inputs,
            self.device()
        )
    }
}
