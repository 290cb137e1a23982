//! `rtf.evaluate`: `rtf eval`'s scoring (rtf_eval::evaluate) of a network on a split, returned
//! as the values `rtf eval --json` writes (the same serde records, read back by Python's json).

use std::path::Path;

use pyo3::prelude::*;
use rtf_eval::{EvalOptions, Inference, InferenceOptions};

use crate::dataset::PyDataset;
use crate::errors::{input, PyResultExt};
use crate::network::PyNetwork;

/// `rtf eval`'s options: sliding windows at its default crop and stride (480×640, 2/3),
/// scales, flip, batch size, resize, its 2 reader threads.
fn options(
    sliding: bool,
    scales: Option<Vec<f64>>,
    flip: bool,
    batch_size: usize,
    resize: Option<(usize, usize)>,
) -> PyResult<EvalOptions> {
    let inference = InferenceOptions {
        mode: match sliding {
            true => Inference::cmx_sliding(),
            false => Inference::Whole,
        },
        scales: scales.unwrap_or_else(|| vec![1.0]),
        flip,
    };
    inference.validate().py()?;
    if batch_size == 0 {
        return Err(input("batch_size: expected at least 1, got 0"));
    }
    Ok(EvalOptions {
        batch_size,
        resize,
        workers: 2,
        inference,
    })
}

/// Refuses data whose class set is not the network's (by the weights' record where they have
/// one, as `rtf eval` does, else by count).
fn check_classes(net: &PyNetwork, data: &PyDataset, split: &rtf_core::ClassSet) -> PyResult<()> {
    if let (Some(trained), Some(weights)) = (&net.trained, &net.weights) {
        let hint = rtf_data::trained_on::WEIGHTS_HINT;
        rtf_data::trained_on::check_data(trained, weights, &data.root, split, hint).py()?;
    }
    if split.len() != net.classes.len() {
        return Err(input(format!(
            "{}: {} classes ({}) but the network has {} ({})",
            data.root.display(),
            split.len(),
            split.names().join(", "),
            net.classes.len(),
            net.classes.names().join(", ")
        )));
    }
    Ok(())
}

/// Scores `net` on `split` of `data` as `rtf eval` does; the values of `rtf eval --json`
/// (`frames`, `miou`, `macc`, `per_class`, `day`, `night`, `class_names`, `confusion`,
/// `inference`) as a dict.
#[pyfunction]
#[pyo3(signature = (net, data, split="test", sliding=false, scales=None, flip=false, batch_size=4, resize=None))]
#[allow(clippy::too_many_arguments)]
pub fn evaluate_json(
    py: Python<'_>,
    net: &PyNetwork,
    data: &PyDataset,
    split: &str,
    sliding: bool,
    scales: Option<Vec<f64>>,
    flip: bool,
    batch_size: usize,
    resize: Option<(usize, usize)>,
) -> PyResult<String> {
    let options = options(sliding, scales, flip, batch_size, resize)?;
    let source = py.allow_threads(|| data.dataset.split(split, true)).py()?;
    let classes = source.class_set().clone();
    check_classes(net, data, &classes)?;
    rtf_eval::evaluate::install_quiet_panic_hook();
    let device = net.device;
    let report = py
        .allow_threads(|| {
            let held = net.held.lock().unwrap_or_else(|e| e.into_inner());
            rtf_eval::evaluate(held.net.as_ref(), source, &options, device)
        })
        .py()?;
    let record = serde_json::json!({
        "model": net.name,
        "inputs": net.inputs,
        "weights": net.weights.as_deref().map(Path::display).map(|p| p.to_string()),
        "data": data.root.display().to_string(),
        "split": split,
        "inference": options.inference,
        "frames": report.frames,
        "all": report.all,
        "day": report.day,
        "night": report.night,
        "class_names": classes.names(),
        "confusion": report.confusion.rows(),
    });
    serde_json::to_string(&record).map_err(|e| input(e.to_string()))
}
