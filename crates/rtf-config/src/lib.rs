//! rtf-config: the configuration schema of rtf, as data. What a training run is
//! ([`train::TrainConfig`], a multi-stage [`train::RunConfig`]), which network it builds
//! ([`network::ModelConfig`]), which dataset it reads and how ([`data`]), its arithmetic
//! ([`Precision`]) and the kernels it recorded ([`compute`]).
//!
//! No libtorch here: `config.json` is read and checked where libtorch is absent (xtask, the
//! readers of run folders). The crates that act on these values (rtf-models builds networks,
//! rtf-data opens datasets, rtf-amp enters autocast, rtf-train trains) re-export them.

pub mod compute;
pub mod data;
pub mod network;
pub mod precision;
pub mod train;

pub use precision::{Bf16Convolutions, Precision};
pub use train::{ConfigError, RunConfig, TrainConfig};
