//! Camera models and conventions (spec §6): pixel centres at integer coordinates, pinhole RGB
//! camera, thermal camera with distortion (k1, k2, p1, p2), X_T = R·X_RGB + t.

use crate::se3::{Rigid, Vec3};
use serde::{Deserialize, Serialize};

/// Intrinsics of the rectified, undistorted RGB camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RgbCamera {
    pub width: usize,
    pub height: usize,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl RgbCamera {
    /// The generated rigs' RGB camera (synthetic and real-imagery): a focal length of 500 px
    /// at 640 px width, scaled with the width, and the principal point at the centre.
    pub fn of_generated_rig(width: usize, height: usize) -> Self {
        let scale = width as f64 / 640.0;
        Self {
            width,
            height,
            fx: 500.0 * scale,
            fy: 500.0 * scale,
            cx: (width as f64 - 1.0) / 2.0,
            cy: (height as f64 - 1.0) / 2.0,
        }
    }

    /// X = D·K⁻¹·[u, v, 1]ᵀ.
    pub fn back_project(&self, u: f64, v: f64, depth: f64) -> Vec3 {
        [
            (u - self.cx) / self.fx * depth,
            (v - self.cy) / self.fy * depth,
            depth,
        ]
    }
}

/// Thermal intrinsics and distortion (the sought parameters besides the extrinsic).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThermalIntrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// k1, k2, p1, p2.
    pub distortion: [f64; 4],
}

impl ThermalIntrinsics {
    /// Applies the distortion model to normalised coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2] = self.distortion;
        let r2 = x * x + y * y;
        let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Inverse of [`distort`](Self::distort) by Newton iterations (numeric Jacobian).
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..30 {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.abs() < 1e-14 && ey.abs() < 1e-14 {
                break;
            }
            let h = 1e-7;
            let (ax, ay) = self.distort(x + h, y);
            let (bx, by) = self.distort(x, y + h);
            let (j11, j21, j12, j22) = ((ax - fx) / h, (ay - fy) / h, (bx - fx) / h, (by - fy) / h);
            let det = j11 * j22 - j12 * j21;
            if det.abs() < 1e-12 {
                break;
            }
            x -= (j22 * ex - j12 * ey) / det;
            y -= (-j21 * ex + j11 * ey) / det;
        }
        (x, y)
    }

    /// Thermal pixel of a point in thermal-camera coordinates; `None` behind the camera.
    pub fn project(&self, p: Vec3) -> Option<(f64, f64)> {
        if p[2] <= 1e-6 {
            return None;
        }
        let (xd, yd) = self.distort(p[0] / p[2], p[1] / p[2]);
        Some((self.fx * xd + self.cx, self.fy * yd + self.cy))
    }

    /// Ray direction (z = 1) in thermal-camera coordinates through a thermal pixel.
    pub fn ray(&self, u: f64, v: f64) -> Vec3 {
        let (x, y) = self.undistort((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        [x, y, 1.0]
    }
}

/// Everything calibration estimates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    pub thermal: ThermalIntrinsics,
    pub extrinsic: Rigid,
}

impl Calibration {
    /// The RGB→thermal pixel map of RGB pixel (u, v) with z-depth `depth` (metres).
    pub fn map_pixel(&self, rgb: &RgbCamera, u: f64, v: f64, depth: f64) -> Option<(f64, f64)> {
        self.thermal
            .project(self.extrinsic.apply(rgb.back_project(u, v, depth)))
    }
}

/// Mean distance (thermal pixels) between the RGB→thermal maps of two calibrations over the
/// RGB pixels with depth whose true image lies inside the thermal image. `depth` is row-major
/// metres, 0 = unknown. Returns (sum of distances, pixel count) so callers can pool frames.
pub fn pixel_map_error(
    rgb: &RgbCamera,
    depth: &[f32],
    thermal_size: (usize, usize),
    estimate: &Calibration,
    truth: &Calibration,
) -> (f64, usize) {
    let (tw, th) = (thermal_size.0 as f64, thermal_size.1 as f64);
    let mut sum = 0.0;
    let mut count = 0;
    for v in 0..rgb.height {
        for u in 0..rgb.width {
            let d = depth[v * rgb.width + u] as f64;
            if d <= 0.0 {
                continue;
            }
            let Some((tu, tv)) = truth.map_pixel(rgb, u as f64, v as f64, d) else {
                continue;
            };
            if tu < -0.5 || tv < -0.5 || tu > tw - 0.5 || tv > th - 0.5 {
                continue;
            }
            if let Some((eu, ev)) = estimate.map_pixel(rgb, u as f64, v as f64, d) {
                sum += ((eu - tu).powi(2) + (ev - tv).powi(2)).sqrt();
            } else {
                sum += tw; // behind the camera: count as a gross error
            }
            count += 1;
        }
    }
    (sum, count)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undistort_inverts_distort() {
        let k = ThermalIntrinsics {
            fx: 500.0,
            fy: 510.0,
            cx: 320.0,
            cy: 256.0,
            distortion: [-0.2, 0.05, 1e-3, -2e-3],
        };
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.5, 0.4)] {
            let (xd, yd) = k.distort(x, y);
            let (bx, by) = k.undistort(xd, yd);
            assert!(
                (bx - x).abs() < 1e-10 && (by - y).abs() < 1e-10,
                "{x},{y} -> {bx},{by}"
            );
        }
    }

    #[test]
    fn principal_ray_hits_principal_point_at_integer_centre() {
        let k = ThermalIntrinsics {
            fx: 400.0,
            fy: 400.0,
            cx: 10.0,
            cy: 7.0,
            distortion: [0.0; 4],
        };
        assert_eq!(k.project([0.0, 0.0, 3.0]), Some((10.0, 7.0)));
        let rgb = RgbCamera {
            width: 4,
            height: 3,
            fx: 400.0,
            fy: 400.0,
            cx: 10.0,
            cy: 7.0,
        };
        let calib = Calibration {
            thermal: k,
            extrinsic: Rigid::identity(),
        };
        let (u, v) = calib.map_pixel(&rgb, 2.0, 1.0, 5.0).unwrap();
        assert!((u - 2.0).abs() < 1e-12 && (v - 1.0).abs() < 1e-12);
        assert_eq!(k.project([0.0, 0.0, -1.0]), None);
    }
}
