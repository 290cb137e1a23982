//! PNG reading and writing with explicit channel and bit-depth checks. Decoding works on bytes
//! already in memory so the same code path is fuzzed and used by the datasets.

use crate::DataError;
use std::io::Cursor;
use std::path::Path;

/// Images larger than this (decoded bytes) are refused before anything is allocated, so a
/// corrupt header cannot ask for gigabytes.
pub const MAX_DECODED_BYTES: usize = 1 << 28;

/// A decoded PNG, samples as stored: 8-bit samples one byte each, 16-bit samples as `u16`.
#[derive(Debug, Clone, PartialEq)]
pub struct PngImage {
    pub width: usize,
    pub height: usize,
    /// 1 (grey or palette index), 2 (grey + alpha), 3 (RGB) or 4 (RGBA).
    pub channels: usize,
    /// True when the samples are palette indices (colour type 3).
    pub indexed: bool,
    pub samples: Samples,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Samples {
    U8(Vec<u8>),
    U16(Vec<u16>),
}

impl PngImage {
    pub fn bit_depth(&self) -> u8 {
        match self.samples {
            Samples::U8(_) => 8,
            Samples::U16(_) => 16,
        }
    }
}

/// Decodes PNG bytes; `path` is only used in error messages. Bit depths below 8 are reported
/// as such (callers decide what they accept); never panics on malformed input.
pub fn decode_png(bytes: &[u8], path: &Path) -> Result<PngImage, DataError> {
    let png_err = |e: png::DecodingError| DataError::Png {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let limits = png::Limits {
        bytes: MAX_DECODED_BYTES,
    };
    let decoder = png::Decoder::new_with_limits(Cursor::new(bytes), limits);
    let mut reader = decoder.read_info().map_err(png_err)?;
    let info = reader.info();
    let (width, height) = (info.width as usize, info.height as usize);
    let color = info.color_type;
    let depth = info.bit_depth as u8;
    let (channels, indexed) = match color {
        png::ColorType::Grayscale => (1, false),
        png::ColorType::Indexed => (1, true),
        png::ColorType::GrayscaleAlpha => (2, false),
        png::ColorType::Rgb => (3, false),
        png::ColorType::Rgba => (4, false),
    };
    if depth != 8 && depth != 16 {
        return Err(DataError::BitDepth {
            path: path.to_path_buf(),
            expected: "8 or 16".into(),
            found: depth,
        });
    }
    let size = reader
        .output_buffer_size()
        .filter(|&n| n <= MAX_DECODED_BYTES)
        .ok_or_else(|| DataError::Png {
            path: path.to_path_buf(),
            message: format!("{width}x{height} image is too large"),
        })?;
    let mut buf = vec![0u8; size];
    let out = reader.next_frame(&mut buf).map_err(png_err)?;
    if out.width as usize != width || out.height as usize != height {
        return Err(DataError::Png {
            path: path.to_path_buf(),
            message: "frame size differs from header".into(),
        });
    }
    let n = width * height * channels * (depth as usize / 8);
    if buf.len() < n {
        return Err(DataError::Png {
            path: path.to_path_buf(),
            message: "short image data".into(),
        });
    }
    buf.truncate(n);
    let samples = if depth == 8 {
        Samples::U8(buf)
    } else {
        Samples::U16(
            buf.chunks_exact(2)
                .map(|c| u16::from_be_bytes([c[0], c[1]]))
                .collect(),
        )
    };
    Ok(PngImage {
        width,
        height,
        channels,
        indexed,
        samples,
    })
}

/// Width, height, interleaved RGB bytes and alpha / 255 of [`decode_rgba8_split`].
pub type SplitRgba = (usize, usize, Vec<u8>, Vec<f32>);

/// An 8-bit RGBA image split row by row into interleaved RGB and alpha / 255 (the MF layout),
/// without a full-size intermediate buffer. `None` when the image is not a non-interlaced
/// 8-bit RGBA PNG; the caller then takes the general path, which reports what is wrong.
pub fn decode_rgba8_split(bytes: &[u8], path: &Path) -> Option<Result<SplitRgba, DataError>> {
    let png_err = |e: png::DecodingError| DataError::Png {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let limits = png::Limits {
        bytes: MAX_DECODED_BYTES,
    };
    let mut reader = png::Decoder::new_with_limits(Cursor::new(bytes), limits)
        .read_info()
        .ok()?;
    let info = reader.info();
    if info.color_type != png::ColorType::Rgba
        || info.bit_depth != png::BitDepth::Eight
        || info.interlaced
    {
        return None;
    }
    let (w, h) = (info.width as usize, info.height as usize);
    let n = w
        .checked_mul(h)
        .filter(|&n| n.checked_mul(4).is_some_and(|b| b <= MAX_DECODED_BYTES))?;
    let mut rgb = Vec::with_capacity(3 * n);
    let mut alpha = Vec::with_capacity(n);
    let mut rows = 0;
    loop {
        match reader.next_row() {
            Ok(Some(row)) => {
                let data = row.data();
                if data.len() != 4 * w {
                    return Some(Err(DataError::Png {
                        path: path.to_path_buf(),
                        message: "row length differs from header".into(),
                    }));
                }
                for px in data.chunks_exact(4) {
                    rgb.extend_from_slice(&px[..3]);
                    alpha.push(px[3] as f32 / 255.0);
                }
                rows += 1;
            }
            Ok(None) => break,
            Err(e) => return Some(Err(png_err(e))),
        }
    }
    if rows != h {
        return Some(Err(DataError::Png {
            path: path.to_path_buf(),
            message: format!("{rows} of {h} rows decoded"),
        }));
    }
    Some(Ok((w, h, rgb, alpha)))
}

/// Reads and decodes a PNG file.
pub fn read_png(path: &Path) -> Result<PngImage, DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    decode_png(&bytes, path)
}

/// Decodes an 8-bit image with exactly `channels` channels (what: e.g. "RGBA image").
pub fn decode_u8(
    bytes: &[u8],
    path: &Path,
    channels: usize,
    what: &'static str,
) -> Result<PngImage, DataError> {
    let img = decode_png(bytes, path)?;
    check_channels(&img, path, channels, what)?;
    if img.bit_depth() != 8 {
        return Err(DataError::BitDepth {
            path: path.to_path_buf(),
            expected: "8".into(),
            found: img.bit_depth(),
        });
    }
    Ok(img)
}

pub(crate) fn check_channels(
    img: &PngImage,
    path: &Path,
    channels: usize,
    what: &'static str,
) -> Result<(), DataError> {
    if img.channels != channels || (img.indexed && channels != 1) {
        return Err(DataError::Channels {
            path: path.to_path_buf(),
            what,
            expected: channels.to_string(),
            found: img.channels,
        });
    }
    Ok(())
}

/// Encodes 8-bit samples (`channels` per pixel) as PNG bytes.
pub fn encode_png_u8(
    width: usize,
    height: usize,
    channels: usize,
    data: &[u8],
) -> Result<Vec<u8>, String> {
    encode(width, height, channels, png::BitDepth::Eight, data)
}

/// Encodes 16-bit samples as PNG bytes (big-endian, as PNG requires).
pub fn encode_png_u16(
    width: usize,
    height: usize,
    channels: usize,
    data: &[u16],
) -> Result<Vec<u8>, String> {
    let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_be_bytes()).collect();
    encode(width, height, channels, png::BitDepth::Sixteen, &bytes)
}

/// The `Software` text of the PNGs rtf writes as outputs (predictions): how a later run tells
/// its own files from a dataset's before replacing one.
pub const RTF_SOFTWARE: &str = "rtf";

/// [`encode_png_u8`] with a `Software: rtf <version>` text chunk ([`written_by_rtf`]).
pub fn encode_png_u8_tagged(
    width: usize,
    height: usize,
    channels: usize,
    data: &[u8],
) -> Result<Vec<u8>, String> {
    let software = format!("{RTF_SOFTWARE} {}", env!("CARGO_PKG_VERSION"));
    encode_with(
        width,
        height,
        channels,
        png::BitDepth::Eight,
        data,
        Some(&software),
    )
}

/// Whether the PNG at `path` carries rtf's `Software` text (header and text chunks only).
pub fn written_by_rtf(path: &Path) -> bool {
    let Ok(file) = std::fs::File::open(path) else {
        return false;
    };
    let decoder = png::Decoder::new(std::io::BufReader::new(file));
    let Ok(reader) = decoder.read_info() else {
        return false;
    };
    let info = reader.info();
    let ours =
        |key: &str, text: &str| key == "Software" && text.split(' ').next() == Some(RTF_SOFTWARE);
    info.uncompressed_latin1_text
        .iter()
        .any(|t| ours(&t.keyword, &t.text))
}

fn encode(
    width: usize,
    height: usize,
    channels: usize,
    depth: png::BitDepth,
    data: &[u8],
) -> Result<Vec<u8>, String> {
    encode_with(width, height, channels, depth, data, None)
}

fn encode_with(
    width: usize,
    height: usize,
    channels: usize,
    depth: png::BitDepth,
    data: &[u8],
    software: Option<&str>,
) -> Result<Vec<u8>, String> {
    let color = match channels {
        1 => png::ColorType::Grayscale,
        2 => png::ColorType::GrayscaleAlpha,
        3 => png::ColorType::Rgb,
        4 => png::ColorType::Rgba,
        c => return Err(format!("cannot encode {c} channels")),
    };
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
    enc.set_color(color);
    enc.set_depth(depth);
    enc.set_compression(png::Compression::Fast);
    if let Some(software) = software {
        enc.add_text_chunk("Software".into(), software.into())
            .map_err(|e| e.to_string())?;
    }
    let mut writer = enc.write_header().map_err(|e| e.to_string())?;
    writer.write_image_data(data).map_err(|e| e.to_string())?;
    writer.finish().map_err(|e| e.to_string())?;
    Ok(out)
}

/// Writes an 8-bit PNG atomically (temp file + rename).
pub fn write_png_u8(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    data: &[u8],
) -> Result<(), DataError> {
    let bytes =
        encode_png_u8(width, height, channels, data).map_err(|message| DataError::Write {
            path: path.to_path_buf(),
            message,
        })?;
    rtf_core::write_bytes_atomic(path, &bytes)?;
    Ok(())
}

/// Writes a 16-bit PNG atomically.
pub fn write_png_u16(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    data: &[u16],
) -> Result<(), DataError> {
    let bytes =
        encode_png_u16(width, height, channels, data).map_err(|message| DataError::Write {
            path: path.to_path_buf(),
            message,
        })?;
    rtf_core::write_bytes_atomic(path, &bytes)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tagged_pngs_are_told_from_others() {
        let dir = tempfile::tempdir().unwrap();
        let (ours, theirs) = (dir.path().join("a.png"), dir.path().join("b.png"));
        std::fs::write(&ours, encode_png_u8_tagged(2, 1, 1, &[1, 2]).unwrap()).unwrap();
        std::fs::write(&theirs, encode_png_u8(2, 1, 1, &[1, 2]).unwrap()).unwrap();
        assert!(written_by_rtf(&ours) && !written_by_rtf(&theirs));
        assert_eq!(
            decode_png(&std::fs::read(&ours).unwrap(), &ours)
                .unwrap()
                .samples,
            Samples::U8(vec![1, 2])
        );
        assert!(!written_by_rtf(&dir.path().join("missing.png")));
    }

    #[test]
    fn round_trips_8_and_16_bit() {
        let p = Path::new("x.png");
        let data: Vec<u8> = (0..2 * 3 * 4).map(|i| i as u8 * 7).collect();
        let bytes = encode_png_u8(3, 2, 4, &data).unwrap();
        let img = decode_png(&bytes, p).unwrap();
        assert_eq!((img.width, img.height, img.channels), (3, 2, 4));
        assert_eq!(img.samples, Samples::U8(data));
        let data16: Vec<u16> = (0..6).map(|i| 20000 + i * 1000).collect();
        let img = decode_png(&encode_png_u16(3, 2, 1, &data16).unwrap(), p).unwrap();
        assert_eq!(img.samples, Samples::U16(data16));
    }

    #[test]
    fn rgba_fast_path_matches_the_general_decoder() {
        let data: Vec<u8> = (0..5 * 3 * 4).map(|i| (i * 37 % 256) as u8).collect();
        let bytes = encode_png_u8(5, 3, 4, &data).unwrap();
        let (w, h, rgb, alpha) = decode_rgba8_split(&bytes, Path::new("x.png"))
            .unwrap()
            .unwrap();
        assert_eq!((w, h), (5, 3));
        let expect_rgb: Vec<u8> = data.chunks(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
        assert_eq!(rgb, expect_rgb);
        assert_eq!(alpha[1], data[7] as f32 / 255.0);
        assert!(decode_rgba8_split(
            &encode_png_u8(5, 3, 3, &data[..45]).unwrap(),
            Path::new("x.png")
        )
        .is_none());
        let truncated = decode_rgba8_split(&bytes[..bytes.len() - 20], Path::new("t.png"));
        assert!(truncated
            .unwrap()
            .unwrap_err()
            .to_string()
            .contains("t.png"));
    }

    #[test]
    fn garbage_is_an_error_naming_the_file() {
        let err = decode_png(b"not a png at all", Path::new("dir/bad.png")).unwrap_err();
        assert!(err.to_string().contains("dir/bad.png"), "{err}");
    }
}
