//! Thermal TIFFs as radiometric cameras export them (FLIR Boson/Tau tools, most RGB-T
//! releases): one grey channel of 8- or 16-bit counts or 32-bit float temperatures,
//! uncompressed, LZW, deflate or PackBits, in strips or tiles. Grey stored as RGB(A) with equal
//! channels is read as grey. Anything else — 12-bit packed samples, signed or 64-bit samples,
//! separate colour planes, JPEG-in-TIFF — is refused naming the file and what it is.

use std::io::Cursor;
use std::path::Path;

use tiff::decoder::{Decoder, DecodingResult};
use tiff::tags::{PlanarConfiguration, SampleFormat, Tag};
use tiff::ColorType;

use crate::planes::{colour_thermal, grey_plane, ThermalImage, ThermalSamples};
use crate::DataError;

/// Decodes a thermal TIFF (module docs); `path` names the file in errors.
pub fn decode_thermal_tiff(bytes: &[u8], path: &Path) -> Result<ThermalImage, DataError> {
    let bad = |message: String| DataError::Format {
        path: path.to_path_buf(),
        message,
    };
    let tiff_err = |e: tiff::TiffError| bad(format!("not a readable TIFF: {e}"));
    let mut decoder = Decoder::new(Cursor::new(bytes)).map_err(tiff_err)?;
    let (width, height) = decoder.dimensions().map_err(tiff_err)?;
    let color = decoder.colortype().map_err(tiff_err)?;
    let channels = match color {
        ColorType::Gray(_) => 1,
        ColorType::GrayA(_) => 2,
        ColorType::RGB(_) => 3,
        ColorType::RGBA(_) => 4,
        other => return Err(bad(format!("{other:?} TIFF: rtf reads grey thermal TIFFs"))),
    };
    let planar = decoder
        .find_tag_unsigned::<u16>(Tag::PlanarConfiguration)
        .map_err(tiff_err)?;
    if channels > 1 && planar == Some(PlanarConfiguration::Planar.to_u16()) {
        return Err(bad(format!(
            "{channels} samples per pixel in separate planes (planar configuration 2): rtf reads interleaved TIFFs"
        )));
    }
    let format = decoder
        .find_tag_unsigned_vec::<u16>(Tag::SampleFormat)
        .map_err(tiff_err)?
        .and_then(|v| v.first().copied())
        .unwrap_or(SampleFormat::Uint.to_u16());
    check_sample_layout(color_bits(color), format).map_err(bad)?;
    let decoded = decoder.read_image().map_err(tiff_err)?;
    let samples =
        samples_of(decoded, channels).ok_or_else(|| colour_thermal(path, channels, ""))?;
    let (width, height) = (width as usize, height as usize);
    let found = match &samples {
        ThermalSamples::Counts { values, .. } => values.len(),
        ThermalSamples::Degrees(values) => values.len(),
    };
    if found != width * height {
        return Err(bad(format!("{found} samples for a {width}x{height} image")));
    }
    Ok(ThermalImage {
        width,
        height,
        samples,
    })
}

fn color_bits(color: ColorType) -> u8 {
    match color {
        ColorType::Gray(b) | ColorType::GrayA(b) | ColorType::RGB(b) | ColorType::RGBA(b) => b,
        _ => 0,
    }
}

/// 8- or 16-bit unsigned integers, or 32-bit floats.
fn check_sample_layout(bits: u8, format: u16) -> Result<(), String> {
    let uint = format == SampleFormat::Uint.to_u16();
    let float = format == SampleFormat::IEEEFP.to_u16();
    match (bits, uint, float) {
        (8 | 16, true, _) | (32, _, true) => Ok(()),
        (_, true, _) => Err(format!(
            "{bits}-bit integer samples: rtf reads 8- or 16-bit counts (or 32-bit float temperatures)"
        )),
        (_, _, true) => Err(format!(
            "{bits}-bit float samples: rtf reads 32-bit float temperatures"
        )),
        _ => Err(format!(
            "{bits}-bit samples of sample format {format} (signed or complex): rtf reads unsigned 8/16-bit counts or 32-bit floats"
        )),
    }
}

