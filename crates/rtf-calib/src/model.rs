//! The differentiable model: RGB pixels with depth are back-projected, moved by T = exp(ξ) into
//! the thermal camera, distorted and projected by K_T (eq. 6); the thermal image (or its edge
//! map) is sampled there with a bilinear spatial transformer (`grid_sampler_2d`,
//! align_corners = true, so pixel centres sit at integer coordinates). Losses compare image
//! gradients (eq. 5–7) under a Gaussian blur with a fixed support (the RGB pixels with depth).

use crate::camera::{Calibration, RgbCamera, ThermalIntrinsics};
use crate::imageio::Plane;
use crate::se3::Rigid;
use tch::{Device, Kind, Tensor};

/// Number of calibration parameters: fx fy cx cy k1 k2 p1 p2 v1 v2 v3 ω1 ω2 ω3.
pub const NUM_PARAMS: usize = 14;
pub const PARAM_NAMES: [&str; NUM_PARAMS] = [
    "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "v1", "v2", "v3", "w1", "w2", "w3",
];

/// Flat parameter vector ↔ [`Calibration`] (extrinsic through the exact exponential).
pub fn to_calibration(p: &[f64; NUM_PARAMS]) -> Calibration {
    Calibration {
        thermal: ThermalIntrinsics {
            fx: p[0],
            fy: p[1],
            cx: p[2],
            cy: p[3],
            distortion: [p[4], p[5], p[6], p[7]],
        },
        extrinsic: Rigid::exp([p[8], p[9], p[10], p[11], p[12], p[13]]),
    }
}

pub fn from_calibration(c: &Calibration) -> [f64; NUM_PARAMS] {
    let t = &c.thermal;
    let xi = c.extrinsic.log();
    [
        t.fx,
        t.fy,
        t.cx,
        t.cy,
        t.distortion[0],
        t.distortion[1],
        t.distortion[2],
        t.distortion[3],
        xi[0],
        xi[1],
        xi[2],
        xi[3],
        xi[4],
        xi[5],
    ]
}

/// Per-parameter scales (physical units per pixel of motion): the RMS pixel motion of the
/// RGB→thermal map per unit of each parameter, measured by finite differences at `p0` over
/// sample points `(u, v, depth)`. One optimiser unit then moves pixels by ~1 px for every
/// parameter, so a single step size fits focal lengths, distortion, angles and metres alike.
pub fn pixel_scales(
    rgb: &RgbCamera,
    p0: &[f64; NUM_PARAMS],
    samples: &[(f64, f64, f64)],
) -> [f64; NUM_PARAMS] {
    let base = to_calibration(p0);
    let mut scales = [1.0; NUM_PARAMS];
    let steps = [
        1.0, 1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3, 1e-4, 1e-4, 1e-4,
    ];
    for i in 0..NUM_PARAMS {
        let mut p = *p0;
        p[i] += steps[i];
        let moved = to_calibration(&p);
        let (mut sum, mut n) = (0.0, 0usize);
        for &(u, v, d) in samples {
            if let (Some(a), Some(b)) =
                (base.map_pixel(rgb, u, v, d), moved.map_pixel(rgb, u, v, d))
            {
                sum += (a.0 - b.0).powi(2) + (a.1 - b.1).powi(2);
                n += 1;
            }
        }
        let rms_per_unit = (sum / n.max(1) as f64).sqrt() / steps[i];
        if rms_per_unit.is_finite() && rms_per_unit > 1e-12 {
            scales[i] = 1.0 / rms_per_unit;
        }
    }
    scales
}

/// Exact exponential (R, t) of ξ = (v, ω) as differentiable tensors. The coefficients
/// A = sinθ/θ, B = (1−cosθ)/θ², C = (θ−sinθ)/θ³ are evaluated by their Taylor series in θ²
/// (exact to f32 precision for |ω| < 1 rad, smooth at ω = 0 where θ = |ω| has no gradient).
pub fn exp_se3(v: &Tensor, w: &Tensor) -> (Tensor, Tensor) {
    let t2 = w.dot(w);
    let series = |c: [f64; 5]| -> Tensor {
        let mut acc = t2.zeros_like() + c[4];
        for k in (0..4).rev() {
            acc = &acc * &t2 + c[k];
        }
        acc
    };
    let a = series([1.0, -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0, 1.0 / 362880.0]);
    let b = series([
        0.5,
        -1.0 / 24.0,
        1.0 / 720.0,
        -1.0 / 40320.0,
        1.0 / 3628800.0,
    ]);
    let c = series([
        1.0 / 6.0,
        -1.0 / 120.0,
        1.0 / 5040.0,
        -1.0 / 362880.0,
        1.0 / 39916800.0,
    ]);
    let zero = w.get(0).zeros_like();
    let k = Tensor::stack(
        &[
            &zero,
            &(-w.get(2)),
            &w.get(1),
            &w.get(2),
            &zero,
            &(-w.get(0)),
            &(-w.get(1)),
            &w.get(0),
            &zero,
        ],
        0,
    )
    .view([3, 3]);
    let k2 = k.matmul(&k);
    let eye = Tensor::eye(3, (w.kind(), w.device()));
    let r = &eye + &k * &a + &k2 * &b;
    let vm = &eye + &k * &b + &k2 * &c;
    (r, vm.matmul(v))
}

