//! Loading a rig's frames: RGB as grey, thermal normalised per frame, depth given or from the
//! stereo matcher. Corrupt, mismatched or featureless frames are skipped with a warning that
//! names them; too few usable frames is an error.

use crate::error::{CalibError, Result};
use crate::imageio::{normalise_robust, read_depth, read_gray, read_thermal_raw, Plane};
use crate::rig::{FrameSpec, Rig};
use std::path::Path;

/// Fewest usable frames a calibration accepts (one view leaves depth/intrinsics ambiguous).
pub const MIN_USABLE_FRAMES: usize = 2;

#[derive(Debug, Clone)]
pub struct Frame {
    /// The RGB file, for messages and overlay names.
    pub name: String,
    pub rgb: Plane,
    /// Thermal in [0, 1] after robust normalisation.
    pub thermal: Plane,
    /// z-depth in metres, 0 = unknown.
    pub depth: Plane,
    pub depth_from_stereo: bool,
}

fn bad(path: &Path, message: impl Into<String>) -> CalibError {
    CalibError::BadFrame {
        path: path.into(),
        message: message.into(),
    }
}

/// Share of pixels with a noticeable gradient; a frame below ~0.5 % has nothing to align.
fn edge_share(p: &Plane) -> f64 {
    let mut strong = 0usize;
    for y in 0..p.height.saturating_sub(1) {
        for x in 0..p.width.saturating_sub(1) {
            let gx = p.at(x + 1, y) - p.at(x, y);
            let gy = p.at(x, y + 1) - p.at(x, y);
            if gx.abs() + gy.abs() > 0.02 {
                strong += 1;
            }
        }
    }
    strong as f64 / (p.width * p.height).max(1) as f64
}

/// Fails with an error naming `path` unless `plane` is `want` (width, height); `what` (empty
/// or ending in a space) and `other` name the two sides in the message.
fn check_size(
    path: &Path,
    plane: &Plane,
    what: &str,
    other: &str,
    want: (usize, usize),
) -> Result<()> {
    if (plane.width, plane.height) == want {
        return Ok(());
    }
    Err(bad(
        path,
        format!(
            "{what}is {}×{}, {other} {}×{}",
            plane.width, plane.height, want.0, want.1
        ),
    ))
}

fn load_one(rig: &Rig, spec: &FrameSpec) -> Result<Frame> {
    let rgb = read_gray(&spec.rgb)?;
    let rig_rgb = (rig.rgb.width, rig.rgb.height);
    check_size(&spec.rgb, &rgb, "", "rig.yaml says rgb", rig_rgb)?;
    let raw = read_thermal_raw(&spec.thermal)?;
    let rig_thermal = (rig.thermal.width, rig.thermal.height);
    check_size(
        &spec.thermal,
        &raw,
        "",
        "rig.yaml says thermal",
        rig_thermal,
    )?;
    let thermal = normalise_robust(&raw)
        .ok_or_else(|| bad(&spec.thermal, "thermal image is flat (featureless)"))?;
    let (depth, from_stereo) = frame_depth(rig, spec, &rgb)?;
    let with_depth =
        depth.data.iter().filter(|&&d| d > 0.0).count() as f64 / depth.data.len() as f64;
    if with_depth < 0.05 {
        return Err(bad(
            &spec.rgb,
            format!("only {:.1} % of pixels have depth", 100.0 * with_depth),
        ));
    }
    if edge_share(&rgb) < 0.005 {
        return Err(bad(&spec.rgb, "RGB image is featureless"));
    }
    if edge_share(&thermal) < 0.005 {
        return Err(bad(&spec.thermal, "thermal image is featureless"));
    }
    Ok(Frame {
        name: spec.rgb.display().to_string(),
        rgb,
        thermal,
        depth,
        depth_from_stereo: from_stereo,
    })
}

/// The frame's depth, read from its depth file or computed from its stereo pair, and
/// whether it came from stereo.
fn frame_depth(rig: &Rig, spec: &FrameSpec, rgb: &Plane) -> Result<(Plane, bool)> {
    let size = (rgb.width, rgb.height);
    match (&spec.depth, &spec.rgb_right) {
        (Some(path), _) => {
            let d = read_depth(path)?;
            check_size(path, &d, "depth ", "the RGB frame", size)?;
            Ok((d, false))
        }
        (None, Some(path)) => {
            let right = read_gray(path)?;
            check_size(path, &right, "right image ", "the left", size)?;
            let baseline = rig.stereo.map(|s| s.baseline_m).unwrap_or(0.0);
            let depth = crate::stereo::depth_from_stereo(
                rgb,
                &right,
                rig.rgb.fx,
                baseline,
                &Default::default(),
            );
            Ok((depth, true))
        }
        (None, None) => Err(bad(&spec.rgb, "frame has neither depth nor rgb_right")),
    }
}

/// Loads every frame of `rig`, calling `warn` for each skipped one.
pub fn load_frames(rig: &Rig, warn: &mut dyn FnMut(String)) -> Result<Vec<Frame>> {
    let mut frames = Vec::new();
    let mut skipped = Vec::new();
    for spec in &rig.frames {
        match load_one(rig, spec) {
            Ok(frame) => frames.push(frame),
            Err(err) => {
                warn(format!("skipping frame: {err}"));
                skipped.push(spec.rgb.display().to_string());
            }
        }
    }
    if frames.len() < MIN_USABLE_FRAMES {
        return Err(CalibError::TooFewFrames {
            usable: frames.len(),
            minimum: MIN_USABLE_FRAMES,
            skipped: if skipped.is_empty() {
                "none".into()
            } else {
                skipped.join(", ")
            },
        });
    }
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth_rig::{write_rig, DepthSource, RigSynthConfig};

    #[test]
    fn corrupt_mismatched_and_flat_frames_are_skipped_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let synth = write_rig(
            dir.path(),
            &RigSynthConfig {
                width: 64,
                height: 48,
                frames: 5,
                depth: DepthSource::Given,
                seed: 2,
                ..Default::default()
            },
        )
        .unwrap();
        let f = |name: &str| dir.path().join("f").join(name);
        std::fs::write(f("000_thermal.png"), b"garbage").unwrap();
        crate::imageio::write_gray16(&f("001_thermal.png"), 64, 64, vec![21000; 64 * 64]).unwrap(); // wrong size
        crate::imageio::write_gray16(&f("002_thermal.png"), 64, 51, vec![21000; 64 * 51]).unwrap(); // flat
        let mut warnings = Vec::new();
        let frames = load_frames(&Rig::load(&synth.rig_path).unwrap(), &mut |w| {
            warnings.push(w)
        })
        .unwrap();
        assert_eq!(frames.len(), 2);
        assert_eq!(warnings.len(), 3, "{warnings:?}");
        assert!(warnings[0].contains("000_thermal.png"));
        assert!(warnings[1].contains("001_thermal.png") && warnings[1].contains("64×64"));
        assert!(warnings[2].contains("002_thermal.png") && warnings[2].contains("flat"));
        // One more broken frame leaves fewer than the minimum: a clear error.
        crate::imageio::write_gray8(&f("003_rgb.png"), 64, 48, vec![128; 64 * 48]).unwrap(); // featureless
        let err = load_frames(&Rig::load(&synth.rig_path).unwrap(), &mut |_| {})
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("only 1 usable frame") && err.contains("003_rgb.png"),
            "{err}"
        );
    }
}
