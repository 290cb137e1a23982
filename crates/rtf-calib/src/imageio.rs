//! Frame readers (RGB → grey, 16-bit depth in mm, 8/16-bit thermal with robust per-frame
//! normalisation) and small PNG writers. All writes are atomic.

use crate::error::{CalibError, Result};
use image::DynamicImage;
use std::path::Path;

/// A single-channel f32 image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Plane {
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), width * height);
        Self {
            width,
            height,
            data,
        }
    }

    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }
}

fn open(path: &Path) -> Result<DynamicImage> {
    let reader = image::ImageReader::open(path).map_err(|e| CalibError::io(path, e))?;
    let reader = reader
        .with_guessed_format()
        .map_err(|e| CalibError::io(path, e))?;
    reader.decode().map_err(|e| CalibError::Image {
        path: path.into(),
        message: e.to_string(),
    })
}

/// RGB (or grey) image as luminance in [0, 1].
pub fn read_gray(path: &Path) -> Result<Plane> {
    let img = open(path)?;
    let rgb = img.to_rgb32f();
    let (w, h) = rgb.dimensions();
    let data = rgb
        .pixels()
        .map(|p| 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2])
        .collect();
    Ok(Plane::new(w as usize, h as usize, data))
}

/// 16-bit PNG z-depth in millimetres → metres, 0 = unknown.
pub fn read_depth(path: &Path) -> Result<Plane> {
    match open(path)? {
        DynamicImage::ImageLuma16(img) => {
            let (w, h) = img.dimensions();
            Ok(Plane::new(
                w as usize,
                h as usize,
                img.into_raw()
                    .into_iter()
                    .map(|mm| mm as f32 / 1000.0)
                    .collect(),
            ))
        }
        other => Err(CalibError::BadFrame {
            path: path.into(),
            message: format!(
                "depth must be a 16-bit grey PNG in millimetres, found {:?}",
                other.color()
            ),
        }),
    }
}

/// Raw thermal counts (8- or 16-bit grey; colour images are converted to grey).
pub fn read_thermal_raw(path: &Path) -> Result<Plane> {
    let img = open(path)?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let data: Vec<f32> = match img {
        DynamicImage::ImageLuma8(i) => i.into_raw().into_iter().map(f32::from).collect(),
        DynamicImage::ImageLuma16(i) => i.into_raw().into_iter().map(f32::from).collect(),
        other => other
            .to_luma16()
            .into_raw()
            .into_iter()
            .map(f32::from)
            .collect(),
    };
    Ok(Plane::new(w, h, data))
}

/// Robust per-frame normalisation: the 1st and 99th percentiles map to 0 and 1 (clamped), so
/// a few hot or dead pixels do not set the contrast. `None` when the frame is (nearly) flat.
pub fn normalise_robust(raw: &Plane) -> Option<Plane> {
    let mut sorted: Vec<f32> = raw.data.iter().copied().filter(|v| v.is_finite()).collect();
    if sorted.len() < 16 {
        return None;
    }
    sorted.sort_by(f32::total_cmp);
    let lo = sorted[sorted.len() / 100];
    let hi = sorted[sorted.len() - 1 - sorted.len() / 100];
    if hi - lo <= 1e-6 * hi.abs().max(1.0) {
        return None;
    }
    let data = raw
        .data
        .iter()
        .map(|v| ((v - lo) / (hi - lo)).clamp(0.0, 1.0))
        .collect();
    Some(Plane::new(raw.width, raw.height, data))
}

fn write_err(path: &Path, e: impl std::fmt::Display) -> CalibError {
    CalibError::Write {
        path: path.into(),
        message: e.to_string(),
    }
}

/// Writes an 8-bit RGB PNG (row-major `[r, g, b]` bytes).
pub fn write_rgb8(path: &Path, width: usize, height: usize, rgb: Vec<u8>) -> Result<()> {
    let img =
        image::RgbImage::from_raw(width as u32, height as u32, rgb).expect("buffer size matches");
    rtf_core::write_atomic(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
    })
    .map_err(|e| write_err(path, e))
}

/// Writes a 16-bit grey PNG.
pub fn write_gray16(path: &Path, width: usize, height: usize, values: Vec<u16>) -> Result<()> {
    let img =
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(width as u32, height as u32, values)
            .expect("buffer size matches");
    rtf_core::write_atomic(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
    })
    .map_err(|e| write_err(path, e))
}

/// Writes an 8-bit grey PNG.
pub fn write_gray8(path: &Path, width: usize, height: usize, values: Vec<u8>) -> Result<()> {
    let img = image::GrayImage::from_raw(width as u32, height as u32, values)
        .expect("buffer size matches");
    rtf_core::write_atomic(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
    })
    .map_err(|e| write_err(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thermal_8_and_16_bit_normalise_alike_and_ignore_hot_pixels() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (20, 10);
        let ramp: Vec<f32> = (0..w * h)
            .map(|i| (i % w) as f32 / (w - 1) as f32)
            .collect();
        let mut v16: Vec<u16> = ramp.iter().map(|r| 20000 + (r * 4000.0) as u16).collect();
        v16[5] = 65535; // a hot pixel must not set the contrast
        let v8: Vec<u8> = ramp.iter().map(|r| 30 + (r * 200.0) as u8).collect();
        write_gray16(&dir.path().join("t16.png"), w, h, v16).unwrap();
        write_gray8(&dir.path().join("t8.png"), w, h, v8).unwrap();
        let a = normalise_robust(&read_thermal_raw(&dir.path().join("t16.png")).unwrap()).unwrap();
        let b = normalise_robust(&read_thermal_raw(&dir.path().join("t8.png")).unwrap()).unwrap();
        for i in [0, 7, 13, 19, 100] {
            assert!(
                (a.data[i] - b.data[i]).abs() < 0.03,
                "pixel {i}: {} vs {}",
                a.data[i],
                b.data[i]
            );
        }
        assert!((a.data[w + 10] - 10.0 / 19.0).abs() < 0.03);
    }

    #[test]
    fn flat_thermal_is_rejected_and_depth_must_be_16_bit() {
        let dir = tempfile::tempdir().unwrap();
        write_gray8(&dir.path().join("flat.png"), 8, 8, vec![77; 64]).unwrap();
        assert!(
            normalise_robust(&read_thermal_raw(&dir.path().join("flat.png")).unwrap()).is_none()
        );
        let err = read_depth(&dir.path().join("flat.png"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("flat.png") && err.contains("16-bit"), "{err}");
        write_gray16(&dir.path().join("d.png"), 2, 1, vec![1500, 0]).unwrap();
        assert_eq!(
            read_depth(&dir.path().join("d.png")).unwrap().data,
            vec![1.5, 0.0]
        );
        std::fs::write(dir.path().join("bad.png"), b"not a png").unwrap();
        let err = read_gray(&dir.path().join("bad.png"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("bad.png"), "{err}");
    }
}
