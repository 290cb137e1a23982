//! `rtf.Run(path)`: a training run folder read back typed, by the reader `rtf report` and
//! `cargo xtask reproduce` use (rtf_run::RunFolder): its configuration, its per-epoch log,
//! its stages and its weights files.

use std::path::PathBuf;

use pyo3::prelude::*;
use rtf_run::RunFolder;

use crate::errors::DataError;

/// The run folder `path` as JSON: `dir`, `config` (config.json's document; None before it is
/// written), `stages` (the stage folders' names of a multi-stage run), `epochs` (log.jsonl's
/// records; [] without a log), `weights` (`best`, `final`, `selected`).
#[pyfunction]
pub fn read_run(path: PathBuf) -> PyResult<String> {
    let error = |e: rtf_run::RunError| DataError::new_err(crate::errors::message(&e));
    let folder = RunFolder::open(&path).map_err(error)?;
    let config = folder.document();
    let epochs = match folder.has_log() {
        true => folder.epochs().map_err(error)?,
        false => Vec::new(),
    };
    let weights = folder.weights();
    let record = serde_json::json!({
        "dir": folder.dir(),
        "config": config,
        "stages": folder.stage_names(),
        "epochs": epochs,
        "weights": {
            "best": weights.best,
            "final": weights.last,
            "selected": weights.selected(),
        },
    });
    Ok(record.to_string())
}