/// The grey plane of decoded samples; `None` when colour channels differ.
fn samples_of(decoded: DecodingResult, channels: usize) -> Option<ThermalSamples> {
    Some(match decoded {
        DecodingResult::U8(v) => ThermalSamples::Counts {
            bits: 8,
            values: grey_plane(&v, channels)?
                .into_iter()
                .map(u16::from)
                .collect(),
        },
        DecodingResult::U16(v) => ThermalSamples::Counts {
            bits: 16,
            values: grey_plane(&v, channels)?,
        },
        DecodingResult::F32(v) => ThermalSamples::Degrees(grey_plane(&v, channels)?),
        // Excluded by `check_sample_layout` before decoding.
        _ => return None,
    })
}

/// How a TIFF written by [`encode_grey`] is compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TiffCompression {
    None,
    Lzw,
    Deflate,
    PackBits,
}

/// One grey plane to write as TIFF (synthetic data sets, test fixtures).
pub enum GreyPlane<'a> {
    U8(&'a [u8]),
    U16(&'a [u16]),
    F32(&'a [f32]),
}

/// Encodes a grey TIFF of `width` × `height` samples.
pub fn encode_grey(
    width: u32,
    height: u32,
    plane: GreyPlane,
    compression: TiffCompression,
) -> Result<Vec<u8>, tiff::TiffError> {
    use tiff::encoder::{colortype, Compression, DeflateLevel, TiffEncoder};
    let mut out = Cursor::new(Vec::new());
    let compression = match compression {
        TiffCompression::None => Compression::Uncompressed,
        TiffCompression::Lzw => Compression::Lzw,
        TiffCompression::Deflate => Compression::Deflate(DeflateLevel::Balanced),
        TiffCompression::PackBits => Compression::Packbits,
    };
    let mut encoder = TiffEncoder::new(&mut out)?.with_compression(compression);
    match plane {
        GreyPlane::U8(v) => encoder.write_image::<colortype::Gray8>(width, height, v)?,
        GreyPlane::U16(v) => encoder.write_image::<colortype::Gray16>(width, height, v)?,
        GreyPlane::F32(v) => encoder.write_image::<colortype::Gray32Float>(width, height, v)?,
    }
    Ok(out.into_inner())
}

/// A one-strip little-endian grey TIFF of `bits`-bit samples written byte by byte (no
/// compression): layouts the encoder does not write (12-bit packed), for tests and fixtures.
pub fn raw_grey_tiff(width: u16, height: u16, bits: u16, data: &[u8]) -> Vec<u8> {
    let (width, height, bits) = (width.into(), height.into(), bits.into());
    raw_tiff(
        &[
            (256, SHORT, &[width]),
            (257, SHORT, &[height]),
            (258, SHORT, &[bits]),
            (259, SHORT, &[1]),
            (262, SHORT, &[1]),
            (273, LONG, &[0]),
            (277, SHORT, &[1]),
            (278, SHORT, &[height]),
            (279, LONG, &[data.len() as u32]),
        ],
        data,
    )
}

/// TIFF field types [`raw_tiff`] writes.
pub const SHORT: u16 = 3;
pub const LONG: u16 = 4;

/// A little-endian one-image TIFF written byte by byte from its tags `(tag, type, values)`, in
/// ascending tag order, and the image data: layouts the encoder does not write (tiles, planes,
/// packed samples), for tests and fixtures. Values of the offset tags (StripOffsets 273,
/// TileOffsets 324) are given relative to the start of `data`.
pub fn raw_tiff(tags: &[(u16, u16, &[u32])], data: &[u8]) -> Vec<u8> {
    let ifd_len = 2 + tags.len() * 12 + 4;
    let size = |kind: u16| if kind == SHORT { 2 } else { 4 };
    let spilled: usize = tags
        .iter()
        .map(|(_, kind, values)| size(*kind) * values.len())
        .filter(|&bytes| bytes > 4)
        .sum();
    let data_start = (8 + ifd_len + spilled) as u32;
    let mut out = b"II*\0".to_vec();
    out.extend(8u32.to_le_bytes());
    out.extend((tags.len() as u16).to_le_bytes());
    let mut arrays = Vec::new();
    for &(tag, kind, values) in tags {
        let shift = if matches!(tag, 273 | 324) {
            data_start
        } else {
            0
        };
        let mut bytes = Vec::new();
        for &v in values {
            match kind {
                SHORT => bytes.extend((v as u16).to_le_bytes()),
                _ => bytes.extend((v + shift).to_le_bytes()),
            }
        }
        out.extend(tag.to_le_bytes());
        out.extend(kind.to_le_bytes());
        out.extend((values.len() as u32).to_le_bytes());
        if bytes.len() <= 4 {
            bytes.resize(4, 0);
            out.extend(bytes);
        } else {
            out.extend(((8 + ifd_len + arrays.len()) as u32).to_le_bytes());
            arrays.extend(bytes);
        }
    }
    out.extend(0u32.to_le_bytes());
    out.extend(arrays);
    out.extend(data);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::images::decode_thermal;

    fn p() -> &'static Path {
        Path::new("ir.tiff")
    }

    #[test]
    fn sixteen_bit_counts_read_back_under_every_compression() {
        let values: Vec<u16> = (0..48).map(|i| 21000 + i * 97).collect();
        for compression in [
            TiffCompression::None,
            TiffCompression::Lzw,
            TiffCompression::Deflate,
            TiffCompression::PackBits,
        ] {
            let bytes = encode_grey(8, 6, GreyPlane::U16(&values), compression).unwrap();
            let t = decode_thermal(&bytes, p()).unwrap();
            assert_eq!((t.width, t.height), (8, 6));
            let want = ThermalSamples::Counts {
                bits: 16,
                values: values.clone(),
            };
            assert_eq!(t.samples, want, "{compression:?}");
        }
    }

    #[test]
    fn eight_bit_and_float_planes_read_back() {
        let bytes = encode_grey(3, 1, GreyPlane::U8(&[1, 2, 3]), TiffCompression::Lzw).unwrap();
        let t = decode_thermal(&bytes, p()).unwrap();
        assert_eq!(
            t.samples,
            ThermalSamples::Counts {
                bits: 8,
                values: vec![1, 2, 3]
            }
        );
        let floats = [20.5f32, -3.25, 310.0];
        let bytes = encode_grey(3, 1, GreyPlane::F32(&floats), TiffCompression::None).unwrap();
        let t = decode_thermal(&bytes, p()).unwrap();
        assert_eq!(t.samples, ThermalSamples::Degrees(floats.to_vec()));
    }

    #[test]
    fn unsupported_layouts_and_truncation_are_refused_naming_the_file() {
        use tiff::encoder::{colortype, TiffEncoder};
        let mut signed = Cursor::new(Vec::new());
        TiffEncoder::new(&mut signed)
            .unwrap()
            .write_image::<colortype::GrayI16>(2, 1, &[-5, 7])
            .unwrap();
        let err = decode_thermal(signed.get_ref(), p())
            .unwrap_err()
            .to_string();
        assert!(err.contains("ir.tiff") && err.contains("signed"), "{err}");
        let mut colour = Cursor::new(Vec::new());
        TiffEncoder::new(&mut colour)
            .unwrap()
            .write_image::<colortype::RGB8>(2, 1, &[1, 2, 3, 4, 4, 4])
            .unwrap();
        let err = decode_thermal(colour.get_ref(), p())
            .unwrap_err()
            .to_string();
        assert!(err.contains("ir.tiff") && err.contains("differ"), "{err}");
        let good = encode_grey(8, 6, GreyPlane::U16(&[9; 48]), TiffCompression::Lzw).unwrap();
        for cut in [9, good.len() / 2, good.len() - 4] {
            let err = decode_thermal(&good[..cut], p()).unwrap_err().to_string();
            assert!(err.contains("ir.tiff"), "cut {cut}: {err}");
        }
    }

    #[test]
    fn twelve_bit_packed_samples_are_refused_by_their_layout() {
        // 2 × 2 pixels of 12 bits: 3 bytes a row.
        let bytes = raw_grey_tiff(2, 2, 12, &[0x12, 0x34, 0x56, 0x78, 0x9a, 0xbc]);
        let err = decode_thermal(&bytes, p()).unwrap_err().to_string();
        assert!(err.contains("ir.tiff") && err.contains("12-bit"), "{err}");
        // The same writer's 16-bit file reads: the refusal is the layout's.
        let bytes = raw_grey_tiff(2, 1, 16, &[1, 0, 2, 0]);
        let t = decode_thermal(&bytes, p()).unwrap();
        assert_eq!(
            t.samples,
            ThermalSamples::Counts {
                bits: 16,
                values: vec![1, 2]
            }
        );
    }

    /// 16-bit samples of a `width`×`height` image cut into 16×16 tiles (row-major, the edge
    /// tiles padded), as a tiled TIFF stores them.
    fn tiles_of(values: &[u16], width: usize, height: usize) -> (Vec<u8>, Vec<u32>) {
        let (across, down) = (width.div_ceil(16), height.div_ceil(16));
        let mut data = Vec::new();
        let mut offsets = Vec::new();
        for ty in 0..down {
            for tx in 0..across {
                offsets.push(data.len() as u32);
                for y in ty * 16..ty * 16 + 16 {
                    for x in tx * 16..tx * 16 + 16 {
                        let v = if x < width && y < height {
                            values[y * width + x]
                        } else {
                            0
                        };
                        data.extend(v.to_le_bytes());
                    }
                }
            }
        }
        (data, offsets)
    }

    #[test]
    fn a_tiled_sixteen_bit_tiff_reads_back_pixel_for_pixel() {
        let (width, height) = (20usize, 18usize);
        let values: Vec<u16> = (0..width * height).map(|i| 20000 + i as u16 * 7).collect();
        let (data, offsets) = tiles_of(&values, width, height);
        let counts = vec![16 * 16 * 2; offsets.len()];
        let (w, h) = (width as u32, height as u32);
        let bytes = raw_tiff(
            &[
                (256, SHORT, &[w]),
                (257, SHORT, &[h]),
                (258, SHORT, &[16]),
                (259, SHORT, &[1]),
                (262, SHORT, &[1]),
                (277, SHORT, &[1]),
                (322, SHORT, &[16]),
                (323, SHORT, &[16]),
                (324, LONG, &offsets),
                (325, LONG, &counts),
            ],
            &data,
        );
        let t = decode_thermal(&bytes, p()).unwrap();
        assert_eq!((t.width, t.height), (width, height));
        assert_eq!(t.samples, ThermalSamples::Counts { bits: 16, values });
    }

    #[test]
    fn separate_colour_planes_are_refused_and_a_grey_plane_reads() {
        // 2 × 1 pixels, RGB 8-bit stored plane by plane (planar configuration 2).
        let planes = [10u8, 11, 20, 21, 30, 31];
        let bytes = raw_tiff(
            &[
                (256, SHORT, &[2]),
                (257, SHORT, &[1]),
                (258, SHORT, &[8, 8, 8]),
                (259, SHORT, &[1]),
                (262, SHORT, &[2]),
                (273, LONG, &[0, 2, 4]),
                (277, SHORT, &[3]),
                (278, SHORT, &[1]),
                (279, LONG, &[2, 2, 2]),
                (284, SHORT, &[2]),
            ],
            &planes,
        );
        let err = decode_thermal(&bytes, p()).unwrap_err().to_string();
        assert!(
            err.contains("ir.tiff") && err.contains("planar configuration 2"),
            "{err}"
        );
        // One sample per pixel: planar and interleaved are the same bytes.
        let grey = raw_tiff(
            &[
                (256, SHORT, &[2]),
                (257, SHORT, &[1]),
                (258, SHORT, &[8]),
                (259, SHORT, &[1]),
                (262, SHORT, &[1]),
                (273, LONG, &[0]),
                (277, SHORT, &[1]),
                (278, SHORT, &[1]),
                (279, LONG, &[2]),
                (284, SHORT, &[2]),
            ],
            &[7, 9],
        );
        let t = decode_thermal(&grey, p()).unwrap();
        assert_eq!(
            t.samples,
            ThermalSamples::Counts {
                bits: 8,
                values: vec![7, 9]
            }
        );
    }
}
