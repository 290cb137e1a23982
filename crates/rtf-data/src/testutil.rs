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
