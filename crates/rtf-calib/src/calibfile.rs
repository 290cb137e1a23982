//! `calib.yaml` (and `ground_truth.yaml`): thermal intrinsics and distortion, the extrinsic as
//! R (rows), t (metres) and se3 = exact log(R, t), plus quality figures.

use crate::camera::{Calibration, ThermalIntrinsics};
use crate::error::{CalibError, Result};
use crate::se3::Rigid;
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalSection {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// k1, k2, p1, p2.
    pub distortion: [f64; 4],
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExtrinsicSection {
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
    pub se3: [f64; 6],
}

/// The `quality:` section: the optimiser's figures and the assessment a user can act on
/// (verdict, reason, scores, agreeing frames, uncertainty; see [`crate::quality`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Quality {
    /// Final loss of the recipe's finest stage (lower is better; comparable within a recipe).
    pub loss: f64,
    pub frames_used: usize,
    pub iterations: usize,
    #[serde(flatten, default, skip_serializing_if = "Option::is_none")]
    pub assessment: Option<crate::quality::Assessment>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibFile {
    pub thermal: ThermalSection,
    pub extrinsic: ExtrinsicSection,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quality: Option<Quality>,
}

impl CalibFile {
    /// Builds the file from exponential coordinates: `rotation`/`translation` = exp(se3).
    pub fn from_se3(thermal: &ThermalIntrinsics, se3: [f64; 6], quality: Option<Quality>) -> Self {
        let t = Rigid::exp(se3);
        Self {
            thermal: ThermalSection {
                fx: thermal.fx,
                fy: thermal.fy,
                cx: thermal.cx,
                cy: thermal.cy,
                distortion: thermal.distortion,
            },
            extrinsic: ExtrinsicSection {
                rotation: t.rotation,
                translation: t.translation,
                se3,
            },
            quality,
        }
    }

    /// Builds the file from (R, t): se3 = log(R, t).
    pub fn from_calibration(calib: &Calibration, quality: Option<Quality>) -> Self {
        Self::from_se3(&calib.thermal, calib.extrinsic.log(), quality)
    }

    /// Readers use `rotation` and `translation` (spec §6).
    pub fn calibration(&self) -> Calibration {
        let t = &self.thermal;
        Calibration {
            thermal: ThermalIntrinsics {
                fx: t.fx,
                fy: t.fy,
                cx: t.cx,
                cy: t.cy,
                distortion: t.distortion,
            },
            extrinsic: Rigid {
                rotation: self.extrinsic.rotation,
                translation: self.extrinsic.translation,
            },
        }
    }

    /// The calib.yaml text [`save`](Self::save) writes.
    pub fn to_yaml(&self) -> std::result::Result<String, String> {
        serde_yaml_ng::to_string(self).map_err(|e| e.to_string())
    }

    pub fn save(&self, path: &Path) -> Result<()> {
        let text = self.to_yaml().map_err(|message| CalibError::Write {
            path: path.into(),
            message,
        })?;
        rtf_core::write_bytes_atomic(path, text.as_bytes()).map_err(|e| CalibError::Write {
            path: path.into(),
            message: e.to_string(),
        })
    }

    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| CalibError::io(path, e))?;
        serde_yaml_ng::from_str(&text).map_err(|e| CalibError::Rig {
            path: path.into(),
            message: e.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calib_yaml_round_trips_and_se3_is_log_of_rotation_translation() {
        let thermal = ThermalIntrinsics {
            fx: 530.0,
            fy: 528.0,
            cx: 322.0,
            cy: 250.0,
            distortion: [-0.1, 0.02, 1e-3, -1e-3],
        };
        let se3 = [0.05, -0.02, 0.01, 0.01, -0.03, 0.02];
        let file = CalibFile::from_se3(
            &thermal,
            se3,
            Some(Quality {
                loss: 0.5,
                frames_used: 3,
                iterations: 10,
                assessment: None,
            }),
        );
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("calib.yaml");
        file.save(&path).unwrap();
        let back = CalibFile::load(&path).unwrap();
        assert_eq!(back, file);
        let text = std::fs::read_to_string(&path).unwrap();
        for key in [
            "thermal:",
            "distortion:",
            "extrinsic:",
            "rotation:",
            "translation:",
            "se3:",
            "quality:",
            "frames_used:",
        ] {
            assert!(text.contains(key), "missing {key} in\n{text}");
        }
        let log = back.calibration().extrinsic.log();
        assert!(log.iter().zip(se3).all(|(a, b)| (a - b).abs() < 1e-12));
    }
}
