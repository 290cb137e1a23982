//! `rtf.calibrate`: `rtf calibrate`'s calibration of a rig (rtf_calib::run), returned as the
//! calib.yaml the command writes (text, and its values read back by Python), written to `out`
//! if given (atomically, never over the rig or an input it lists).

use std::path::{Path, PathBuf};

use pyo3::prelude::*;
use rtf_calib::optimize::Recipe;
use rtf_calib::rig::{OptimizerOverrides, Rig};
use rtf_calib::run::{refuse_overwriting_inputs, CalibrateOptions, Prepared};

use crate::errors::{input, PyResultExt};

fn recipe(name: &str) -> PyResult<Recipe> {
    match name {
        "default" => Ok(Recipe::Default),
        "paper" => Ok(Recipe::Paper),
        other => Err(input(format!(
            "recipe: expected \"default\" or \"paper\", got {other:?}"
        ))),
    }
}

/// Calibrates the rig `rig` (its rig.yaml) as `rtf calibrate --rig RIG` does with the same
/// options; returns (calib.yaml text, the same as JSON). `threads`: libtorch's CPU threads
/// (the command's default, 1, is its fastest on a busy machine).
#[pyfunction]
#[pyo3(signature = (rig, out=None, recipe_name="default", iterations=None, batch_size=None,
                    learning_rate=None, seed=0, threads=1))]
#[allow(clippy::too_many_arguments)]
pub fn calibrate_yaml(
    py: Python<'_>,
    rig: PathBuf,
    out: Option<PathBuf>,
    recipe_name: &str,
    iterations: Option<usize>,
    batch_size: Option<usize>,
    learning_rate: Option<f64>,
    seed: u64,
    threads: i32,
) -> PyResult<(String, String)> {
    let options = CalibrateOptions {
        recipe: recipe(recipe_name)?,
        overrides: OptimizerOverrides {
            iterations,
            batch_size,
            learning_rate,
        },
        seed,
    };
    if threads < 1 {
        return Err(input(format!(
            "threads: expected at least 1, got {threads}"
        )));
    }
    py.allow_threads(|| {
        // libtorch's thread count is the process's: set for the calibration, then restored.
        let _threads = Threads::set(threads);
        let loaded = Rig::load(&rig)?;
        if let Some(out) = &out {
            refuse_overwriting_inputs(&rig, &loaded, &[("out", out.as_path())])?;
        }
        let prepared = Prepared::new(&rig, loaded, &options, &mut |w| eprintln!("warning: {w}"))?;
        let calibrated = prepared.calibrate(&mut |_| {})?;
        if let Some(out) = &out {
            calibrated.file.save(out)?;
        }
        Ok::<_, rtf_calib::error::CalibError>(calibrated.file)
    })
    .py()
    .and_then(|file| texts(&file, out.as_deref()))
}

/// libtorch's intra-op thread count set for a scope, restored when dropped.
struct Threads(i32);

impl Threads {
    fn set(threads: i32) -> Self {
        let before = tch::get_num_threads();
        tch::set_num_threads(threads);
        Threads(before)
    }
}

impl Drop for Threads {
    fn drop(&mut self) {
        tch::set_num_threads(self.0);
    }
}

fn texts(file: &rtf_calib::calibfile::CalibFile, out: Option<&Path>) -> PyResult<(String, String)> {
    let yaml = file.to_yaml().map_err(|e| input(format!("{out:?}: {e}")))?;
    let json = serde_json::to_string(file).map_err(|e| input(e.to_string()))?;
    Ok((yaml, json))
}
