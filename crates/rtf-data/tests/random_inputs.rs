//! Stable-Rust randomised run of rtf-data's readers (the cargo-fuzz targets in `fuzz/` need
//! nightly): seeded mutations of a valid file and random bytes
//! ([`rtf_data::fuzzing::mutations`]) must give a value or an error naming the file, never a
//! panic. A fixed number of cases each, so `cargo xtask test` runs them every time.

use rtf_data::fuzzing::{check_reader, ReaderOutcome};
use rtf_data::pngio::{decode_png, encode_png_u16, encode_png_u8};
use std::path::Path;

const CASES: usize = 600;

/// Most mutations must be refused (the reader checks), and some accepted or refused for
/// another reason than the first byte (the mutations reach past the signature).
fn exercised(what: &str, outcome: ReaderOutcome) {
    assert!(
        outcome.refused > CASES / 4,
        "{what}: mutations mostly accepted: {outcome:?}"
    );
}

fn pattern(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i * 7 % 251) as u8).collect()
}

#[test]
fn png_8_bit_rgba_grey_and_16_bit_never_panic() {
    let (w, h) = (24, 16);
    let rgba = encode_png_u8(w, h, 4, &pattern(4 * w * h)).unwrap();
    let outcome = check_reader("MF RGBA PNG", &rgba, 1, CASES, "x.png", |b| {
        rtf_data::mf::decode_mf_image(b, Path::new("x.png"))
    });
    exercised("MF RGBA PNG", outcome);
    let grey = encode_png_u8(w, h, 1, &pattern(w * h)).unwrap();
    let outcome = check_reader("8-bit grey PNG", &grey, 2, CASES, "x.png", |b| {
        decode_png(b, Path::new("x.png"))
    });
    exercised("8-bit grey PNG", outcome);
    let deep: Vec<u16> = (0..w * h).map(|i| 21800 + 13 * i as u16).collect();
    let thermal = encode_png_u16(w, h, 1, &deep).unwrap();
    let outcome = check_reader("16-bit PNG", &thermal, 3, CASES, "x.png", |b| {
        decode_png(b, Path::new("x.png"))
    });
    exercised("16-bit PNG", outcome);
}

#[test]
fn jpeg_rgb_and_thermal_tiff_and_npy_never_panic() {
    use rtf_data::images::{decode_rgb, decode_thermal};
    use rtf_data::tiffio::{encode_grey, GreyPlane, TiffCompression};
    let (w, h) = (24u32, 16u32);
    let mut jpeg = Vec::new();
    let encoder = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90);
    let rgb = pattern(3 * (w * h) as usize);
    image::ImageEncoder::write_image(encoder, &rgb, w, h, image::ExtendedColorType::Rgb8).unwrap();
    let outcome = check_reader("JPEG RGB", &jpeg, 6, CASES, "x.jpg", |b| {
        decode_rgb(b, Path::new("x.jpg"))
    });
    exercised("JPEG RGB", outcome);
    let counts: Vec<u16> = (0..w * h).map(|i| 21800 + 13 * i as u16).collect();
    for (seed, compression) in [
        (7, TiffCompression::None),
        (8, TiffCompression::Lzw),
        (9, TiffCompression::Deflate),
        (10, TiffCompression::PackBits),
    ] {
        let tiff = encode_grey(w, h, GreyPlane::U16(&counts), compression).unwrap();
        let what = format!("16-bit TIFF {compression:?}");
        let outcome = check_reader(&what, &tiff, seed, CASES, "x.tiff", |b| {
            decode_thermal(b, Path::new("x.tiff"))
        });
        assert!(
            outcome.refused > 0,
            "{what}: no mutation refused: {outcome:?}"
        );
    }
    let temps: Vec<f32> = (0..w * h).map(|i| 20.0 + i as f32 * 0.01).collect();
    let tiff = encode_grey(w, h, GreyPlane::F32(&temps), TiffCompression::None).unwrap();
    let outcome = check_reader("float TIFF", &tiff, 11, CASES, "x.tif", |b| {
        decode_thermal(b, Path::new("x.tif"))
    });
    assert!(outcome.refused > 0, "float TIFF: {outcome:?}");
}

#[test]
fn npy_labels_and_float_arrays_never_panic() {
    let labels = rtf_data::npy::encode_u8(20, 10, &pattern(200));
    let outcome = check_reader("label .npy", &labels, 4, CASES, "x.npy", |b| {
        rtf_data::npy::decode_label_npy(b, Path::new("x.npy"))
    });
    exercised("label .npy", outcome);
    let values: Vec<f32> = (0..9 * 6 * 5).map(|i| i as f32 * 0.25 - 3.0).collect();
    let logits = rtf_core::npy::encode_f32(&[9, 6, 5], &values);
    // rtf_core's decoder returns the fault only; its callers add the path.
    let outcome = check_reader("float32 .npy", &logits, 5, CASES, "", |b| {
        rtf_core::npy::decode_f32(b)
    });
    exercised("float32 .npy", outcome);
}

const DATASET_YAML: &str = "classes:
  - {id: 0, name: background, color: [0, 0, 0]}
  - {id: 1, name: pedestrian, color: [220, 20, 60]}
  - {id: 2, name: car, color: [0, 0, 142]}
ignore_id: 255
label_encoding: ids
thermal:
  range: [21800, 25000]
splits:
  train: {rgb: train/rgb, thermal: \"train/ir/{name}_ir.png\", labels: train/labels}
  val: {rgb: val/rgb, thermal: val/ir, labels: val/labels}
night: {suffix: N}
";

#[test]
fn dataset_yaml_and_split_files_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    for split in ["train", "val"] {
        for folder in ["rgb", "ir", "labels"] {
            std::fs::create_dir_all(dir.path().join(split).join(folder)).unwrap();
        }
    }
    let file = dir.path().join("dataset.yaml");
    let outcome = check_reader(
        "dataset.yaml",
        DATASET_YAML.as_bytes(),
        6,
        CASES,
        "dataset.yaml",
        |b| {
            std::fs::write(&file, b).unwrap();
            rtf_data::description::read_description(&file)
        },
    );
    exercised("dataset.yaml", outcome);
    let split = b"00001D\n00002N\n00003D\n# a comment\n00004N\n";
    let split_file = dir.path().join("val.txt");
    check_reader("split file", split, 7, CASES, "val.txt", |b| {
        std::fs::write(&split_file, b).unwrap();
        rtf_data::mf::read_split_file(&split_file)
    });
}
