//! The readers of a dataset's image files, as public RGB-T sets ship them: RGB as PNG or JPEG;
//! thermal as PNG (8/16-bit), JPEG (8-bit grey, [`grey_of_jpeg`]), TIFF (8/16-bit integer, uncompressed, LZW, deflate or PackBits;
//! 32-bit float) or `.npy` (integer counts, or float temperatures); labels as PNG. Every
//! command that reads a frame — training, evaluation, prediction, the data check — reads it
//! through these functions, so a file one of them accepts, all accept.
//!
//! The format is taken from the file's extension and checked against its content (a PNG named
//! `.jpg` is refused naming both). Grey stored as RGB or RGBA is read as grey where one
//! channel is expected, after checking that the channels are equal.

use std::io::Cursor;
use std::path::Path;

use crate::planes::colour_thermal;
pub use crate::planes::{grey_plane, ThermalImage, ThermalSamples};
use crate::pngio::{decode_png, PngImage, Samples, MAX_DECODED_BYTES};
use crate::DataError;

/// The file formats rtf reads frames from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Png,
    Jpeg,
    Tiff,
    Npy,
}

impl Format {
    /// Extensions of RGB images, in the order a folder pattern tries them.
    pub const RGB: &'static [Format] = &[Format::Png, Format::Jpeg];
    /// Formats of thermal images.
    pub const THERMAL: &'static [Format] = &[Format::Png, Format::Jpeg, Format::Tiff, Format::Npy];
    /// Formats of label images (lossless, one id or colour per pixel).
    pub const LABEL: &'static [Format] = &[Format::Png];

    /// The format a file's extension names (case-insensitive), if any.
    pub fn of_extension(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        Some(match ext.as_str() {
            "png" => Format::Png,
            "jpg" | "jpeg" => Format::Jpeg,
            "tif" | "tiff" => Format::Tiff,
            "npy" => Format::Npy,
            _ => return None,
        })
    }

    /// The format a file's first bytes say it is, if any.
    pub fn of_content(bytes: &[u8]) -> Option<Format> {
        match bytes {
            [0x89, b'P', b'N', b'G', ..] => Some(Format::Png),
            [0xFF, 0xD8, 0xFF, ..] => Some(Format::Jpeg),
            [b'I', b'I', 42 | 43, 0, ..] | [b'M', b'M', 0, 42 | 43, ..] => Some(Format::Tiff),
            [0x93, b'N', b'U', b'M', b'P', b'Y', ..] => Some(Format::Npy),
            _ => None,
        }
    }

    /// The extensions written for this format (for messages).
    pub fn extensions(self) -> &'static [&'static str] {
        match self {
            Format::Png => &["png"],
            Format::Jpeg => &["jpg", "jpeg"],
            Format::Tiff => &["tif", "tiff"],
            Format::Npy => &["npy"],
        }
    }

    /// Every extension of `formats` (a folder pattern's candidates).
    pub fn all_extensions(formats: &[Format]) -> Vec<&'static str> {
        formats
            .iter()
            .flat_map(|f| f.extensions())
            .copied()
            .collect()
    }
}

/// The format of `path` among `allowed` for `what`: named by the extension and confirmed by
/// the content; an extension outside `allowed` or content of another format is an error.
pub fn checked_format(
    path: &Path,
    bytes: &[u8],
    allowed: &[Format],
    what: &str,
) -> Result<Format, DataError> {
    let bad = |message: String| DataError::Format {
        path: path.to_path_buf(),
        message,
    };
    let named = Format::of_extension(path).filter(|f| allowed.contains(f));
    let Some(named) = named else {
        let exts = Format::all_extensions(allowed).join(", .");
        return Err(bad(format!("{what} must be .{exts} (by its extension)")));
    };
    match Format::of_content(bytes) {
        Some(found) if found == named => Ok(named),
        Some(found) => Err(bad(format!(
            "named .{} but its content is a {found:?} file",
            named.extensions()[0]
        ))),
        None if bytes.is_empty() => Err(bad("the file is empty".into())),
        None => Err(bad(format!("not a {named:?} file (unrecognised content)"))),
    }
}

fn read(path: &Path) -> Result<Vec<u8>, DataError> {
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

/// An 8-bit RGB image, interleaved.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
}