/// Thermal pixel coordinates (u, v) of points in RGB-camera coordinates `points` [B, N, 3]
/// under physical parameters `p` [14].
pub fn project(points: &Tensor, p: &Tensor) -> (Tensor, Tensor) {
    let (fx, fy, cx, cy) = (p.get(0), p.get(1), p.get(2), p.get(3));
    let (k1, k2, p1, p2) = (p.get(4), p.get(5), p.get(6), p.get(7));
    let (r, t) = exp_se3(&p.narrow(0, 8, 3), &p.narrow(0, 11, 3));
    let xt = points.matmul(&r.tr()) + t; // [B, N, 3]
    let z = xt.select(2, 2).clamp_min(1e-3);
    let x = xt.select(2, 0) / &z;
    let y = xt.select(2, 1) / &z;
    let r2 = &x * &x + &y * &y;
    let radial = 1.0 + &k1 * &r2 + &k2 * &r2 * &r2;
    let xy = &x * &y;
    let xd = &x * &radial + 2.0 * &p1 * &xy + &p2 * (&r2 + 2.0 * &x * &x);
    let yd = &y * &radial + &p1 * (&r2 + 2.0 * &y * &y) + 2.0 * &p2 * &xy;
    (fx * xd + cx, fy * yd + cy)
}

/// Separable Gaussian blur of `x` [B, C, H, W] with zero padding (the loss's support is the
/// fixed mask, so nothing outside it leaks in).
pub fn gaussian_blur(x: &Tensor, sigma: f64, taps: i64) -> Tensor {
    if taps <= 1 {
        return x.shallow_clone();
    }
    let half = taps / 2;
    let w: Vec<f32> = (-half..=half)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let sum: f32 = w.iter().sum();
    let k =
        Tensor::from_slice(&w.iter().map(|v| v / sum).collect::<Vec<_>>()).to_device(x.device());
    let (b, c, h, wd) = x.size4().unwrap();
    let flat = x.reshape([b * c, 1, h, wd]);
    let horizontal = flat.conv2d(
        &k.view([1, 1, 1, taps]),
        None::<Tensor>,
        [1, 1],
        [0, half],
        [1, 1],
        1,
    );
    let both = horizontal.conv2d(
        &k.view([1, 1, taps, 1]),
        None::<Tensor>,
        [1, 1],
        [half, 0],
        [1, 1],
        1,
    );
    both.reshape([b, c, h, wd])
}

/// Central-difference gradients (∂x, ∂y) of `x` [B, 1, H, W] → [B, 2, H, W]; the one-pixel
/// border is 0 (replicate padding).
pub fn gradients(x: &Tensor) -> Tensor {
    let padded = x.replication_pad2d([1, 1, 1, 1]);
    let (h, w) = (x.size()[2], x.size()[3]);
    let gx =
        (padded.narrow(3, 2, w).narrow(2, 1, h) - padded.narrow(3, 0, w).narrow(2, 1, h)) * 0.5;
    let gy =
        (padded.narrow(2, 2, h).narrow(3, 1, w) - padded.narrow(2, 0, h).narrow(3, 1, w)) * 0.5;
    Tensor::cat(&[gx, gy], 1)
}

/// Robust edge representation of `x` [B, 1, H, W] → [B, 3, H, W]: Sobel magnitude compressed
/// as m / (m + k) (k = twice the frame's mean magnitude, so contrast and a few strong edges do
/// not dominate) times (1, cos 2φ, sin 2φ). Doubling the angle makes it blind to edge
/// polarity, which differs between RGB and thermal (a dark object may be warm).
pub fn edge_features(x: &Tensor) -> Tensor {
    // No pre-smoothing: measured on synthetic rigs, every bit of extra blur lets edges present
    // in one band only pull on nearby shared edges (σ 0.7 → 0.3: 0.20 → 0.13 px map error).
    let g = gradients(x);
    let (gx, gy) = (g.narrow(1, 0, 1), g.narrow(1, 1, 1));
    let m2 = &gx * &gx + &gy * &gy + 1e-12;
    let m = m2.sqrt();
    let k = m.mean_dim(&[1i64, 2, 3][..], true, Kind::Float) * 2.0 + 1e-6;
    let compressed = &m / (&m + k);
    let cos2 = (&gx * &gx - &gy * &gy) / &m2;
    let sin2 = 2.0 * &gx * &gy / &m2;
    Tensor::cat(
        &[
            compressed.shallow_clone(),
            &compressed * cos2,
            &compressed * sin2,
        ],
        1,
    )
}

