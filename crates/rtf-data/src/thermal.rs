//! Thermal normalisation of RGB-T datasets other than MF and Freiburg: how raw thermal counts
//! (8-bit, or 16-bit radiometric) become the network's [0, 1] thermal plane.
//!
//! - 8-bit thermal without a rule: byte / 255 (as MF; spec §1).
//! - A fixed range `[lo, hi]`: linear to [0, 1], clipped (as HeatNet clips Freiburg's 16-bit
//!   counts; spec §5), optionally after a linear map counts → °C/K given by the user, in which
//!   case the range is in degrees.
//! - Per image: min–max, or a percentile clip `[p_lo, p_hi]` (the common AGC-style display
//!   of radiometric frames).
//!
//! 16-bit thermal without a rule is refused: guessing a range would change what the network
//! sees from one dataset to the next without a word.

use std::path::Path;

use crate::planes::ThermalSamples;
use crate::DataError;

/// How thermal samples become [0, 1]: the schema's (rtf-config; a run and its weights record
/// it).
pub use rtf_config::data::{TemperatureMap, TemperatureUnit, ThermalNormalisation};

/// A [`ThermalNormalisation`] applied to an image's samples.
pub trait Normalise {
    /// Normalises one image's samples (`bits` 8 or 16, already one channel) to [0, 1].
    /// `path` names the file in the error for 16-bit samples without a rule.
    fn apply(&self, samples: &[u16], bits: u8, path: &Path) -> Result<Vec<f32>, DataError>;

    /// Normalises one thermal image as read ([`ThermalSamples`]): counts by [`Self::apply`];
    /// temperatures (float TIFF or `.npy`) by a range in degrees, min–max or percentiles. A
    /// float thermal under the 8-bit rule, or a range with a counts → degrees map (the file
    /// holds degrees already), is an error naming the file.
    fn apply_samples(&self, samples: &ThermalSamples, path: &Path) -> Result<Vec<f32>, DataError>;
}

impl Normalise for ThermalNormalisation {
    fn apply(&self, samples: &[u16], bits: u8, path: &Path) -> Result<Vec<f32>, DataError> {
        Ok(match self {
            Self::Byte if bits == 8 => samples.iter().map(|&v| v as f32 / 255.0).collect(),
            Self::Byte => {
                return Err(DataError::ThermalNormalisation {
                    path: path.to_path_buf(),
                    bits,
                })
            }
            Self::Range { lo, hi, map } => {
                let to_unit = |&v: &u16| match map {
                    Some(m) => m.scale * v as f64 + m.offset,
                    None => v as f64,
                };
                linear_clip(samples, lo, hi, to_unit)
            }
            Self::MinMax => {
                let lo = samples.iter().copied().min().unwrap_or(0) as f64;
                let hi = samples.iter().copied().max().unwrap_or(0) as f64;
                linear_clip(samples, &lo, &hi, |&v| v as f64)
            }
            Self::Percentile { lo, hi } => {
                let (a, b) = percentiles(samples, *lo, *hi);
                linear_clip(samples, &a, &b, |&v| v as f64)
            }
        })
    }

    fn apply_samples(&self, samples: &ThermalSamples, path: &Path) -> Result<Vec<f32>, DataError> {
        let values = match samples {
            ThermalSamples::Counts { bits, values } => return self.apply(values, *bits, path),
            ThermalSamples::Degrees(values) => values,
        };
        let bad = |message: &str| DataError::Format {
            path: path.to_path_buf(),
            message: message.to_string(),
        };
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(bad(&format!(
                "thermal value {} at sample {i} is not a number",
                values[i]
            )));
        }
        let degrees = |v: &f32| f64::from(*v);
        Ok(match self {
            Self::Byte => return Err(bad("float thermal (temperatures) needs a rule: give `thermal: {range: [lo, hi]}` in its degrees, or `percentile: [1, 99]` / `min_max: true`, in dataset.yaml")),
            Self::Range { map: Some(_), .. } => return Err(bad("float thermal holds temperatures already: `to_temperature` maps counts, drop it and give the range in the file's degrees")),
            Self::Range { lo, hi, map: None } => linear_clip(values, lo, hi, degrees),
            Self::MinMax => {
                let lo = values.iter().copied().fold(f32::INFINITY, f32::min) as f64;
                let hi = values.iter().copied().fold(f32::NEG_INFINITY, f32::max) as f64;
                linear_clip(values, &lo, &hi, degrees)
            }
            Self::Percentile { lo, hi } => {
                let mut sorted = values.clone();
                sorted.sort_by(f32::total_cmp);
                let rank = |p: f64| ((p / 100.0) * (sorted.len().max(1) - 1) as f64).round() as usize;
                let at = |p: f64| sorted.get(rank(p)).map_or(0.0, |&v| v as f64);
                linear_clip(values, &at(*lo), &at(*hi), degrees)
            }
        })
    }
}

/// `(f(v) - lo) / (hi - lo)` clipped to [0, 1]; a flat range (hi <= lo) gives 0 everywhere.
fn linear_clip<T>(samples: &[T], lo: &f64, hi: &f64, f: impl Fn(&T) -> f64) -> Vec<f32> {
    let span = hi - lo;
    if span <= 0.0 {
        return vec![0.0; samples.len()];
    }
    samples
        .iter()
        .map(|v| ((f(v) - lo) / span).clamp(0.0, 1.0) as f32)
        .collect()
}