/// Reads an RGB image: PNG (8-bit RGB, or RGBA whose alpha is dropped) or JPEG.
pub fn read_rgb(path: &Path) -> Result<RgbImage, DataError> {
    decode_rgb(&read(path)?, path)
}

/// [`read_rgb`] of bytes in memory (`path` names the file in errors).
pub fn decode_rgb(bytes: &[u8], path: &Path) -> Result<RgbImage, DataError> {
    match checked_format(path, bytes, Format::RGB, "an RGB image")? {
        Format::Jpeg => decode_jpeg(bytes, path),
        _ => rgb_of_png(&decode_png(bytes, path)?, path),
    }
}

fn rgb_of_png(png: &PngImage, path: &Path) -> Result<RgbImage, DataError> {
    let Samples::U8(samples) = &png.samples else {
        return Err(DataError::BitDepth {
            path: path.to_path_buf(),
            expected: "8".into(),
            found: png.bit_depth(),
        });
    };
    let rgb = match png.channels {
        3 if !png.indexed => samples.clone(),
        4 => samples
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect(),
        found => {
            return Err(DataError::Channels {
                path: path.to_path_buf(),
                what: "RGB image",
                expected: "3 or 4".into(),
                found,
            })
        }
    };
    Ok(RgbImage {
        width: png.width,
        height: png.height,
        rgb,
    })
}

/// A JPEG decoded as stored (grey or colour), within the decoder's memory limit.
fn jpeg_image(bytes: &[u8], path: &Path) -> Result<image::DynamicImage, DataError> {
    let bad = |message: String| DataError::Format {
        path: path.to_path_buf(),
        message: format!("not a readable JPEG: {message}"),
    };
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), image::ImageFormat::Jpeg);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_DECODED_BYTES as u64);
    reader.limits(limits);
    reader.decode().map_err(|e| bad(e.to_string()))
}

fn decode_jpeg(bytes: &[u8], path: &Path) -> Result<RgbImage, DataError> {
    let decoded = jpeg_image(bytes, path)?;
    let found = decoded.color().channel_count() as usize;
    if found != 3 {
        return Err(DataError::Channels {
            path: path.to_path_buf(),
            what: "RGB image",
            expected: "3".into(),
            found,
        });
    }
    let rgb = decoded.into_rgb8();
    Ok(RgbImage {
        width: rgb.width() as usize,
        height: rgb.height() as usize,
        rgb: rgb.into_raw(),
    })
}

/// Reads a thermal image: PNG, TIFF or `.npy` (module docs).
pub fn read_thermal(path: &Path) -> Result<ThermalImage, DataError> {
    decode_thermal(&read(path)?, path)
}

/// [`read_thermal`] of bytes in memory (`path` names the file in errors).
pub fn decode_thermal(bytes: &[u8], path: &Path) -> Result<ThermalImage, DataError> {
    match checked_format(path, bytes, Format::THERMAL, "a thermal image")? {
        Format::Tiff => crate::tiffio::decode_thermal_tiff(bytes, path),
        Format::Npy => thermal_of_npy(bytes, path),
        Format::Jpeg => thermal_of_jpeg(bytes, path),
        Format::Png => thermal_of_png(&decode_png(bytes, path)?, path),
    }
}

/// The most two channels of one pixel of a grey JPEG stored in three channels may differ:
/// JPEG codes colour as luma and chroma, and the chroma planes' quantisation and subsampling
/// leave grey pixels a few levels off grey after decoding. A colour-mapped rendering differs
/// by far more.
pub const JPEG_GREY_SPREAD: u8 = 8;

/// An 8-bit thermal JPEG: grey as stored, or grey stored in three channels, read as the
/// channels' mean (rounded), as the reference loaders' `mean(axis=2)` does, after checking
/// that no pixel's channels differ by more than [`JPEG_GREY_SPREAD`].
fn thermal_of_jpeg(bytes: &[u8], path: &Path) -> Result<ThermalImage, DataError> {
    let decoded = jpeg_image(bytes, path)?;
    let (width, height) = (decoded.width() as usize, decoded.height() as usize);
    let values = match decoded.color().channel_count() {
        1 => decoded.into_luma8().into_raw(),
        _ => grey_of_jpeg(&decoded.into_rgb8().into_raw(), width, path)?,
    };
    Ok(ThermalImage {
        width,
        height,
        samples: ThermalSamples::Counts {
            bits: 8,
            values: values.into_iter().map(u16::from).collect(),
        },
    })
}

