//! `rig.yaml`: the cameras, the frames (paths relative to the file) and optional optimizer
//! settings. Parsing errors name the file and the field.

use crate::camera::RgbCamera;
use crate::error::{CalibError, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Nominal thermal camera: eq. 8 initialises K_T from these.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalSpec {
    pub width: usize,
    pub height: usize,
    pub focal_length_mm: f64,
    pub pixel_pitch_mm: f64,
    /// Square pixels (fx = fy), the default: every thermal core we know of has them. `false`
    /// lets the calibration fit fx and fy separately.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub square_pixels: Option<bool>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameSpec {
    pub rgb: PathBuf,
    pub thermal: PathBuf,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rgb_right: Option<PathBuf>,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StereoSpec {
    pub baseline_m: f64,
}

/// Optimizer settings; each one present overrides the recipe's value.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizerOverrides {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iterations: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub batch_size: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub learning_rate: Option<f64>,
}

impl OptimizerOverrides {
    /// `self` where set, else `lower`.
    pub fn or(self, lower: OptimizerOverrides) -> Self {
        Self {
            iterations: self.iterations.or(lower.iterations),
            batch_size: self.batch_size.or(lower.batch_size),
            learning_rate: self.learning_rate.or(lower.learning_rate),
        }
    }
}

/// What the user knows about the rig (issue 28), each item optional. Estimation becomes MAP:
/// the images' cost plus (x − μ)²/σ² per item, so directions the images cannot fix (focal
/// length against forward offset, principal point against rotation) are set by what was
/// measured rather than left to chance.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PriorSpec {
    /// Thermal camera centre in the RGB frame (metres), as measured: −Rᵀt.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation_m: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation_sigma_m: Option<f64>,
    /// Rotation vector RGB → thermal (the `se3` ω), degrees.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation_deg: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation_sigma_deg: Option<f64>,
    /// σ of the principal point about `principal_point_px` (default: the image centre); it
    /// replaces the built-in prior (free within ±5 % of the width of the centre).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub principal_point_sigma_px: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub principal_point_px: Option<Vec<f64>>,
}

