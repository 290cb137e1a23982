//! Figures: a grid of RGB | thermal | ground truth | prediction rows (like the papers' Fig. 4/5),
//! optionally with column titles, several prediction columns and a class legend
//! ([`annotated_grid`]; text drawn with the public-domain 8×8 bitmap font of `font8x8`).

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

/// A prediction column of [`annotated_grid`]: a title and one id map per grid row.
pub struct PredictionColumn {
    pub title: String,
    pub ids: Vec<Vec<u8>>,
}

/// Pixel scale of the 8×8 font for panels `panel_width` wide.
fn text_scale(panel_width: u32) -> u32 {
    if panel_width >= 240 {
        2
    } else {
        1
    }
}

/// Width in pixels of `text` at `scale`.
pub fn text_width(text: &str, scale: u32) -> u32 {
    text.chars().count() as u32 * 8 * scale
}

/// Draws `text` (8×8 glyphs, `scale`× enlarged) with its top-left corner at (x, y); characters
/// without a glyph are drawn as `?`, pixels outside the image are skipped.
pub fn draw_text(image: &mut RgbImage, x: u32, y: u32, text: &str, scale: u32, color: [u8; 3]) {
    use font8x8::UnicodeFonts;
    for (k, ch) in text.chars().enumerate() {
        let glyph = font8x8::BASIC_FONTS
            .get(ch)
            .or_else(|| font8x8::BASIC_FONTS.get('?'))
            .unwrap_or([0; 8]);
        for (gy, bits) in glyph.iter().enumerate() {
            for gx in 0..8u32 {
                if bits & (1 << gx) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let px = x + (k as u32 * 8 + gx) * scale + dx;
                        let py = y + gy as u32 * scale + dy;
                        if px < image.width() && py < image.height() {
                            image.put_pixel(px, py, Rgb(color));
                        }
                    }
                }
            }
        }
    }
}

/// RGB | thermal | ground truth | one column per prediction, a title above each column and a
/// legend of the classes (colour swatch and name) below the rows.
pub fn annotated_grid(
    rows: &[GridRow],
    predictions: &[PredictionColumn],
    classes: &ClassSet,
) -> RgbImage {
    let w = rows.iter().map(|r| r.width).max().unwrap_or(0) as u32;
    let h = rows.iter().map(|r| r.height).max().unwrap_or(0) as u32;
    let columns = 3 + predictions.len() as u32;
    let width = (columns * w + (columns - 1) * GAP).max(1);
    let scale = text_scale(w);
    let line = 8 * scale + 2 * GAP;
    let (legend, legend_height) = legend_layout(classes, width, scale, line);
    let grid_top = line;
    let grid_height = rows.len() as u32 * (h + GAP);
    let mut out = RgbImage::from_pixel(
        width,
        grid_top + grid_height + legend_height,
        Rgb([255, 255, 255]),
    );
    let mut titles = vec!["RGB".to_string(), "thermal".into(), "ground truth".into()];
    titles.extend(predictions.iter().map(|p| p.title.clone()));
    for (c, title) in titles.iter().enumerate() {
        let max_chars = (w / (8 * scale)).max(1) as usize;
        let text: String = title.chars().take(max_chars).collect();
        let x0 = c as u32 * (w + GAP) + (w.saturating_sub(text_width(&text, scale))) / 2;
        draw_text(&mut out, x0, GAP, &text, scale, [0, 0, 0]);
    }
    for (r, row) in rows.iter().enumerate() {
        let y0 = grid_top + r as u32 * (h + GAP);
        draw_grid_row(&mut out, row, r, predictions, classes, (w, y0));
    }
    let legend_top = grid_top + grid_height;
    let swatch = 8 * scale;
    for (x, y, id, name) in legend {
        let y = legend_top + y + GAP;
        for dy in 0..swatch {
            for dx in 0..swatch {
                if x + dx < out.width() {
                    out.put_pixel(x + dx, y + dy, Rgb(classes.color(id)));
                }
            }
        }
        draw_text(&mut out, x + swatch + GAP, y, name, scale, [0, 0, 0]);
    }
    out
}

/// Legend entries (x, y, class id, name) laid out left to right, wrapping at `width`, and
/// the legend's height.
fn legend_layout(
    classes: &ClassSet,
    width: u32,
    scale: u32,
    line: u32,
) -> (Vec<(u32, u32, u8, &str)>, u32) {
    let swatch = 8 * scale;
    let mut legend = Vec::new();
    let (mut x, mut y) = (GAP, 0);
    for c in &classes.classes {
        let name = c.name.as_str();
        let entry = swatch + GAP + text_width(name, scale) + 3 * GAP;
        if x > GAP && x + entry > width {
            x = GAP;
            y += line;
        }
        legend.push((x, y, c.id, name));
        x += entry;
    }
    let height = if legend.is_empty() { 0 } else { y + line };
    (legend, height)
}

