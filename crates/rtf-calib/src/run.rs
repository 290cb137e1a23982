//! A rig calibrated as `rtf calibrate` does it, for every caller (the command and the Python
//! package): the rig read, its optimiser settings resolved, its frames loaded ([`Prepared`]),
//! then solved and assessed into the calib.yaml contents ([`Calibrated`]).

use std::path::{Path, PathBuf};

use crate::calibfile::{CalibFile, Quality};
use crate::error::{CalibError, Result};
use crate::frames::{load_frames, Frame};
use crate::optimize::{Progress, Recipe, Settings};
use crate::rig::{OptimizerOverrides, Rig};
use crate::solve::Outcome;

/// What the user chose: the recipe, its overrides (flags over the rig file's over the
/// recipe's defaults) and the seed.
#[derive(Debug, Clone, Copy)]
pub struct CalibrateOptions {
    pub recipe: Recipe,
    pub overrides: OptimizerOverrides,
    pub seed: u64,
}

/// A rig ready to solve.
pub struct Prepared {
    pub rig_path: PathBuf,
    pub rig: Rig,
    pub settings: Settings,
    pub frames: Vec<Frame>,
}

/// A solved rig: the solver's outcome and the calib.yaml it makes.
pub struct Calibrated {
    pub outcome: Outcome,
    pub file: CalibFile,
}

impl Prepared {
    /// Reads `rig_path`, then [`Prepared::new`].
    pub fn load(
        rig_path: &Path,
        options: &CalibrateOptions,
        warn: &mut dyn FnMut(String),
    ) -> Result<Self> {
        Self::new(rig_path, Rig::load(rig_path)?, options, warn)
    }

    /// The rig read from `rig_path`, its settings resolved and its usable frames loaded
    /// (`warn` hears of each skipped one).
    pub fn new(
        rig_path: &Path,
        rig: Rig,
        options: &CalibrateOptions,
        warn: &mut dyn FnMut(String),
    ) -> Result<Self> {
        let settings = Settings::resolve(
            options.recipe,
            options.overrides,
            rig.optimizer,
            options.seed,
        )?;
        let frames = load_frames(&rig, warn)?;
        Ok(Self {
            rig_path: rig_path.to_path_buf(),
            rig,
            settings,
            frames,
        })
    }

    /// Solves and assesses the rig ([`crate::solve::calibrate`]), `progress` told of each step.
    pub fn calibrate(&self, progress: &mut dyn FnMut(&Progress)) -> Result<Calibrated> {
        let outcome = crate::solve::calibrate(&self.rig, &self.frames, &self.settings, progress)?;
        let quality = Quality {
            loss: outcome.loss,
            frames_used: outcome.frames_used,
            iterations: outcome.iterations,
            assessment: outcome.assessment.clone(),
        };
        let file = CalibFile::from_calibration(&outcome.calibration, Some(quality));
        Ok(Calibrated { outcome, file })
    }
}

/// Refuses an output (`what` names it for the message, e.g. a flag) that is the rig
/// description `rig_path` or any input `rig` lists; checked before any work.
pub fn refuse_overwriting_inputs(
    rig_path: &Path,
    rig: &Rig,
    outputs: &[(&str, &Path)],
) -> Result<()> {
    let mut inputs = vec![("the rig description".to_string(), rig_path.to_path_buf())];
    for (i, f) in rig.frames.iter().enumerate() {
        let listed = [
            ("rgb", Some(&f.rgb)),
            ("thermal", Some(&f.thermal)),
            ("depth", f.depth.as_ref()),
            ("rgb_right", f.rgb_right.as_ref()),
        ];
        for (what, path) in listed {
            if let Some(p) = path {
                inputs.push((format!("frames[{i}].{what} of the rig"), p.clone()));
            }
        }
    }
    for (what, out) in outputs {
        let target = rtf_core::resolved(out);
        if let Some((input, _)) = inputs.iter().find(|(_, p)| rtf_core::resolved(p) == target) {
            return Err(CalibError::OverwritesInput(format!(
                "{what} {}: is {input} ({}); refusing to overwrite an input, choose another path",
                out.display(),
                rig_path.display()
            )));
        }
    }
    Ok(())
}
