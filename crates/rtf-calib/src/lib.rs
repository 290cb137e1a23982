//! rtf-calib: targetless RGB-thermal calibration by edge-gradient alignment (HeatNet §IV-A).
//!
//! Conventions (spec §6): pixel centres at integer coordinates; X_T = R·X_RGB + t; T stored as
//! R and t with se(3) coordinates its exact logarithm.

pub mod bound;
pub mod calibfile;
pub mod camera;
pub mod error;
pub mod frames;
pub mod imageio;
pub mod kalibr;
pub mod model;
pub mod optimize;
pub mod overlay;
pub mod quality;
pub mod real_rig;
pub mod rig;
pub mod run;
pub mod se3;
pub mod solve;
pub mod stereo;
pub mod synth_rig;
pub mod synth_run;

pub use error::{CalibError, Result};
