//! Evaluation of any network on any frame source: one confusion matrix for the split and one
//! per daytime, accumulated batch by batch.
//!
//! Missing-modality robustness ([`evaluate_with_drop`]): the RGB or the thermal channels of
//! every input are replaced before the network, by zero (a black / coldest image) or by the
//! split's mean of that modality, as in the modality-dropout protocols of the RGB-T literature
//! (e.g. HeatNet's single-modality ablations, spec §3); the labels are unchanged.

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

/// A modality of the 4-channel input (R, G, B, T).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Modality {
    Rgb,
    Thermal,
}

impl Modality {
    /// (first channel, channel count) in the network input.
    pub fn channels(self) -> (usize, usize) {
        match self {
            Self::Rgb => (0, 3),
            Self::Thermal => (3, 1),
        }
    }
}

/// What replaces a dropped modality.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DropFill {
    /// Pixel value 0 in every channel of the modality (then the network's input convention).
    Zero,
    /// The split's per-channel mean of the modality (then the input convention).
    Mean,
}

/// A modality replaced in every input of an evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ModalityDrop {
    pub modality: Modality,
    pub fill: DropFill,
}

/// Per-channel mean (R, G, B, T, in [0, 1]) over every frame of `source`.
pub fn channel_means(source: &dyn FrameSource) -> Result<[f64; 4], EvalError> {
    let mut sums = [0f64; 4];
    let mut pixels = 0u64;
    for i in 0..source.len() {
        let frame = source.load(i)?;
        for px in frame.rgb.chunks_exact(3) {
            for c in 0..3 {
                sums[c] += px[c] as f64 / 255.0;
            }
        }
        sums[3] += frame.thermal.iter().map(|&t| t as f64).sum::<f64>();
        pixels += (frame.width * frame.height) as u64;
    }
    if pixels == 0 {
        return Err(EvalError::Shape("no pixels to average".into()));
    }
    Ok(sums.map(|s| s / pixels as f64))
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
    evaluate_with_drop(network, source, options, None, device)
}

/// [`evaluate`] with one modality replaced in every input (see the module docs).
pub fn evaluate_with_drop(
    network: &dyn Network,
    source: Arc<dyn FrameSource>,
    options: &EvalOptions,
    drop: Option<ModalityDrop>,
    device: Device,
) -> Result<EvalReport, EvalError> {
    let convention = network.input_convention();
    // Values (already in the network's input scale) of the dropped channels.
    let fill: Option<(usize, Vec<f64>)> = match drop {
        None => None,
        Some(d) => {
            let (first, count) = d.modality.channels();
            let unit = match d.fill {
                DropFill::Zero => vec![0.0; count],
                DropFill::Mean => channel_means(source.as_ref())?[first..first + count].to_vec(),
            };
            let values = unit
                .iter()
                .map(|&u| convention.apply(u as f32) as f64)
                .collect();
            Some((first, values))
        }
    };
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
        let input = batch.input.to_device(device);
        if let Some((first, values)) = &fill {
            for (c, &v) in values.iter().enumerate() {
                let _ = input.narrow(1, (first + c) as i64, 1).fill_(v);
            }
        }
        let prediction = predict_ids(network, &input)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use rtf_core::ClassSet;
    use tch::nn::ModuleT;

    /// Predicts class 1 where the thermal channel is above 0.5, else class 0 (RGB ignored).
    #[derive(Debug)]
    struct ThermalThreshold;

    impl ModuleT for ThermalThreshold {
        fn forward_t(&self, xs: &Tensor, _train: bool) -> Tensor {
            let t = xs.narrow(1, 3, 1);
            let one = t.gt(0.5).to_kind(Kind::Float);
            Tensor::cat(&[one.ones_like() - &one, one], 1)
        }
    }

    impl Network for ThermalThreshold {
        fn input_convention(&self) -> rtf_core::InputConvention {
            rtf_core::InputConvention::UnitRange
        }
        fn num_classes(&self) -> i64 {
            2
        }
        fn size_multiple(&self) -> i64 {
            1
        }
        fn name(&self) -> String {
            "thermal-threshold".into()
        }
    }

    /// Two 2x2 frames whose label is "thermal > 0.5" (class 1), one day, one night.
    fn frames() -> rtf_data::MemorySource {
        let frame = |index: usize| {
            let thermal: Vec<f32> = if index == 0 {
                vec![0.9, 0.1, 0.9, 0.1]
            } else {
                vec![0.1, 0.1, 0.9, 0.9]
            };
            rtf_data::Frame {
                name: format!("f{index}"),
                daytime: Some(if index == 0 {
                    Daytime::Day
                } else {
                    Daytime::Night
                }),
                width: 2,
                height: 2,
                rgb: vec![200; 12],
                label: Some(thermal.iter().map(|&t| (t > 0.5) as u8).collect()),
                thermal,
            }
        };
        rtf_data::MemorySource {
            frames: vec![frame(0), frame(1)],
            class_set: ClassSet::mf(),
        }
    }

    #[test]
    fn dropping_a_modality_changes_only_what_uses_it() {
        let net = ThermalThreshold;
        let source: Arc<dyn FrameSource> = Arc::new(frames());
        let options = EvalOptions {
            batch_size: 2,
            resize: None,
            workers: 1,
        };
        let run =
            |drop| evaluate_with_drop(&net, source.clone(), &options, drop, Device::Cpu).unwrap();
        let full = run(None);
        assert_eq!(full.all.pixel_acc, 1.0);
        let no_rgb = run(Some(ModalityDrop {
            modality: Modality::Rgb,
            fill: DropFill::Zero,
        }));
        assert_eq!(no_rgb.all.pixel_acc, 1.0);
        assert_eq!(no_rgb.day.unwrap().pixel_acc, 1.0);
        for fill in [DropFill::Zero, DropFill::Mean] {
            let no_t = run(Some(ModalityDrop {
                modality: Modality::Thermal,
                fill,
            }));
            // Every pixel predicted cold: half the pixels right.
            assert_eq!(no_t.all.pixel_acc, 0.5, "{fill:?}");
            assert_eq!(no_t.confusion.get(1, 0), 4, "{fill:?}");
        }
        let means = channel_means(source.as_ref()).unwrap();
        assert!((means[0] - 200.0 / 255.0).abs() < 1e-9);
        assert!((means[3] - 0.5).abs() < 1e-6);
    }
}
