//! `--overlay DIR`: per frame, the RGB edges over the thermal image warped into the RGB view
//! with the initial and with the final parameters (like HeatNet Fig. 5), and a heat map of the
//! final edge-feature residual.

use crate::camera::{Calibration, RgbCamera};
use crate::error::Result;
use crate::frames::Frame;
use crate::imageio::{write_rgb8, Plane};
use crate::model;
use std::path::{Path, PathBuf};
use tch::{Device, Kind, Tensor};

/// Depth used to draw pixels without depth (sky): far enough for pure rotation.
const FAR_M: f32 = 1000.0;

/// The thermal image [1, 1, H, W] warped into the RGB view (0 outside the thermal image).
pub fn warp_thermal(rgb: &RgbCamera, frame: &Frame, calib: &Calibration) -> Tensor {
    let filled = Plane::new(
        frame.depth.width,
        frame.depth.height,
        frame
            .depth
            .data
            .iter()
            .map(|&d| if d > 0.0 { d } else { FAR_M })
            .collect(),
    );
    let (points, _) = model::level_points(rgb, &filled, 1);
    let p = Tensor::from_slice(&model::from_calibration(calib).map(|x| x as f32));
    let (u, v) = model::project(&points, &p);
    let (tw, th) = (frame.thermal.width as i64, frame.thermal.height as i64);
    let grid = model::sampling_grid(&u, &v, 1, tw, th, rgb.height as i64, rgb.width as i64);
    model::plane_tensor(&frame.thermal, Device::Cpu).grid_sampler_2d(&grid, 0, 0, true)
}

fn to_vec(t: &Tensor) -> Vec<f32> {
    Vec::try_from(t.to_kind(Kind::Float).flatten(0, -1)).unwrap()
}

/// "Hot" colour map of a value in [0, 1].
fn hot(x: f32) -> [u8; 3] {
    let c = |v: f32| (v.clamp(0.0, 1.0) * 255.0) as u8;
    [c(3.0 * x), c(3.0 * x - 1.0), c(3.0 * x - 2.0)]
}

fn edges_over(warped: &[f32], rgb_edges: &[f32]) -> Vec<u8> {
    warped
        .iter()
        .zip(rgb_edges)
        .flat_map(|(&t, &e)| {
            if e > 0.5 {
                [0, 255, 0]
            } else {
                let g = (t.clamp(0.0, 1.0) * 255.0) as u8;
                [g, g, g]
            }
        })
        .collect()
}

/// Writes `<index>_<name>_{initial,final,residual}.png` for every frame; returns the paths.
pub fn write_overlays(
    dir: &Path,
    rgb: &RgbCamera,
    frames: &[Frame],
    initial: &Calibration,
    fin: &Calibration,
) -> Result<Vec<PathBuf>> {
    let _guard = tch::no_grad_guard();
    let mut written = Vec::new();
    for (i, frame) in frames.iter().enumerate() {
        let stem = Path::new(&frame.name)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let rgb_t = model::plane_tensor(&frame.rgb, Device::Cpu);
        let rgb_feat = model::edge_features(&rgb_t);
        let edges = to_vec(&rgb_feat.narrow(1, 0, 1));
        let (w, h) = (rgb.width, rgb.height);
        for (tag, calib) in [("initial", initial), ("final", fin)] {
            let warped = to_vec(&warp_thermal(rgb, frame, calib));
            let path = dir.join(format!("{i:03}_{stem}_{tag}.png"));
            write_rgb8(&path, w, h, edges_over(&warped, &edges))?;
            written.push(path);
        }
        let warped = warp_thermal(rgb, frame, fin);
        let mask = model::plane_tensor(&frame.depth, Device::Cpu)
            .gt(0.0)
            .to_kind(Kind::Float);
        let residual = ((rgb_feat - model::edge_features(&warped)) * &mask)
            .square()
            .sum_dim_intlist(&[1i64][..], true, Kind::Float)
            .sqrt();
        let residual = model::gaussian_blur(&residual, 1.0, 7);
        let values = to_vec(&residual);
        let peak = values.iter().copied().fold(1e-6f32, f32::max);
        let path = dir.join(format!("{i:03}_{stem}_residual.png"));
        write_rgb8(
            &path,
            w,
            h,
            values.iter().flat_map(|&v| hot(v / peak)).collect(),
        )?;
        written.push(path);
    }
    Ok(written)
}
