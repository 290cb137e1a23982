//! Figures: a grid of RGB | thermal | ground truth | prediction rows (like the papers' Fig. 4/5).

use std::path::Path;

use image::{Rgb, RgbImage};
use rtf_core::{ClassSet, Daytime, InputConvention};
use rtf_data::{Frame, FrameSource};
use rtf_models::Network;
use tch::{Device, Kind, Tensor};

use crate::evaluate::{predict_ids, EvalError};

/// One frame of the grid; images are row-major, `rgb` packed R,G,B in [0, 1].
pub struct GridRow {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<f32>,
    pub thermal: Vec<f32>,
    pub truth: Vec<u8>,
    pub prediction: Vec<u8>,
}

const GAP: u32 = 4;

/// Draws the rows one under the other, four panels each, white gaps between panels.
pub fn prediction_grid(rows: &[GridRow], classes: &ClassSet) -> RgbImage {
    let w = rows.iter().map(|r| r.width).max().unwrap_or(0) as u32;
    let h = rows.iter().map(|r| r.height).max().unwrap_or(0) as u32;
    let mut out = RgbImage::from_pixel(
        4 * w + 3 * GAP,
        rows.len() as u32 * (h + GAP),
        Rgb([255, 255, 255]),
    );
    let to_byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    for (r, row) in rows.iter().enumerate() {
        let y0 = r as u32 * (h + GAP);
        for y in 0..row.height {
            for x in 0..row.width {
                let i = y * row.width + x;
                let rgb = [
                    to_byte(row.rgb[3 * i]),
                    to_byte(row.rgb[3 * i + 1]),
                    to_byte(row.rgb[3 * i + 2]),
                ];
                let t = to_byte(row.thermal[i]);
                let panels = [
                    rgb,
                    [t, t, t],
                    classes.color(row.truth[i]),
                    classes.color(row.prediction[i]),
                ];
                for (p, color) in panels.into_iter().enumerate() {
                    out.put_pixel(p as u32 * (w + GAP) + x as u32, y0 + y as u32, Rgb(color));
                }
            }
        }
    }
    out
}

/// One frame as network input [1, 4, H, W] (R, G, B, T scaled by `convention`).
pub fn frame_input(frame: &Frame, convention: InputConvention) -> Tensor {
    let n = frame.width * frame.height;
    let mut planar = vec![0f32; 4 * n];
    for i in 0..n {
        for c in 0..3 {
            planar[c * n + i] = convention.apply(frame.rgb[3 * i + c] as f32 / 255.0);
        }
        planar[3 * n + i] = convention.apply(frame.thermal[i]);
    }
    Tensor::from_slice(&planar).view([1, 4, frame.height as i64, frame.width as i64])
}

/// Grid rows for up to `count` frames of `source`: half from the day frames, half from the
/// night frames where both exist, each predicted by `network`.
pub fn rows_for(
    network: &dyn Network,
    source: &dyn FrameSource,
    count: usize,
    resize: Option<(usize, usize)>,
    device: Device,
) -> Result<Vec<GridRow>, EvalError> {
    let by_time = |t: Option<Daytime>| (0..source.len()).filter(move |&i| source.daytime(i) == t);
    let mut picked: Vec<usize> = by_time(Some(Daytime::Day))
        .take(count.div_ceil(2))
        .collect();
    picked.extend(by_time(Some(Daytime::Night)).take(count - picked.len()));
    let rest: Vec<usize> = (0..source.len())
        .filter(|i| !picked.contains(i))
        .take(count - picked.len())
        .collect();
    picked.extend(rest);
    let _guard = tch::no_grad_guard();
    picked
        .into_iter()
        .map(|i| {
            let mut frame = source.load(i)?;
            if let Some((w, h)) = resize {
                frame = rtf_data::resize_frame(&frame, w, h);
            }
            let input = frame_input(&frame, network.input_convention()).to_device(device);
            let ids = predict_ids(network, &input)?
                .get(0)
                .to_kind(Kind::Uint8)
                .to_device(Device::Cpu);
            Ok(GridRow {
                width: frame.width,
                height: frame.height,
                rgb: frame.rgb.iter().map(|&v| v as f32 / 255.0).collect(),
                thermal: frame.thermal.clone(),
                truth: frame
                    .label
                    .clone()
                    .unwrap_or_else(|| vec![0; frame.width * frame.height]),
                prediction: Vec::<u8>::try_from(ids.flatten(0, -1))?,
            })
        })
        .collect()
}

/// Writes the grid as PNG, atomically.
pub fn save_png(
    image: &RgbImage,
    path: &Path,
) -> Result<(), rtf_core::AtomicWriteError<image::ImageError>> {
    rtf_core::write_atomic(path, |tmp| {
        image.save_with_format(tmp, image::ImageFormat::Png)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_places_panels() {
        let row = GridRow {
            width: 2,
            height: 1,
            rgb: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            thermal: vec![0.0, 1.0],
            truth: vec![1, 2],
            prediction: vec![2, 1],
        };
        let classes = ClassSet::mf();
        let img = prediction_grid(&[row], &classes);
        assert_eq!(img.dimensions(), (4 * 2 + 3 * GAP, 1 + GAP));
        assert_eq!(img.get_pixel(0, 0).0, [255, 0, 0]);
        assert_eq!(img.get_pixel(2 + GAP + 1, 0).0, [255, 255, 255]);
        assert_eq!(img.get_pixel(2 * (2 + GAP), 0).0, classes.color(1));
        assert_eq!(img.get_pixel(3 * (2 + GAP), 0).0, classes.color(2));
    }
}
