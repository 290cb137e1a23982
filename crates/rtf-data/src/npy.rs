//! `.npy` 2-D arrays in C order: label maps (Freiburg test set: integer or integral float) and
//! thermal planes (raw counts, or temperatures as floats).

use crate::DataError;
use std::path::Path;

/// A 2-D `.npy` array read as f64 values, with the dtype it was stored in.
pub struct Array2d {
    pub width: usize,
    pub height: usize,
    /// NumPy's kind letter: `u`, `i` or `f`.
    pub kind: u8,
    /// Bytes per element.
    pub size: usize,
    pub values: Vec<f64>,
}

/// Decodes a 2-D `.npy` (C order; u1/i1/u2/i2/u4/i4/u8/i8, f4/f8; a leading or trailing
/// singleton axis is allowed). `what` names the array in errors ("label", "thermal").
pub fn decode_2d(bytes: &[u8], path: &Path, what: &str) -> Result<Array2d, DataError> {
    let bad = |message: String| DataError::Format {
        path: path.to_path_buf(),
        message,
    };
    let (header, body) = rtf_core::npy::parse(bytes).map_err(bad)?;
    if header.fortran_order {
        return Err(bad("Fortran-order arrays are not supported".into()));
    }
    let descr = header.descr.as_str();
    let mut shape = header.shape.clone();
    while shape.len() > 2 && shape[0] == 1 {
        shape.remove(0);
    }
    while shape.len() > 2 && shape[shape.len() - 1] == 1 {
        shape.pop();
    }
    let [h, w] = shape[..] else {
        return Err(bad(format!(
            "expected a 2-D {what} array, shape is {:?}",
            header.shape
        )));
    };
    let n = h
        .checked_mul(w)
        .filter(|&n| n > 0 && n <= 1 << 28)
        .ok_or_else(|| bad(format!("bad {what} shape {h}x{w}")))?;
    let (kind, size, big_endian) = dtype(descr);
    if size == 0 || !matches!((kind, size), (b'u' | b'i', 1 | 2 | 4 | 8) | (b'f', 4 | 8)) {
        return Err(bad(format!("unsupported {what} dtype '{descr}'")));
    }
    if body.len() != n * size {
        return Err(bad(format!(
            "expected {} data bytes for {h}x{w} '{descr}', found {}",
            n * size,
            body.len()
        )));
    }
    let values = body
        .chunks_exact(size)
        .map(|c| element(c, kind, big_endian))
        .collect();
    Ok(Array2d {
        width: w,
        height: h,
        kind,
        size,
        values,
    })
}

/// (kind letter, bytes per element, big-endian) of a NumPy `descr` such as `<f4`.
fn dtype(descr: &str) -> (u8, usize, bool) {
    match descr.as_bytes() {
        [e, kind, s @ ..] => {
            let size: usize = std::str::from_utf8(s)
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or(0);
            (*kind, size, *e == b'>')
        }
        _ => (0, 0, false),
    }
}

/// One element's value.
fn element(c: &[u8], kind: u8, big_endian: bool) -> f64 {
    let size = c.len();
    let mut b = [0u8; 8];
    b[..size].copy_from_slice(c);
    if big_endian {
        b[..size].reverse();
    }
    match (kind, size) {
        (b'u', _) => u64::from_le_bytes(b) as f64,
        (b'i', _) => {
            let shift = 64 - 8 * size as u32;
            ((i64::from_le_bytes(b) << shift) >> shift) as f64
        }
        (b'f', 4) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        _ => f64::from_le_bytes(b),
    }
}

/// Decodes a 2-D `.npy` of class ids into (width, height, ids): any dtype of [`decode_2d`]
/// holding whole numbers 0..=65535.
pub fn decode_label_npy(bytes: &[u8], path: &Path) -> Result<(usize, usize, Vec<u16>), DataError> {
    let array = decode_2d(bytes, path, "label")?;
    let w = array.width;
    let mut ids = Vec::with_capacity(array.values.len());
    for (i, &v) in array.values.iter().enumerate() {
        if !(0.0..=65535.0).contains(&v) || v.fract() != 0.0 {
            return Err(DataError::Format {
                path: path.to_path_buf(),
                message: format!(
                    "label value {v} at (x {}, y {}) is not a class id",
                    i % w,
                    i / w
                ),
            });
        }
        ids.push(v as u16);
    }
    Ok((w, array.height, ids))
}

/// Encodes a 2-D uint8 array (used by the synthetic Freiburg writer).
pub fn encode_u8(width: usize, height: usize, data: &[u8]) -> Vec<u8> {
    rtf_core::npy::encode("|u1", &[height, width], data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn u8_round_trip_and_int64_float_labels() {
        let p = Path::new("l.npy");
        let ids: Vec<u8> = (0..12).collect();
        let (w, h, back) = decode_label_npy(&encode_u8(4, 3, &ids), p).unwrap();
        assert_eq!((w, h), (4, 3));
        assert_eq!(back, ids.iter().map(|&v| v as u16).collect::<Vec<_>>());
        // int64 as NumPy writes it by default.
        let mut bytes = encode_u8(2, 1, &[0, 0]);
        let at = bytes.windows(4).position(|w| w == b"|u1'").unwrap();
        bytes[at..at + 3].copy_from_slice(b"<i8");
        bytes.truncate(bytes.len() - 2);
        bytes.extend_from_slice(&13i64.to_le_bytes());
        bytes.extend_from_slice(&2i64.to_le_bytes());
        assert_eq!(decode_label_npy(&bytes, p).unwrap().2, vec![13, 2]);
        let bad = &bytes[..bytes.len() - 3];
        assert!(decode_label_npy(bad, p)
            .unwrap_err()
            .to_string()
            .contains("l.npy"));
    }
}