/// The `lo`-th and `hi`-th percentiles of the samples (nearest rank, from a full histogram).
fn percentiles(samples: &[u16], lo: f64, hi: f64) -> (f64, f64) {
    if samples.is_empty() {
        return (0.0, 0.0);
    }
    let mut histogram = vec![0usize; 65536];
    for &v in samples {
        histogram[v as usize] += 1;
    }
    let rank = |p: f64| ((p / 100.0) * (samples.len() - 1) as f64).round() as usize;
    let (want_lo, want_hi) = (rank(lo), rank(hi));
    let (mut seen, mut found_lo, mut found_hi) = (0usize, None, None);
    for (value, &count) in histogram.iter().enumerate() {
        seen += count;
        if found_lo.is_none() && seen > want_lo {
            found_lo = Some(value as f64);
        }
        if seen > want_hi {
            found_hi = Some(value as f64);
            break;
        }
    }
    (found_lo.unwrap_or(0.0), found_hi.unwrap_or(65535.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> &'static Path {
        Path::new("t.png")
    }

    #[test]
    fn byte_rule_scales_8_bit_and_refuses_16_bit_naming_the_file() {
        let out = ThermalNormalisation::Byte
            .apply(&[0, 255, 51], 8, p())
            .unwrap();
        assert_eq!(out, vec![0.0, 1.0, 0.2]);
        let err = ThermalNormalisation::Byte
            .apply(&[0, 40000], 16, p())
            .unwrap_err();
        let text = err.to_string();
        assert!(text.contains("t.png") && text.contains("16-bit"), "{text}");
    }

    #[test]
    fn fixed_range_is_linear_and_clipped() {
        let rule = ThermalNormalisation::Range {
            lo: 21800.0,
            hi: 25000.0,
            map: None,
        };
        let out = rule
            .apply(&[20000, 21800, 23400, 25000, 30000], 16, p())
            .unwrap();
        assert_eq!(out, vec![0.0, 0.0, 0.5, 1.0, 1.0]);
    }

    #[test]
    fn range_in_degrees_goes_through_the_temperature_map() {
        // counts * 0.01 - 273.15 = °C: 29315 -> 20 °C, 31315 -> 40 °C.
        let rule = ThermalNormalisation::Range {
            lo: 20.0,
            hi: 40.0,
            map: Some(TemperatureMap {
                scale: 0.01,
                offset: -273.15,
                unit: TemperatureUnit::Celsius,
            }),
        };
        let out = rule.apply(&[29315, 30315, 31315], 16, p()).unwrap();
        for (got, want) in out.iter().zip([0.0f32, 0.5, 1.0]) {
            assert!((got - want).abs() < 1e-4, "{out:?}");
        }
    }

    #[test]
    fn min_max_and_percentiles_follow_the_image() {
        let out = ThermalNormalisation::MinMax
            .apply(&[1000, 1500, 2000], 16, p())
            .unwrap();
        assert_eq!(out, vec![0.0, 0.5, 1.0]);
        // 101 samples 0..=100 plus one hot outlier: the 1st..99th percentile clip ignores it.
        let mut samples: Vec<u16> = (0..=100).map(|v| 1000 + v * 10).collect();
        samples.push(60000);
        let rule = ThermalNormalisation::Percentile { lo: 1.0, hi: 99.0 };
        let out = rule.apply(&samples, 16, p()).unwrap();
        assert_eq!(out[0], 0.0);
        assert_eq!(*out.last().unwrap(), 1.0);
        assert!(out[50] > 0.45 && out[50] < 0.55, "{}", out[50]);
    }

    #[test]
    fn temperatures_take_a_range_in_degrees_and_refuse_the_byte_rule_and_a_counts_map() {
        let temps = ThermalSamples::Degrees(vec![10.0, 25.0, 40.0, 55.0]);
        let rule = ThermalNormalisation::Range {
            lo: 10.0,
            hi: 40.0,
            map: None,
        };
        assert_eq!(
            rule.apply_samples(&temps, p()).unwrap(),
            vec![0.0, 0.5, 1.0, 1.0]
        );
        let out = ThermalNormalisation::MinMax
            .apply_samples(&temps, p())
            .unwrap();
        assert_eq!(out, vec![0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0]);
        let err = ThermalNormalisation::Byte
            .apply_samples(&temps, p())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("t.png") && err.contains("needs a rule"),
            "{err}"
        );
        let mapped = ThermalNormalisation::Range {
            lo: 10.0,
            hi: 40.0,
            map: Some(TemperatureMap {
                scale: 0.01,
                offset: -273.15,
                unit: TemperatureUnit::Celsius,
            }),
        };
        let err = mapped.apply_samples(&temps, p()).unwrap_err().to_string();
        assert!(err.contains("to_temperature"), "{err}");
        let nan = ThermalSamples::Degrees(vec![1.0, f32::NAN]);
        let err = rule.apply_samples(&nan, p()).unwrap_err().to_string();
        assert!(err.contains("sample 1"), "{err}");
    }
}
