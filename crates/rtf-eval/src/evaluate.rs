//! Evaluation of any network on any frame source: one confusion matrix for the split and one
//! per daytime, accumulated batch by batch.

use std::sync::Arc;

use rtf_core::Daytime;
use rtf_data::{DataError, FrameSource, Loader, LoaderConfig};
use rtf_models::Network;
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

use crate::metrics::{ConfusionMatrix, Scores};

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Data(#[from] DataError),
    #[error("{0}")]
    Shape(String),
    #[error(transparent)]
    Torch(#[from] tch::TchError),
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalOptions {
    pub batch_size: usize,
    /// Resize frames to (width, height) before the network (labels nearest); None = as stored.
    pub resize: Option<(usize, usize)>,
    pub workers: usize,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            batch_size: 4,
            resize: None,
            workers: 2,
        }
    }
}

/// Scores of a split, its day and night frames separately, and the raw matrices.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalReport {
    pub frames: usize,
    pub all: Scores,
    pub day: Option<Scores>,
    pub night: Option<Scores>,
    pub confusion: ConfusionMatrix,
}

/// Runs `network` (eval mode, no autograd) over every frame of `source`.
pub fn evaluate(
    network: &dyn Network,
    source: Arc<dyn FrameSource>,
    options: &EvalOptions,
    device: Device,
) -> Result<EvalReport, EvalError> {
    let classes = source.class_set().clone();
    let n = classes.len();
    let mut day = ConfusionMatrix::new(n, classes.ignore_id);
    let mut night = ConfusionMatrix::new(n, classes.ignore_id);
    let mut unknown = ConfusionMatrix::new(n, classes.ignore_id);
    let loader = Loader::new(
        source.clone(),
        LoaderConfig {
            batch_size: options.batch_size,
            shuffle: false,
            drop_last: false,
            seed: 0,
            workers: options.workers,
            prefetch: 2,
            augment: Default::default(),
            resize: options.resize,
        },
        network.input_convention(),
    );
    let mut frames = 0;
    let _guard = tch::no_grad_guard();
    for batch in loader.epoch(0) {
        let batch = batch?;
        let prediction = predict_ids(network, &batch.input.to_device(device))?;
        let target = batch.target.to_device(device);
        for (i, daytime) in batch.daytimes.iter().enumerate() {
            let matrix = match daytime {
                Some(Daytime::Day) => &mut day,
                Some(Daytime::Night) => &mut night,
                None => &mut unknown,
            };
            matrix.update(&target.get(i as i64), &prediction.get(i as i64));
        }
        frames += batch.names.len();
    }
    let names = classes.names();
    let mut all = day.clone();
    all.merge(&night);
    all.merge(&unknown);
    let scores_if_any = |m: &ConfusionMatrix| (m.total() > 0).then(|| m.compute(&names));
    Ok(EvalReport {
        frames,
        all: all.compute(&names),
        day: scores_if_any(&day),
        night: scores_if_any(&night),
        confusion: all,
    })
}

/// Class ids [B, H, W] for an input [B, C, H, W]: H and W are padded up to the network's size
/// multiple (replicating the border) and the logits cropped back.
pub fn predict_ids(network: &dyn Network, input: &Tensor) -> Result<Tensor, EvalError> {
    Ok(logits(network, input)?.argmax(1, false))
}

/// Logits [B, classes, H, W] at the input's resolution, in eval mode.
pub fn logits(network: &dyn Network, input: &Tensor) -> Result<Tensor, EvalError> {
    let (h, w) = match input.size().as_slice() {
        [_, _, h, w] => (*h, *w),
        other => {
            return Err(EvalError::Shape(format!(
                "expected input [B, C, H, W], got {other:?}"
            )))
        }
    };
    let m = network.size_multiple().max(1);
    let (ph, pw) = ((m - h % m) % m, (m - w % m) % m);
    let padded = if ph > 0 || pw > 0 {
        input.f_pad([0, pw, 0, ph], "replicate", None)?
    } else {
        input.shallow_clone()
    };
    let out = network.forward_t(&padded.to_kind(Kind::Float), false);
    Ok(out.narrow(2, 0, h).narrow(3, 0, w))
}