/// `Plane` → [1, 1, H, W] tensor.
pub fn plane_tensor(p: &Plane, device: Device) -> Tensor {
    Tensor::from_slice(&p.data)
        .view([1, 1, p.height as i64, p.width as i64])
        .to_device(device)
}

/// Block-average downsampling by `factor` (dimensions floored).
pub fn downsample(p: &Plane, factor: usize) -> Plane {
    if factor == 1 {
        return p.clone();
    }
    let (w, h) = (p.width / factor, p.height / factor);
    let mut out = Vec::with_capacity(w * h);
    let n = (factor * factor) as f32;
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for dy in 0..factor {
                for dx in 0..factor {
                    s += p.at(x * factor + dx, y * factor + dy);
                }
            }
            out.push(s / n);
        }
    }
    Plane::new(w, h, out)
}

/// Depth downsampling: the block mean where the whole block has depth, else 0 (unknown).
pub fn downsample_depth(p: &Plane, factor: usize) -> Plane {
    if factor == 1 {
        return p.clone();
    }
    let (w, h) = (p.width / factor, p.height / factor);
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut ok) = (0.0, true);
            for dy in 0..factor {
                for dx in 0..factor {
                    let d = p.at(x * factor + dx, y * factor + dy);
                    ok &= d > 0.0;
                    s += d;
                }
            }
            out.push(if ok {
                s / (factor * factor) as f32
            } else {
                0.0
            });
        }
    }
    Plane::new(w, h, out)
}

/// Back-projected points [1, H·W, 3] of a level's pixel grid (level pixel u ↔ full-resolution
/// u·f + (f−1)/2) and its mask [1, 1, H, W]; pixels without depth get a dummy point at z = 1.
pub fn level_points(rgb: &RgbCamera, depth: &Plane, factor: usize) -> (Tensor, Tensor) {
    let mut pts = Vec::with_capacity(depth.width * depth.height * 3);
    let mut mask = Vec::with_capacity(depth.width * depth.height);
    let off = (factor as f64 - 1.0) / 2.0;
    for y in 0..depth.height {
        for x in 0..depth.width {
            let d = depth.at(x, y) as f64;
            let (u, v) = (
                x as f64 * factor as f64 + off,
                y as f64 * factor as f64 + off,
            );
            let p = if d > 0.0 {
                rgb.back_project(u, v, d)
            } else {
                [0.0, 0.0, 1.0]
            };
            pts.extend(p.map(|c| c as f32));
            mask.push(if d > 0.0 { 1.0f32 } else { 0.0 });
        }
    }
    let n = (depth.width * depth.height) as i64;
    (
        Tensor::from_slice(&pts).view([1, n, 3]),
        Tensor::from_slice(&mask).view([1, 1, depth.height as i64, depth.width as i64]),
    )
}

