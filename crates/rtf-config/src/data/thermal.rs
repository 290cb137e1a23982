//! How a dataset's thermal samples become the network's [0, 1] thermal plane
//! ([`ThermalNormalisation`]), as a dataset description and a run's weights record it;
//! rtf-data's `thermal` applies it.

use serde::{Deserialize, Serialize};

/// A linear map from raw counts to a temperature: `t = scale * counts + offset`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemperatureMap {
    pub scale: f64,
    pub offset: f64,
    pub unit: TemperatureUnit,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TemperatureUnit {
    Celsius,
    Kelvin,
}

/// How thermal samples become [0, 1].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ThermalNormalisation {
    /// 8-bit only: byte / 255. 16-bit files under this rule are an error.
    Byte,
    /// `[lo, hi]` in counts, or in degrees of `map` when given; clipped.
    Range {
        lo: f64,
        hi: f64,
        map: Option<TemperatureMap>,
    },
    /// Each image's own minimum and maximum.
    MinMax,
    /// Each image's `lo`-th and `hi`-th percentiles (0..=100), clipped.
    Percentile { lo: f64, hi: f64 },
}

impl ThermalNormalisation {
    /// A short description for the first line of output ("16-bit, range [21800, 25000]").
    pub fn describe(&self) -> String {
        match self {
            Self::Byte => "8-bit / 255".into(),
            Self::Range { lo, hi, map: None } => format!("range [{lo}, {hi}] counts, clipped"),
            Self::Range {
                lo,
                hi,
                map: Some(m),
            } => format!(
                "counts x {} + {} -> {:?}, range [{lo}, {hi}], clipped",
                m.scale, m.offset, m.unit
            ),
            Self::MinMax => "per-image min-max".into(),
            Self::Percentile { lo, hi } => format!("per-image percentile clip [{lo}, {hi}]"),
        }
    }
}
