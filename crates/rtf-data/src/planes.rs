//! The decoded forms every image reader of [`crate::images`] and [`crate::tiffio`] returns:
//! a thermal plane (counts or temperatures) and the grey plane of interleaved samples.

use std::path::Path;

use crate::DataError;

/// A thermal plane as stored: integer counts of a bit depth, or temperatures.
#[derive(Debug, Clone, PartialEq)]
pub enum ThermalSamples {
    /// 8- or 16-bit counts (`bits` says which).
    Counts { bits: u8, values: Vec<u16> },
    /// Floating-point values (°C or K, as the dataset's thermal rule says).
    Degrees(Vec<f32>),
}

/// One thermal image, one channel.
#[derive(Debug, Clone, PartialEq)]
pub struct ThermalImage {
    pub width: usize,
    pub height: usize,
    pub samples: ThermalSamples,
}

/// The grey plane of `channels`-channel interleaved samples: the plane itself for one
/// channel, the first channel of grey + alpha, or of RGB(A) whose colour channels are equal.
/// `None` for colour (a colour-mapped rendering, not measurements).
pub fn grey_plane<T: Copy + PartialEq>(samples: &[T], channels: usize) -> Option<Vec<T>> {
    let grey = match channels {
        1 => return Some(samples.to_vec()),
        2 => true,
        3 | 4 => samples
            .chunks_exact(channels)
            .all(|p| p[0] == p[1] && p[1] == p[2]),
        _ => false,
    };
    grey.then(|| samples.chunks_exact(channels).map(|p| p[0]).collect())
}

/// The error for a thermal image whose colour channels differ.
pub(crate) fn colour_thermal(path: &Path, channels: usize, detail: &str) -> DataError {
    DataError::Format {
        path: path.to_path_buf(),
        message: format!(
            "thermal image has {channels} channels that differ{detail} (a colour-mapped rendering?); rtf reads thermal from one grey channel"
        ),
    }
}
