//! Kalibr-style camchain YAML (`--format kalibr`), so users can compare with target-based
//! results: `cam0` is the RGB camera (pinhole, no distortion), `cam1` the thermal camera
//! (pinhole, `radtan` = our k1, k2, p1, p2, the OpenCV/Kalibr order) with `T_cn_cnm1`, the
//! 4×4 transform from cam0 to cam1 coordinates (X_thermal = R·X_rgb + t, spec §6). Kalibr's
//! pinhole model, like ours, puts pixel centres at integer coordinates.

use crate::camera::{Calibration, RgbCamera, ThermalIntrinsics};
use crate::error::{CalibError, Result};
use crate::se3::Rigid;
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KalibrCam {
    #[serde(rename = "T_cn_cnm1", default, skip_serializing_if = "Option::is_none")]
    pub t_cn_cnm1: Option<[[f64; 4]; 4]>,
    pub camera_model: String,
    pub intrinsics: [f64; 4],
    pub distortion_model: String,
    pub distortion_coeffs: [f64; 4],
    pub resolution: [usize; 2],
    pub rostopic: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Camchain {
    pub cam0: KalibrCam,
    pub cam1: KalibrCam,
}

impl Camchain {
    pub fn new(rgb: &RgbCamera, thermal_size: (usize, usize), calib: &Calibration) -> Self {
        let (r, t) = (calib.extrinsic.rotation, calib.extrinsic.translation);
        let k = &calib.thermal;
        Self {
            cam0: KalibrCam {
                t_cn_cnm1: None,
                camera_model: "pinhole".into(),
                intrinsics: [rgb.fx, rgb.fy, rgb.cx, rgb.cy],
                distortion_model: "radtan".into(),
                distortion_coeffs: [0.0; 4],
                resolution: [rgb.width, rgb.height],
                rostopic: "/rgb/image_raw".into(),
            },
            cam1: KalibrCam {
                t_cn_cnm1: Some([
                    [r[0][0], r[0][1], r[0][2], t[0]],
                    [r[1][0], r[1][1], r[1][2], t[1]],
                    [r[2][0], r[2][1], r[2][2], t[2]],
                    [0.0, 0.0, 0.0, 1.0],
                ]),
                camera_model: "pinhole".into(),
                intrinsics: [k.fx, k.fy, k.cx, k.cy],
                distortion_model: "radtan".into(),
                distortion_coeffs: k.distortion,
                resolution: [thermal_size.0, thermal_size.1],
                rostopic: "/thermal/image_raw".into(),
            },
        }
    }

    /// The thermal calibration this camchain describes (cam1 relative to cam0).
    pub fn calibration(&self) -> std::result::Result<Calibration, String> {
        let cam = &self.cam1;
        if cam.camera_model != "pinhole" || cam.distortion_model != "radtan" {
            return Err(format!(
                "cam1: only pinhole/radtan is supported, found {}/{}",
                cam.camera_model, cam.distortion_model
            ));
        }
        let m = cam.t_cn_cnm1.ok_or("cam1.T_cn_cnm1: missing")?;
        let [fx, fy, cx, cy] = cam.intrinsics;
        Ok(Calibration {
            thermal: ThermalIntrinsics {
                fx,
                fy,
                cx,
                cy,
                distortion: cam.distortion_coeffs,
            },
            extrinsic: Rigid {
                rotation: std::array::from_fn(|i| [m[i][0], m[i][1], m[i][2]]),
                translation: [m[0][3], m[1][3], m[2][3]],
            },
        })
    }

    pub fn save(&self, path: &Path) -> Result<()> {
        let err = |message: String| CalibError::Write {
            path: path.into(),
            message,
        };
        let text = serde_yaml_ng::to_string(self).map_err(|e| err(e.to_string()))?;
        rtf_core::write_bytes_atomic(path, text.as_bytes()).map_err(|e| err(e.to_string()))
    }

    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| CalibError::io(path, e))?;
        serde_yaml_ng::from_str(&text).map_err(|e| CalibError::Rig {
            path: path.into(),
            message: e.to_string(),
        })
    }
}

/// `calib.yaml` → `calib-camchain.yaml` beside it.
pub fn camchain_path(calib_yaml: &Path) -> std::path::PathBuf {
    let stem = calib_yaml
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "calib".into());
    calib_yaml.with_file_name(format!("{stem}-camchain.yaml"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camchain_round_trips_the_parameters() {
        let calib = Calibration {
            thermal: ThermalIntrinsics {
                fx: 531.5,
                fy: 531.5,
                cx: 321.25,
                cy: 250.5,
                distortion: [-0.12, 0.03, 4e-4, -2e-4],
            },
            extrinsic: Rigid::exp([0.05, -0.03, 0.01, 0.02, -0.04, 0.01]),
        };
        let rgb = RgbCamera {
            width: 640,
            height: 480,
            fx: 500.0,
            fy: 500.0,
            cx: 319.5,
            cy: 239.5,
        };
        let dir = tempfile::tempdir().unwrap();
        let path = camchain_path(&dir.path().join("calib.yaml"));
        assert!(path.ends_with("calib-camchain.yaml"));
        Camchain::new(&rgb, (640, 512), &calib).save(&path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        for key in [
            "cam0:",
            "cam1:",
            "T_cn_cnm1:",
            "distortion_model: radtan",
            "intrinsics:",
        ] {
            assert!(text.contains(key), "{key} missing:\n{text}");
        }
        let back = Camchain::load(&path).unwrap().calibration().unwrap();
        assert_eq!(back.thermal, calib.thermal);
        let (deg, m) = back.extrinsic.difference(&calib.extrinsic);
        assert!(deg < 1e-9 && m < 1e-12, "{deg} {m}");
        // A point maps identically through both.
        let a = calib.map_pixel(&rgb, 100.0, 50.0, 7.0).unwrap();
        let b = back.map_pixel(&rgb, 100.0, 50.0, 7.0).unwrap();
        assert!((a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 1e-9);
    }
}
