//! Tiny fixtures written by tests (no binary files in git).

use crate::pngio::{encode_png_u16, encode_png_u8};
use std::path::Path;

/// Deterministic RGBA image bytes (thermal in alpha) for a frame of size w×h.
pub fn rgba(w: usize, h: usize, salt: u8) -> Vec<u8> {
    (0..w * h)
        .flat_map(|i| {
            [
                (i % 251) as u8,
                salt,
                (i / w) as u8 * 3,
                255 - (i % 200) as u8,
            ]
        })
        .collect()
}

/// Label ids cycling over 0..classes.
pub fn ids(w: usize, h: usize, classes: u8) -> Vec<u8> {
    (0..w * h)
        .map(|i| ((i / 3) % classes as usize) as u8)
        .collect()
}

pub fn write(path: &Path, bytes: &[u8]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, bytes).unwrap();
}

/// Writes an MF dataset of `names` (w×h) with one split `train.txt` listing all of them.
pub fn mf_dataset(root: &Path, names: &[&str], w: usize, h: usize) {
    for (k, name) in names.iter().enumerate() {
        write(
            &root.join("images").join(format!("{name}.png")),
            &encode_png_u8(w, h, 4, &rgba(w, h, k as u8)).unwrap(),
        );
        write(
            &root.join("labels").join(format!("{name}.png")),
            &encode_png_u8(w, h, 1, &ids(w, h, 9)).unwrap(),
        );
    }
    let list: String = names.iter().map(|n| format!("{n}\n")).collect();
    write(&root.join("train.txt"), list.as_bytes());
}

pub fn png_u8(w: usize, h: usize, channels: usize, data: &[u8]) -> Vec<u8> {
    encode_png_u8(w, h, channels, data).unwrap()
}

pub fn png_u16(w: usize, h: usize, channels: usize, data: &[u16]) -> Vec<u8> {
    encode_png_u16(w, h, channels, data).unwrap()
}

/// Deterministic RGB bytes for a frame of size w×h.
pub fn rgb(w: usize, h: usize, salt: u8) -> Vec<u8> {
    (0..w * h)
        .flat_map(|i| [(i % 251) as u8, salt, (i / w) as u8 * 3])
        .collect()
}

/// The folders of one split of an RGB-T layout (e.g. MSRS: `vi`, `ir`, `Label`).
pub struct RgbtFolders<'a> {
    pub rgb: &'a str,
    pub thermal: &'a str,
    pub labels: &'a str,
}

/// How a fixture stores thermal.
#[derive(Clone, Copy)]
pub enum ThermalFixture {
    /// 8-bit grey, one channel: value `(i % 256)`.
    Grey8,
    /// 8-bit grey stored as RGB (all three channels equal).
    GreyAsRgb8,
    /// 16-bit counts `base + i`.
    Raw16 { base: u16 },
}

/// Writes one frame `name` of size w×h under `dir` in `folders`: RGB, thermal as `thermal`,
/// and (unless `labels` is empty) 8-bit label ids cycling over 0..classes.
pub fn write_rgbt_frame(
    dir: &Path,
    folders: &RgbtFolders,
    name: &str,
    (w, h): (usize, usize),
    thermal: ThermalFixture,
    classes: u8,
) {
    let file = |folder: &str| dir.join(folder).join(format!("{name}.png"));
    write(
        &file(folders.rgb),
        &png_u8(w, h, 3, &rgb(w, h, name.len() as u8)),
    );
    let grey: Vec<u8> = (0..w * h).map(|i| (i % 256) as u8).collect();
    let thermal_png = match thermal {
        ThermalFixture::Grey8 => png_u8(w, h, 1, &grey),
        ThermalFixture::GreyAsRgb8 => {
            let rgb: Vec<u8> = grey.iter().flat_map(|&v| [v, v, v]).collect();
            png_u8(w, h, 3, &rgb)
        }
        ThermalFixture::Raw16 { base } => {
            let counts: Vec<u16> = (0..w * h).map(|i| base + i as u16).collect();
            png_u16(w, h, 1, &counts)
        }
    };
    write(&file(folders.thermal), &thermal_png);
    if !folders.labels.is_empty() {
        write(&file(folders.labels), &png_u8(w, h, 1, &ids(w, h, classes)));
    }
}

/// JPEG bytes (quality 95) of interleaved RGB.
pub fn jpeg_rgb(w: usize, h: usize, rgb: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95);
    image::ImageEncoder::write_image(enc, rgb, w as u32, h as u32, image::ExtendedColorType::Rgb8)
        .unwrap();
    out
}
