//! Shared vocabulary of rtf: class sets and palettes, day/night, input conventions, and the
//! atomic-write helper every crate uses for outputs, the host description benchmarks report, the
//! refusal a command's library layer says.
//! No libtorch here.

pub mod classes;
pub mod fsutil;
pub mod host;
pub mod input;
pub mod npy;
pub mod refusal;
pub mod size;

pub use classes::{ClassInfo, ClassSet, LabelValues};
pub use fsutil::{resolved, write_atomic, write_bytes_atomic, AtomicWriteError};
pub use input::InputConvention;
pub use refusal::{refused, Refusal};
pub use size::parse_size;

use serde::{Deserialize, Serialize};

/// Time of day of a frame; MF names end in `D` or `N`, Freiburg paths contain `night`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Daytime {
    Day,
    Night,
}

impl Daytime {
    /// MF convention: the frame name's last character, `D` or `N`.
    pub fn from_mf_name(name: &str) -> Option<Self> {
        match name.chars().last()? {
            'D' | 'd' => Some(Self::Day),
            'N' | 'n' => Some(Self::Night),
            _ => None,
        }
    }
}