/// Row `r` of the grid at height `y0`: its RGB, thermal, ground truth and each prediction
/// (white where a prediction lacks the row), panels `w` + GAP apart.
fn draw_grid_row(
    out: &mut RgbImage,
    row: &GridRow,
    r: usize,
    predictions: &[PredictionColumn],
    classes: &ClassSet,
    (w, y0): (u32, u32),
) {
    let to_byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    for y in 0..row.height {
        for x in 0..row.width {
            let i = y * row.width + x;
            let t = to_byte(row.thermal[i]);
            let mut panels = vec![
                [
                    to_byte(row.rgb[3 * i]),
                    to_byte(row.rgb[3 * i + 1]),
                    to_byte(row.rgb[3 * i + 2]),
                ],
                [t, t, t],
                classes.color(row.truth[i]),
            ];
            panels.extend(predictions.iter().map(|p| {
                p.ids
                    .get(r)
                    .and_then(|ids| ids.get(i))
                    .map_or([255; 3], |&id| classes.color(id))
            }));
            for (p, color) in panels.into_iter().enumerate() {
                out.put_pixel(p as u32 * (w + GAP) + x as u32, y0 + y as u32, Rgb(color));
            }
        }
    }
}

/// The prediction of `network` for a row already drawn (its RGB and thermal planes).
pub fn predict_row(
    network: &dyn Network,
    row: &GridRow,
    device: Device,
) -> Result<Vec<u8>, EvalError> {
    let convention = network.input_convention();
    let n = row.width * row.height;
    let mut planar = vec![0f32; 4 * n];
    for i in 0..n {
        for c in 0..3 {
            planar[c * n + i] = convention.apply(row.rgb[3 * i + c]);
        }
        planar[3 * n + i] = convention.apply(row.thermal[i]);
    }
    let input = Tensor::from_slice(&planar)
        .view([1, 4, row.height as i64, row.width as i64])
        .to_device(device);
    let _guard = tch::no_grad_guard();
    let ids = predict_ids(network, &input)?
        .get(0)
        .to_kind(Kind::Uint8)
        .to_device(Device::Cpu);
    Ok(Vec::<u8>::try_from(ids.flatten(0, -1))?)
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

/// Writes the grid as PNG, atomically, tagged as rtf's output (a later run replaces it
/// without --overwrite).
pub fn save_png(image: &RgbImage, path: &Path) -> Result<(), rtf_data::DataError> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let bytes =
        rtf_data::pngio::encode_png_u8_tagged(w, h, 3, image.as_raw()).map_err(|message| {
            rtf_data::DataError::Write {
                path: path.to_path_buf(),
                message,
            }
        })?;
    rtf_core::write_bytes_atomic(path, &bytes)?;
    Ok(())
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

    #[test]
    fn annotated_grid_has_titles_columns_and_legend() {
        let (w, h) = (40usize, 8usize);
        let row = GridRow {
            width: w,
            height: h,
            rgb: vec![0.5; 3 * w * h],
            thermal: vec![0.25; w * h],
            truth: vec![1; w * h],
            prediction: vec![2; w * h],
        };
        let classes = ClassSet::mf();
        let columns = [
            PredictionColumn {
                title: "run a".into(),
                ids: vec![vec![2; w * h]],
            },
            PredictionColumn {
                title: "run b".into(),
                ids: vec![vec![3; w * h]],
            },
        ];
        let img = annotated_grid(&[row], &columns, &classes);
        let width = 5 * w as u32 + 4 * GAP;
        assert_eq!(img.width(), width);
        let title_h = 8 + 2 * GAP;
        // Title strip: dark text pixels above the first column, none in the gaps.
        let dark = |x0: u32, x1: u32, y0: u32, y1: u32| {
            (y0..y1)
                .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                .filter(|&(x, y)| img.get_pixel(x, y).0 == [0, 0, 0])
                .count()
        };
        assert!(dark(0, w as u32, 0, title_h) > 10, "RGB title drawn");
        assert!(
            dark(4 * (w as u32 + GAP), width, 0, title_h) > 10,
            "run b title drawn"
        );
        // Panels: truth, then the two prediction columns.
        let y = title_h + 1;
        assert_eq!(img.get_pixel(2 * (w as u32 + GAP), y).0, classes.color(1));
        assert_eq!(img.get_pixel(3 * (w as u32 + GAP), y).0, classes.color(2));
        assert_eq!(img.get_pixel(4 * (w as u32 + GAP), y).0, classes.color(3));
        // Legend below the rows holds a swatch of every class colour.
        let legend_top = title_h + h as u32 + GAP;
        for c in &classes.classes {
            let found = (legend_top..img.height())
                .any(|y| (0..img.width()).any(|x| img.get_pixel(x, y).0 == c.color));
            assert!(found, "legend swatch of {}", c.name);
        }
    }
}
