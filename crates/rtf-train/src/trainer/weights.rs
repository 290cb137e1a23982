//! What the run keeps of its weights: checkpoints (refused for non-finite weights) and the
//! prediction grid of validation frames drawn for TensorBoard.
use std::path::Path;

use rtf_data::FrameSource;

use crate::checkpoint::{self, Part, TrainState};
use crate::config::NetworkConfig;
use crate::error::TrainError;
use crate::procedure::{self, Procedure};

/// A titled grid (RGB | thermal | truth | prediction) of four validation frames, as PNG.
pub(super) fn prediction_grid_png(
    student: &procedure::Student,
    val: &dyn FrameSource,
    network: &NetworkConfig,
    resize: Option<(usize, usize)>,
    device: tch::Device,
) -> Result<Vec<u8>, TrainError> {
    let rows = rtf_eval::figure::rows_for(&student.net, val, 4, resize, device)?;
    let column = rtf_eval::figure::PredictionColumn {
        title: network.model.name(),
        ids: rows.iter().map(|r| r.prediction.clone()).collect(),
    };
    let grid = rtf_eval::figure::annotated_grid(&rows, &[column], val.class_set());
    let mut png = Vec::new();
    image::DynamicImage::ImageRgb8(grid)
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| TrainError::Config(format!("encoding the prediction grid: {e}")))?;
    Ok(png)
}

/// Refuses to keep weights with a non-finite value (a diverged run would otherwise leave Inf
/// BatchNorm statistics in its checkpoint and best weights).
pub(super) fn check_finite(
    procedure: &dyn Procedure,
    epoch: usize,
    step: u64,
) -> Result<(), TrainError> {
    for trained in procedure.trained() {
        for (name, t) in trained.vs.variables() {
            let finite = tch::no_grad(|| t.isfinite().all().int64_value(&[]) != 0);
            if !finite {
                return Err(TrainError::Diverged {
                    epoch,
                    step,
                    what: format!(
                        "`{}` `{name}` holds a non-finite value; the last checkpoint (before this) is kept",
                        trained.role
                    ),
                });
            }
        }
    }
    Ok(())
}

pub(super) fn save_checkpoint(
    path: &Path,
    procedure: &dyn Procedure,
    state: &TrainState,
    epoch: usize,
) -> Result<(), TrainError> {
    check_finite(procedure, epoch, state.steps_done)?;
    let trained = procedure.trained();
    let parts: Vec<Part> = trained
        .iter()
        .map(|t| Part {
            role: t.role,
            vs: &t.vs,
            optimizer: t.optimizer.state(),
        })
        .collect();
    checkpoint::save(path, &parts, state)?;
    Ok(())
}