/// Sampling grid [B, H, W, 2] for a thermal level of size (tw, th) at downsampling `factor`,
/// from full-resolution thermal pixel coordinates. align_corners = true: level pixel 0 ↔ −1,
/// level pixel (tw − 1) ↔ +1.
pub fn sampling_grid(
    u: &Tensor,
    v: &Tensor,
    factor: usize,
    tw: i64,
    th: i64,
    h: i64,
    w: i64,
) -> Tensor {
    let off = (factor as f64 - 1.0) / 2.0;
    let f = factor as f64;
    let gu = (u - off) / f * (2.0 / (tw - 1) as f64) - 1.0;
    let gv = (v - off) / f * (2.0 / (th - 1) as f64) - 1.0;
    let b = u.size()[0];
    Tensor::stack(&[gu, gv], -1).view([b, h, w, 2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tensor_exp_matches_f64_exp() {
        let xi = [0.05, -0.03, 0.02, 0.03, -0.05, 0.02];
        let v = Tensor::from_slice(&xi[..3]);
        let w = Tensor::from_slice(&xi[3..]);
        let (r, t) = exp_se3(&v, &w);
        let expect = Rigid::exp(xi);
        let r: Vec<f64> = Vec::try_from(r.flatten(0, 1)).unwrap();
        let t: Vec<f64> = Vec::try_from(t).unwrap();
        assert!(r
            .iter()
            .zip(expect.rotation.concat())
            .all(|(a, b)| (a - b).abs() < 1e-12));
        assert!(t
            .iter()
            .zip(expect.translation)
            .all(|(a, b)| (a - b).abs() < 1e-12));
    }

    #[test]
    fn tensor_projection_matches_f64_model() {
        let p = [
            530.0, 525.0, 321.0, 250.0, -0.15, 0.03, 1e-3, -5e-4, 0.04, -0.02, 0.01, 0.02, -0.03,
            0.01,
        ];
        let calib = to_calibration(&p);
        let rgb = RgbCamera {
            width: 640,
            height: 480,
            fx: 500.0,
            fy: 500.0,
            cx: 319.5,
            cy: 239.5,
        };
        let samples = [(10.0, 20.0, 3.0), (600.0, 400.0, 12.0), (320.0, 5.0, 40.0)];
        let pts: Vec<f64> = samples
            .iter()
            .flat_map(|&(u, v, d)| rgb.back_project(u, v, d))
            .collect();
        let (u, v) = project(
            &Tensor::from_slice(&pts).view([1, 3, 3]),
            &Tensor::from_slice(&p),
        );
        let (u, v): (Vec<f64>, Vec<f64>) = (
            Vec::try_from(u.flatten(0, 1)).unwrap(),
            Vec::try_from(v.flatten(0, 1)).unwrap(),
        );
        for (i, &(su, sv, d)) in samples.iter().enumerate() {
            let (eu, ev) = calib.map_pixel(&rgb, su, sv, d).unwrap();
            assert!(
                (u[i] - eu).abs() < 1e-9 && (v[i] - ev).abs() < 1e-9,
                "{} {} vs {eu} {ev}",
                u[i],
                v[i]
            );
        }
    }

    #[test]
    fn grid_sampling_puts_pixel_centres_at_integers() {
        // A 5×4 ramp image whose value is its column: sampling at u = 2.25 returns 2.25.
        let img = Tensor::arange(5, (Kind::Float, Device::Cpu))
            .view([1, 1, 1, 5])
            .expand([1, 1, 4, 5], false)
            .contiguous();
        let u = Tensor::from_slice(&[2.25f32, 0.0, 4.0]).view([1, 3]);
        let v = Tensor::from_slice(&[1.5f32, 0.0, 3.0]).view([1, 3]);
        let grid = sampling_grid(&u, &v, 1, 5, 4, 1, 3);
        let s: Vec<f32> =
            Vec::try_from(img.grid_sampler_2d(&grid, 0, 0, true).flatten(0, 3)).unwrap();
        assert!(
            (s[0] - 2.25).abs() < 1e-5 && s[1].abs() < 1e-6 && (s[2] - 4.0).abs() < 1e-5,
            "{s:?}"
        );
        // At half resolution, full-res u = 2.5 is level pixel 1 (centre of full pixels 2 and 3).
        let img2 = Tensor::arange(3, (Kind::Float, Device::Cpu))
            .view([1, 1, 1, 3])
            .expand([1, 1, 2, 3], false)
            .contiguous();
        let grid2 = sampling_grid(
            &Tensor::from_slice(&[2.5f32]).view([1, 1]),
            &Tensor::from_slice(&[0.5f32]).view([1, 1]),
            2,
            3,
            2,
            1,
            1,
        );
        let s2: Vec<f32> =
            Vec::try_from(img2.grid_sampler_2d(&grid2, 0, 0, true).flatten(0, 3)).unwrap();
        assert!((s2[0] - 1.0).abs() < 1e-5, "{s2:?}");
    }

    #[test]
    fn pixel_scales_make_unit_steps_move_one_pixel() {
        let rgb = RgbCamera {
            width: 64,
            height: 48,
            fx: 50.0,
            fy: 50.0,
            cx: 31.5,
            cy: 23.5,
        };
        let p0 = [
            53.0, 53.0, 32.0, 25.6, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4,
        ];
        let samples: Vec<_> = (0..48)
            .step_by(6)
            .flat_map(|v| (0..64).step_by(8).map(move |u| (u as f64, v as f64, 5.0)))
            .collect();
        let s = pixel_scales(&rgb, &p0, &samples);
        assert!((s[2] - 1.0).abs() < 1e-6, "cx moves every pixel by 1");
        assert!((s[12] * 53.0 - 1.0).abs() < 0.3, "pan scale {}", s[12]);
        assert!(s[13] > s[12], "roll moves pixels less than pan");
        assert!(s[8] > 0.05 && s[8] < 0.2, "v1 scale ≈ depth / f = {}", s[8]);
    }

    #[test]
    fn edge_features_ignore_polarity() {
        let a = Tensor::zeros([1, 1, 8, 8], (Kind::Float, Device::Cpu));
        let _ = a.narrow(3, 4, 4).fill_(1.0);
        let b = 1.0 - &a;
        let diff = (edge_features(&a) - edge_features(&b))
            .abs()
            .max()
            .double_value(&[]);
        assert!(diff < 1e-5, "{diff}");
        assert!(edge_features(&a).max().double_value(&[]) > 0.5);
    }
}