/// The grey of interleaved RGB samples of a JPEG ([`thermal_of_jpeg`]); a pixel whose
/// channels differ by more than [`JPEG_GREY_SPREAD`] is an error naming it.
pub fn grey_of_jpeg(rgb: &[u8], width: usize, path: &Path) -> Result<Vec<u8>, DataError> {
    rgb.chunks_exact(3)
        .enumerate()
        .map(|(i, p)| {
            let spread = p.iter().max().unwrap() - p.iter().min().unwrap();
            if spread > JPEG_GREY_SPREAD {
                return Err(colour_thermal(
                    path,
                    3,
                    &format!(
                        " by {spread} levels at (x {}, y {}): RGB {p:?}; a grey JPEG's channels differ by at most {JPEG_GREY_SPREAD}",
                        i % width.max(1),
                        i / width.max(1)
                    ),
                ));
            }
            let sum: u16 = p.iter().map(|&v| u16::from(v)).sum();
            Ok(((sum + 1) / 3) as u8)
        })
        .collect()
}

fn thermal_of_png(png: &PngImage, path: &Path) -> Result<ThermalImage, DataError> {
    let c = png.channels;
    let values = match &png.samples {
        Samples::U8(v) => grey_plane(v, c).map(|g| g.into_iter().map(u16::from).collect()),
        Samples::U16(v) => grey_plane(v, c),
    };
    let values = values.filter(|_| !png.indexed).ok_or_else(|| {
        colour_thermal(path, c, if png.indexed { " (palette image)" } else { "" })
    })?;
    Ok(ThermalImage {
        width: png.width,
        height: png.height,
        samples: ThermalSamples::Counts {
            bits: png.bit_depth(),
            values,
        },
    })
}

fn thermal_of_npy(bytes: &[u8], path: &Path) -> Result<ThermalImage, DataError> {
    let array = crate::npy::decode_2d(bytes, path, "thermal")?;
    let samples = match (array.kind, array.size) {
        (b'f', _) => ThermalSamples::Degrees(array.values.iter().map(|&v| v as f32).collect()),
        (b'u', 1 | 2) => ThermalSamples::Counts {
            bits: 8 * array.size as u8,
            values: array.values.iter().map(|&v| v as u16).collect(),
        },
        (kind, size) => {
            return Err(DataError::Format {
                path: path.to_path_buf(),
                message: format!(
                "thermal .npy of dtype {}{}: rtf reads uint8/uint16 counts or float temperatures",
                kind as char, size
            ),
            })
        }
    };
    Ok(ThermalImage {
        width: array.width,
        height: array.height,
        samples,
    })
}

