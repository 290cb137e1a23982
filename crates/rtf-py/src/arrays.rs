//! NumPy arrays in (through the buffer protocol: no copy until rtf's own planes are filled),
//! each checked for dtype and shape with an `rtf.InputError` naming what was given and what
//! is expected, before anything runs; tensors and class sets out.

use crate::tensor::PyTensor;
use pyo3::buffer::{Element, PyBuffer};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rtf_core::ClassSet;
use rtf_data::images::ThermalSamples;
use tch::Tensor;

use crate::errors::input;

/// `dtype [d0, d1, ...]` of an array-like, for messages.
fn given(obj: &Bound<'_, PyAny>) -> String {
    let dtype = obj
        .getattr("dtype")
        .and_then(|d| d.str().map(|s| s.to_string()));
    let shape = obj
        .getattr("shape")
        .and_then(|s| s.str().map(|s| s.to_string()));
    match (dtype, shape) {
        (Ok(dtype), Ok(shape)) => format!("dtype {dtype}, shape {shape}"),
        _ => format!(
            "a {}",
            obj.get_type().name().map_or("?".into(), |n| n.to_string())
        ),
    }
}

/// The array's samples (row-major) and shape, if its dtype is `T`.
fn samples<T: Element + Copy>(obj: &Bound<'_, PyAny>) -> Option<(Vec<T>, Vec<usize>)> {
    let buffer = PyBuffer::<T>::get(obj).ok()?;
    let shape = buffer.shape().to_vec();
    let values = buffer.to_vec(obj.py()).ok()?;
    Some((values, shape))
}

/// An RGB image, H×W×3 uint8: (interleaved bytes, width, height).
pub fn rgb(obj: &Bound<'_, PyAny>) -> PyResult<(Vec<u8>, usize, usize)> {
    match samples::<u8>(obj) {
        Some((values, shape)) if shape.len() == 3 && shape[2] == 3 => {
            Ok((values, shape[1], shape[0]))
        }
        _ => Err(input(format!(
            "rgb: expected a numpy array of dtype uint8 and shape (H, W, 3), got {}",
            given(obj)
        ))),
    }
}

/// One grey plane of H×W or H×W×C samples (C = 3 or 4 with equal colour channels, as the
/// image readers take grey stored as colour); (plane, width, height).
fn grey<T: Copy + PartialEq>(
    values: Vec<T>,
    shape: &[usize],
    what: &dyn Fn() -> String,
) -> PyResult<(Vec<T>, usize, usize)> {
    match *shape {
        [h, w] => Ok((values, w, h)),
        [h, w, c @ (1 | 3 | 4)] => match rtf_data::planes::grey_plane(&values, c) {
            Some(plane) => Ok((plane, w, h)),
            None => Err(input(format!(
                "thermal: {} has {c} channels that differ (a colour-mapped rendering?); rtf \
                 reads thermal from one grey channel",
                what()
            ))),
        },
        _ => Err(input(format!(
            "thermal: expected shape (H, W) (or (H, W, 3) of equal channels), got {}",
            what()
        ))),
    }
}

/// A thermal image: H×W uint8 or uint16 counts, or float32 values (degrees), as the
/// datasets' readers return them; (samples, width, height).
pub fn thermal(obj: &Bound<'_, PyAny>) -> PyResult<(ThermalSamples, usize, usize)> {
    let what = || given(obj);
    if let Some((values, shape)) = samples::<u8>(obj) {
        let (plane, w, h) = grey(values, &shape, &what)?;
        let values = plane.into_iter().map(u16::from).collect();
        return Ok((ThermalSamples::Counts { bits: 8, values }, w, h));
    }
    if let Some((values, shape)) = samples::<u16>(obj) {
        let (values, w, h) = grey(values, &shape, &what)?;
        return Ok((ThermalSamples::Counts { bits: 16, values }, w, h));
    }
    if let Some((values, shape)) = samples::<f32>(obj) {
        let (values, w, h) = grey(values, &shape, &what)?;
        return Ok((ThermalSamples::Degrees(values), w, h));
    }
    Err(input(format!(
        "thermal: expected a numpy array of dtype uint8, uint16 or float32 and shape (H, W), \
         got {}",
        what()
    )))
}

/// Class ids, H×W uint8: (values, width, height).
pub fn ids(obj: &Bound<'_, PyAny>) -> PyResult<(Vec<u8>, usize, usize)> {
    match samples::<u8>(obj) {
        Some((values, shape)) if shape.len() == 2 => Ok((values, shape[1], shape[0])),
        _ => Err(input(format!(
            "ids: expected a numpy array of dtype uint8 and shape (H, W), got {}",
            given(obj)
        ))),
    }
}

/// A tensor to NumPy (`Tensor.numpy()`: the same memory).
pub fn to_numpy(py: Python<'_>, tensor: Tensor) -> PyResult<Bound<'_, PyAny>> {
    PyTensor(tensor).into_pyobject(py)?.call_method0("numpy")
}

/// The classes of a set in output order: id, name, colour, the label value a dataset file
/// uses for it; the ignore id (if any) is `Dataset.ignore_id`.
pub fn class_records<'py>(py: Python<'py>, set: &ClassSet) -> PyResult<Vec<Bound<'py, PyDict>>> {
    set.classes
        .iter()
        .map(|class| {
            let record = PyDict::new(py);
            record.set_item("id", class.id)?;
            record.set_item("name", &class.name)?;
            let [r, g, b] = class.color;
            record.set_item("color", (r, g, b))?;
            record.set_item("label_value", set.label_value(class.id))?;
            Ok(record)
        })
        .collect()
}