impl PriorSpec {
    fn validate(&self) -> std::result::Result<(), String> {
        let vector = |name: &str, v: &Option<Vec<f64>>, len: usize| match v {
            Some(v) if v.len() != len => Err(format!(
                "prior.{name}: needs {len} numbers, got {}",
                v.len()
            )),
            Some(v) if v.iter().any(|x| !x.is_finite()) => {
                Err(format!("prior.{name}: must be finite, got {v:?}"))
            }
            _ => Ok(()),
        };
        let sigma = |name: &str, s: Option<f64>| match s {
            Some(s) if !(s.is_finite() && s > 0.0) => {
                Err(format!("prior.{name}: must be a positive number, got {s}"))
            }
            _ => Ok(()),
        };
        vector("translation_m", &self.translation_m, 3)?;
        vector("rotation_deg", &self.rotation_deg, 3)?;
        vector("principal_point_px", &self.principal_point_px, 2)?;
        sigma("translation_sigma_m", self.translation_sigma_m)?;
        sigma("rotation_sigma_deg", self.rotation_sigma_deg)?;
        sigma("principal_point_sigma_px", self.principal_point_sigma_px)?;
        let pairs = [
            (
                "translation_m",
                self.translation_m.is_some(),
                "translation_sigma_m",
                self.translation_sigma_m.is_some(),
            ),
            (
                "rotation_deg",
                self.rotation_deg.is_some(),
                "rotation_sigma_deg",
                self.rotation_sigma_deg.is_some(),
            ),
            (
                "principal_point_px",
                self.principal_point_px.is_some(),
                "principal_point_sigma_px",
                self.principal_point_sigma_px.is_some(),
            ),
        ];
        for (value, has_value, sd, has_sd) in pairs {
            if has_value && !has_sd {
                return Err(format!("prior.{sd}: needed with prior.{value}"));
            }
            if has_sd && !has_value && value != "principal_point_px" {
                return Err(format!("prior.{value}: needed with prior.{sd}"));
            }
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rig {
    pub rgb: RgbCamera,
    pub thermal: ThermalSpec,
    pub frames: Vec<FrameSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stereo: Option<StereoSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub optimizer: Option<OptimizerOverrides>,
    /// What the user knows about the rig (optional; see [`PriorSpec`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prior: Option<PriorSpec>,
}

impl Rig {
    /// Reads and validates `rig.yaml`; frame paths are made relative to its directory.
    pub fn load(path: &Path) -> Result<Rig> {
        let text = std::fs::read_to_string(path).map_err(|e| CalibError::io(path, e))?;
        let mut rig = Self::parse(&text).map_err(|message| CalibError::Rig {
            path: path.to_path_buf(),
            message,
        })?;
        let base = path.parent().unwrap_or(Path::new(""));
        for frame in &mut rig.frames {
            frame.rgb = base.join(&frame.rgb);
            frame.thermal = base.join(&frame.thermal);
            frame.depth = frame.depth.as_ref().map(|p| base.join(p));
            frame.rgb_right = frame.rgb_right.as_ref().map(|p| base.join(p));
        }
        Ok(rig)
    }

    /// Parses and validates rig.yaml text (paths untouched); the error names the field.
    pub fn parse(text: &str) -> std::result::Result<Rig, String> {
        let rig: Rig = serde_yaml_ng::from_str(text).map_err(|e| e.to_string())?;
        rig.validate()?;
        Ok(rig)
    }

    fn validate(&self) -> std::result::Result<(), String> {
        let positive = |name: &str, value: f64| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(format!("{name}: must be a positive number, got {value}"))
            }
        };
        positive("rgb.width", self.rgb.width as f64)?;
        positive("rgb.height", self.rgb.height as f64)?;
        positive("rgb.fx", self.rgb.fx)?;
        positive("rgb.fy", self.rgb.fy)?;
        if !self.rgb.cx.is_finite() || !self.rgb.cy.is_finite() {
            return Err("rgb.cx/rgb.cy: must be finite".into());
        }
        positive("thermal.width", self.thermal.width as f64)?;
        positive("thermal.height", self.thermal.height as f64)?;
        positive("thermal.focal_length_mm", self.thermal.focal_length_mm)?;
        positive("thermal.pixel_pitch_mm", self.thermal.pixel_pitch_mm)?;
        if self.frames.is_empty() {
            return Err("frames: at least one frame is needed".into());
        }
        for (i, frame) in self.frames.iter().enumerate() {
            if frame.depth.is_none() && frame.rgb_right.is_none() {
                return Err(format!("frames[{i}]: needs `depth` or `rgb_right`"));
            }
            if frame.depth.is_none() && self.stereo.is_none() {
                return Err(format!("stereo.baseline_m: needed because frames[{i}] gives `rgb_right` without `depth`"));
            }
        }
        if let Some(stereo) = self.stereo {
            positive("stereo.baseline_m", stereo.baseline_m)?;
        }
        if let Some(opt) = self.optimizer {
            if opt.iterations == Some(0) {
                return Err("optimizer.iterations: must be at least 1".into());
            }
            if opt.batch_size == Some(0) {
                return Err("optimizer.batch_size: must be at least 1".into());
            }
            if let Some(lr) = opt.learning_rate {
                positive("optimizer.learning_rate", lr)?;
            }
        }
        if let Some(prior) = &self.prior {
            prior.validate()?;
        }
        Ok(())
    }

    /// Eq. 8: f = f_m / l, principal point at the image centre (a starting value only).
    pub fn nominal_thermal(&self) -> crate::camera::ThermalIntrinsics {
        let f = self.thermal.focal_length_mm / self.thermal.pixel_pitch_mm;
        crate::camera::ThermalIntrinsics {
            fx: f,
            fy: f,
            cx: self.thermal.width as f64 / 2.0,
            cy: self.thermal.height as f64 / 2.0,
            distortion: [1e-4; 4],
        }
    }

    /// Writes rig.yaml atomically (used by the synthetic rig generator).
    pub fn save(&self, path: &Path) -> Result<()> {
        let text = serde_yaml_ng::to_string(self).map_err(|e| CalibError::Write {
            path: path.into(),
            message: e.to_string(),
        })?;
        rtf_core::write_bytes_atomic(path, text.as_bytes()).map_err(|e| CalibError::Write {
            path: path.into(),
            message: e.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "
rgb:      { width: 640, height: 480, fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0 }
thermal:  { width: 640, height: 512, focal_length_mm: 13.0, pixel_pitch_mm: 0.017 }
frames:
  - { rgb: f/000_rgb.png, thermal: f/000_thermal.png, depth: f/000_depth.png }
  - { rgb: f/001_rgb.png, thermal: f/001_thermal.png, rgb_right: f/001_right.png }
stereo:   { baseline_m: 0.3 }
optimizer: { iterations: 2000, batch_size: 10, learning_rate: 0.01 }
";

    /// Issue 28's example, verbatim.
    const PRIOR: &str = "
prior:
  translation_m: [0.12, -0.02, 0.03]   # thermal camera centre in the RGB frame, as measured
  translation_sigma_m: 0.02
  rotation_deg: [0.0, 0.0, 0.0]        # rotation vector RGB→thermal, degrees
  rotation_sigma_deg: 2.0
  principal_point_sigma_px: 10         # about the image centre (or the datasheet's point)
";

    #[test]
    fn parses_the_prior_in_the_issues_form() {
        let rig = Rig::parse(&format!("{GOOD}{PRIOR}")).unwrap();
        let p = rig.prior.expect("prior");
        assert_eq!(p.translation_m, Some(vec![0.12, -0.02, 0.03]));
        assert_eq!(p.translation_sigma_m, Some(0.02));
        assert_eq!(p.rotation_deg, Some(vec![0.0; 3]));
        assert_eq!(p.rotation_sigma_deg, Some(2.0));
        assert_eq!(p.principal_point_sigma_px, Some(10.0));
        assert_eq!(p.principal_point_px, None);
        assert!(Rig::parse(GOOD).unwrap().prior.is_none());
    }

    #[test]
    fn parses_issue_example_with_paths_relative_to_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rig.yaml");
        std::fs::write(&path, GOOD).unwrap();
        let rig = Rig::load(&path).unwrap();
        assert_eq!(rig.frames.len(), 2);
        assert_eq!(
            rig.frames[0].depth.as_deref(),
            Some(dir.path().join("f/000_depth.png").as_path())
        );
        assert_eq!(
            rig.frames[1].rgb_right.as_deref(),
            Some(dir.path().join("f/001_right.png").as_path())
        );
        assert_eq!(rig.optimizer.unwrap().iterations, Some(2000));
        let k = rig.nominal_thermal();
        assert!((k.fx - 13.0 / 0.017).abs() < 1e-9 && k.cx == 320.0 && k.cy == 256.0);
    }

    #[test]
    fn malformed_fields_are_named() {
        let cases = [
            (GOOD.replace("fx: 500.0,", "fx: fast,"), "fx"),
            (
                GOOD.replace("focal_length_mm: 13.0", "focal_length_mm: -13.0"),
                "thermal.focal_length_mm",
            ),
            (GOOD.replace(", depth: f/000_depth.png", ""), "frames[0]"),
            (
                GOOD.replace("stereo:   { baseline_m: 0.3 }", ""),
                "stereo.baseline_m",
            ),
            (GOOD.replace("thermal: f/000_thermal.png, ", ""), "thermal"),
            (
                GOOD.replace("batch_size: 10", "batch_size: 0"),
                "optimizer.batch_size",
            ),
            (
                GOOD.replace("iterations: 2000", "iteration: 2000"),
                "iteration",
            ),
            (
                format!("{GOOD}{PRIOR}").replace("sigma_m: 0.02", "sigma_m: -0.02"),
                "prior.translation_sigma_m: must be a positive number",
            ),
            (
                format!("{GOOD}{PRIOR}").replace("[0.12, -0.02, 0.03]", "[0.12, -0.02]"),
                "prior.translation_m: needs 3 numbers, got 2",
            ),
            (
                format!("{GOOD}{PRIOR}").replace("  rotation_sigma_deg: 2.0\n", ""),
                "prior.rotation_sigma_deg: needed with prior.rotation_deg",
            ),
            (
                format!("{GOOD}{PRIOR}").replace("principal_point_sigma_px", "principal_sigma_px"),
                "principal_sigma_px",
            ),
        ];
        for (text, field) in cases {
            let err = Rig::parse(&text).unwrap_err();
            assert!(err.contains(field), "error `{err}` should name `{field}`");
        }
    }

    #[test]
    fn flags_override_file_override_recipe() {
        let recipe = OptimizerOverrides {
            iterations: Some(8000),
            batch_size: Some(10),
            learning_rate: Some(0.5),
        };
        let file = OptimizerOverrides {
            iterations: Some(100),
            batch_size: Some(4),
            learning_rate: None,
        };
        let flags = OptimizerOverrides {
            iterations: Some(7),
            ..Default::default()
        };
        let s = flags.or(file).or(recipe);
        assert_eq!(
            (s.iterations, s.batch_size, s.learning_rate),
            (Some(7), Some(4), Some(0.5))
        );
    }
}