/// Reads a label image (PNG only: labels must be lossless).
pub fn read_label(path: &Path) -> Result<PngImage, DataError> {
    let bytes = read(path)?;
    checked_format(path, &bytes, Format::LABEL, "a label image")?;
    decode_png(&bytes, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png_bytes(
        w: u32,
        h: u32,
        color: png::ColorType,
        depth: png::BitDepth,
        data: &[u8],
    ) -> Vec<u8> {
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(color);
        enc.set_depth(depth);
        enc.write_header().unwrap().write_image_data(data).unwrap();
        out
    }

    fn jpeg_bytes(w: u32, h: u32, rgb: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95);
        image::ImageEncoder::write_image(enc, rgb, w, h, image::ExtendedColorType::Rgb8).unwrap();
        out
    }

    #[test]
    fn the_extension_names_the_format_and_the_content_must_agree() {
        let png = png_bytes(2, 1, png::ColorType::Rgb, png::BitDepth::Eight, &[9; 6]);
        let rgb = decode_rgb(&png, Path::new("a.png")).unwrap();
        assert_eq!((rgb.width, rgb.height, rgb.rgb), (2, 1, vec![9; 6]));
        let err = decode_rgb(&png, Path::new("a.JPG"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("a.JPG") && err.contains("Png"), "{err}");
        let err = decode_rgb(&png, Path::new("a.bmp"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("a.bmp") && err.contains(".png, .jpg"), "{err}");
        let err = decode_thermal(b"", Path::new("t.tiff"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("t.tiff") && err.contains("empty"), "{err}");
    }

    #[test]
    fn jpeg_rgb_decodes_close_to_its_source_and_truncated_jpeg_names_the_file() {
        let (w, h) = (16u32, 8u32);
        let rgb: Vec<u8> = (0..w * h).flat_map(|i| [(i * 4) as u8, 128, 200]).collect();
        let bytes = jpeg_bytes(w, h, &rgb);
        let got = decode_rgb(&bytes, Path::new("f.jpeg")).unwrap();
        assert_eq!((got.width, got.height), (16, 8));
        let worst = got
            .rgb
            .iter()
            .zip(&rgb)
            .map(|(&a, &b)| a.abs_diff(b))
            .max()
            .unwrap();
        assert!(
            worst < 24,
            "JPEG q95 of a smooth ramp is within a few levels: {worst}"
        );
        let err = decode_rgb(&bytes[..bytes.len() / 3], Path::new("f.jpeg"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("f.jpeg") && err.contains("JPEG"), "{err}");
    }

    #[test]
    fn grey_stored_as_rgb_is_grey_and_colour_thermal_is_refused() {
        let grey3 = png_bytes(
            2,
            1,
            png::ColorType::Rgb,
            png::BitDepth::Eight,
            &[7, 7, 7, 9, 9, 9],
        );
        let t = decode_thermal(&grey3, Path::new("ir.png")).unwrap();
        assert_eq!(
            t.samples,
            ThermalSamples::Counts {
                bits: 8,
                values: vec![7, 9]
            }
        );
        let colour = png_bytes(
            2,
            1,
            png::ColorType::Rgb,
            png::BitDepth::Eight,
            &[7, 7, 7, 9, 1, 9],
        );
        let err = decode_thermal(&colour, Path::new("ir.png"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("ir.png") && err.contains("differ"), "{err}");
    }

    #[test]
    fn grey_jpeg_thermal_in_one_or_three_channels_is_its_mean_and_colour_is_refused() {
        let (w, h) = (16u32, 8u32);
        let grey: Vec<u8> = (0..w * h).map(|i| (i * 2) as u8).collect();
        let rgb: Vec<u8> = grey.iter().flat_map(|&g| [g, g, g]).collect();
        let three = jpeg_bytes(w, h, &rgb);
        let t = decode_thermal(&three, Path::new("lwir/I1.jpg")).unwrap();
        let ThermalSamples::Counts { bits: 8, values } = &t.samples else {
            panic!("{:?}", t.samples)
        };
        let decoded = decode_rgb(&three, Path::new("x.jpg")).unwrap().rgb;
        let mean: Vec<u16> = decoded
            .chunks_exact(3)
            .map(|p| (p.iter().map(|&v| u16::from(v)).sum::<u16>() + 1) / 3)
            .collect();
        assert_eq!(values, &mean, "the channels' mean, rounded");
        let mut one = Vec::new();
        let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut one, 95);
        image::ImageEncoder::write_image(enc, &grey, w, h, image::ExtendedColorType::L8).unwrap();
        let t1 = decode_thermal(&one, Path::new("t.jpeg")).unwrap();
        assert_eq!((t1.width, t1.height), (16, 8));
        let colour: Vec<u8> = grey.iter().flat_map(|&g| [g, 255 - g, 0]).collect();
        let err = decode_thermal(&jpeg_bytes(w, h, &colour), Path::new("lwir/c.jpg"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("lwir/c.jpg") && err.contains("differ") && err.contains("(x 0, y 0)"),
            "{err}"
        );
    }

    #[test]
    fn npy_thermal_reads_counts_and_temperatures() {
        let counts = crate::npy::encode_u8(2, 1, &[3, 250]);
        let t = decode_thermal(&counts, Path::new("t.npy")).unwrap();
        assert_eq!(
            t.samples,
            ThermalSamples::Counts {
                bits: 8,
                values: vec![3, 250]
            }
        );
        let body: Vec<u8> = [21.5f32, 36.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let floats = rtf_core::npy::encode("<f4", &[1, 2], &body);
        let t = decode_thermal(&floats, Path::new("t.npy")).unwrap();
        assert_eq!(t.samples, ThermalSamples::Degrees(vec![21.5, 36.0]));
    }

    #[test]
    fn labels_must_be_png() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("l.jpg");
        std::fs::write(&path, jpeg_bytes(8, 8, &[0; 192])).unwrap();
        let err = read_label(&path).unwrap_err().to_string();
        assert!(err.contains("l.jpg") && err.contains(".png"), "{err}");
    }
}
