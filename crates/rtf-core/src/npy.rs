//! Minimal NumPy `.npy` (format 1.0) writer and reader for little-endian float32 arrays.

use std::path::Path;

/// An `.npy` header: dtype string (e.g. `<f4`, `|u1`), memory order and shape.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    pub descr: String,
    pub fortran_order: bool,
    pub shape: Vec<usize>,
}

/// Encodes a C-order array whose little-endian bytes are `body`, with dtype `descr`.
pub fn encode(descr: &str, shape: &[usize], body: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_text}, }}");
    // Magic (6) + version (2) + header length (2) + header, padded with spaces to 64 bytes, '\n' last.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + body.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(body);
    out
}

/// Splits `.npy` bytes (format 1, 2 or 3) into its header and data bytes; never panics.
pub fn parse(bytes: &[u8]) -> Result<(Header, &[u8]), String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not an .npy file (bad magic)".into());
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10usize),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(format!("unsupported .npy version {v}")),
    };
    let header = bytes
        .get(start..start.saturating_add(header_len))
        .ok_or("truncated .npy header")?;
    let header = std::str::from_utf8(header).map_err(|_| ".npy header is not text")?;
    let descr = header
        .split("'descr':")
        .nth(1)
        .and_then(|s| s.split('\'').nth(1))
        .ok_or("no dtype in .npy header")?
        .to_string();
    let shape_text = header
        .split("'shape':")
        .nth(1)
        .and_then(|s| s.split(['(', ')']).nth(1))
        .ok_or("no shape in .npy header")?;
    let shape = shape_text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!("bad shape entry `{s}`"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let fortran_order = header.contains("'fortran_order': True");
    Ok((
        Header {
            descr,
            fortran_order,
            shape,
        },
        &bytes[start + header_len..],
    ))
}

/// Encodes a C-order float32 array.
pub fn encode_f32(shape: &[usize], data: &[f32]) -> Vec<u8> {
    assert_eq!(
        shape.iter().product::<usize>(),
        data.len(),
        "shape does not match data length"
    );
    let body: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    encode("<f4", shape, &body)
}

/// Writes a float32 `.npy` atomically.
pub fn write_f32(
    path: &Path,
    shape: &[usize],
    data: &[f32],
) -> Result<(), crate::AtomicWriteError<std::io::Error>> {
    crate::write_bytes_atomic(path, &encode_f32(shape, data))
}

/// Decodes a float32 C-order `.npy` (as written by [`encode_f32`] or NumPy); returns shape and data.
pub fn decode_f32(bytes: &[u8]) -> Result<(Vec<usize>, Vec<f32>), String> {
    let (header, body) = parse(bytes)?;
    if header.descr != "<f4" || header.fortran_order {
        return Err(format!(
            "expected little-endian float32 in C order, found '{}'",
            header.descr
        ));
    }
    let count: usize = header.shape.iter().product();
    if body.len() != 4 * count {
        return Err(format!(
            "expected {} data bytes for shape {:?}, found {}",
            4 * count,
            header.shape,
            body.len()
        ));
    }
    Ok((
        header.shape,
        body.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_alignment() {
        let data: Vec<f32> = (0..24).map(|i| i as f32 * 0.5).collect();
        let bytes = encode_f32(&[2, 3, 4], &data);
        assert_eq!((bytes.len() - 4 * 24) % 64, 0, "header padded to 64 bytes");
        let (shape, back) = decode_f32(&bytes).unwrap();
        assert_eq!(shape, vec![2, 3, 4]);
        assert_eq!(back, data);
    }

    #[test]
    fn one_dimensional_shape_has_trailing_comma() {
        let bytes = encode_f32(&[3], &[1.0, 2.0, 3.0]);
        assert!(String::from_utf8_lossy(&bytes).contains("'shape': (3,)"));
        assert!(decode_f32(&bytes[..bytes.len() - 1]).is_err());
    }
}
