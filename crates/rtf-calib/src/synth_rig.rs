//! Synthetic calibration rig with ground truth. Each frame is a random street scene of
//! axis-aligned boxes on a ground plane, ray-traced (2×2 supersampled) into the RGB camera, a
//! right stereo camera and a thermal camera with known intrinsics, distortion and extrinsic.
//! Materials differ between the bands: painted road lines and face shading exist only in RGB,
//! warm bodies and heated ground patches stand out only in thermal, window contrast differs.

use crate::calibfile::CalibFile;
use crate::camera::{Calibration, RgbCamera, ThermalIntrinsics};
use crate::error::Result;
use crate::imageio::{write_gray16, write_gray8, write_rgb8};
use crate::rig::{FrameSpec, Rig, StereoSpec, ThermalSpec};
use crate::se3::{Rigid, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Where the rig's depth comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthSource {
    /// Frames list `depth` (16-bit PNG, mm).
    Given,
    /// Frames list only `rgb_right` (depth from the stereo matcher).
    Stereo,
    /// Frames list both (depth wins).
    Both,
}

#[derive(Debug, Clone, PartialEq)]
pub struct RigSynthConfig {
    pub seed: u64,
    /// RGB width; everything (thermal size, focal lengths) scales with width / 640.
    pub width: usize,
    pub height: usize,
    pub frames: usize,
    pub depth: DepthSource,
    /// 16-bit thermal PNGs (else 8-bit).
    pub thermal_16bit: bool,
    pub baseline_m: f64,
}

impl Default for RigSynthConfig {
    fn default() -> Self {
        Self {
            seed: 0,
            width: 640,
            height: 480,
            frames: 12,
            depth: DepthSource::Both,
            thermal_16bit: true,
            baseline_m: 0.3,
        }
    }
}

/// What [`write_rig`] wrote.
#[derive(Debug, Clone)]
pub struct SynthRig {
    pub rig_path: PathBuf,
    /// A rig listing the rendered depth of every frame (= `rig_path` unless stereo-only), for
    /// evaluating a calibration against the truth.
    pub eval_rig_path: PathBuf,
    pub ground_truth_path: PathBuf,
    /// The rig as loaded from `rig_path` (frame paths resolved).
    pub rig: Rig,
    pub truth: Calibration,
}

/// Nominal thermal camera of the synthetic rig at this RGB width.
pub fn thermal_spec(width: usize) -> ThermalSpec {
    let scale = width as f64 / 640.0;
    ThermalSpec {
        width,
        height: (512.0 * scale).round() as usize,
        focal_length_mm: 9.0,
        pixel_pitch_mm: 0.017 / scale,
        // The synthetic truth draws fy = fx·(1 ± 1 %): this rig says its pixels are not square.
        square_pixels: Some(false),
    }
}

/// Draws a realistic ground truth: f ±4 %, c ±3 %, barrel distortion, up to 3° rotation, a
/// few cm of offset.
pub fn draw_truth(rng: &mut ChaCha8Rng, spec: &ThermalSpec) -> Calibration {
    let f = spec.focal_length_mm / spec.pixel_pitch_mm;
    let fx = f * (1.0 + rng.random_range(-0.04..0.04));
    let fy = fx * (1.0 + rng.random_range(-0.01..0.01));
    let cx = spec.width as f64 / 2.0 * (1.0 + rng.random_range(-0.03..0.03));
    let cy = spec.height as f64 / 2.0 * (1.0 + rng.random_range(-0.03..0.03));
    let distortion = [
        rng.random_range(-0.20..-0.05),
        rng.random_range(-0.02..0.05),
        rng.random_range(-1e-3..1e-3),
        rng.random_range(-1e-3..1e-3),
    ];
    let mut axis: Vec3 = [
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
    ];
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
        .sqrt()
        .max(1e-9);
    let angle = rng.random_range(0.5f64..3.0).to_radians();
    axis = axis.map(|a| a / n * angle);
    let rotation = Rigid::exp([0.0, 0.0, 0.0, axis[0], axis[1], axis[2]]).rotation;
    let translation = [
        rng.random_range(-0.06..0.06),
        rng.random_range(-0.04..0.04),
        rng.random_range(-0.02..0.02),
    ];
    Calibration {
        thermal: ThermalIntrinsics {
            fx,
            fy,
            cx,
            cy,
            distortion,
        },
        extrinsic: Rigid {
            rotation,
            translation,
        },
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    Building,
    Car,
    Person,
    Pole,
    Clutter,
}

#[derive(Debug, Clone, Copy)]
struct Block {
    min: Vec3,
    max: Vec3,
    kind: Kind,
    rgb: [f32; 3],
    heat: f32,
    seed: u32,
}

/// One random scene (RGB-camera coordinates: x right, y down, z forward).
struct Scene {
    ground_y: f64,
    blocks: Vec<Block>,
    seed: u32,
}

/// A block before it is placed on the ground: its kind, centre x, near z, size and heat.
struct Spec {
    kind: Kind,
    x: f64,
    z: f64,
    size: Vec3,
    heat: f32,
}

// Every function below draws from the generator in a fixed order that recorded rigs depend
// on: the order of the draws must not change.
impl Spec {
    /// The far facade closing the street (sky above it has no depth).
    fn far_facade(rng: &mut ChaCha8Rng) -> Spec {
        let size = [200.0, rng.random_range(10.0..16.0), 5.0];
        let heat = rng.random_range(0.35..0.5);
        Spec {
            kind: Kind::Building,
            x: 0.0,
            z: 60.0,
            size,
            heat,
        }
    }

    /// A building on either side of the street.
    fn building(rng: &mut ChaCha8Rng) -> Spec {
        let z = rng.random_range(12.0..40.0);
        let side = if rng.random_bool(0.5) { -1.0 } else { 1.0 };
        let x = side * rng.random_range(6.0..14.0);
        let size = [
            rng.random_range(5.0..10.0),
            rng.random_range(5.0..18.0),
            rng.random_range(6.0..12.0),
        ];
        let heat = rng.random_range(0.35..0.55);
        Spec {
            kind: Kind::Building,
            x,
            z,
            size,
            heat,
        }
    }

    /// An object of a fixed size at a random depth in `depth` and a lateral position within
    /// `spread` of the depth (the field of view), with a random heat in `heat` or a fixed one.
    fn street_object(
        rng: &mut ChaCha8Rng,
        kind: Kind,
        depth: std::ops::Range<f64>,
        spread: f64,
        size: Vec3,
        heat: HeatDraw,
    ) -> Spec {
        let z = rng.random_range(depth);
        let x = rng.random_range(-spread * z..spread * z);
        let heat = match heat {
            HeatDraw::Fixed(h) => h,
            HeatDraw::Between(lo, hi) => rng.random_range(lo..hi),
        };
        Spec {
            kind,
            x,
            z,
            size,
            heat,
        }
    }

    /// Clutter near the camera (boxes, bins): random size.
    fn clutter(rng: &mut ChaCha8Rng) -> Spec {
        let z = rng.random_range(2.5..5.0);
        let size = [rng.random_range(0.5..1.2), rng.random_range(0.8..1.4), 0.6];
        let x = rng.random_range(-0.4 * z..0.4 * z);
        let heat = rng.random_range(0.4..0.7);
        Spec {
            kind: Kind::Clutter,
            x,
            z,
            size,
            heat,
        }
    }

    /// The block standing on the ground at `ground_y`, with a random colour and texture seed.
    fn place(self, ground_y: f64, rng: &mut ChaCha8Rng) -> Block {
        let Spec {
            kind,
            x,
            z,
            size,
            heat,
        } = self;
        Block {
            min: [x - size[0] / 2.0, ground_y - size[1], z],
            max: [x + size[0] / 2.0, ground_y, z + size[2]],
            kind,
            rgb: [
                rng.random_range(0.1f32..0.9),
                rng.random_range(0.1f32..0.9),
                rng.random_range(0.1f32..0.9),
            ],
            heat,
            seed: rng.random(),
        }
    }
}

/// A block's heat: fixed (people are at body temperature) or drawn from a range.
#[derive(Clone, Copy)]
enum HeatDraw {
    Fixed(f32),
    Between(f32, f32),
}

impl Scene {
    fn random(rng: &mut ChaCha8Rng) -> Scene {
        let ground_y = rng.random_range(1.3..1.7);
        let mut specs = vec![Spec::far_facade(rng)];
        for _ in 0..rng.random_range(4..7) {
            specs.push(Spec::building(rng));
        }
        let car = HeatDraw::Between(0.55, 0.75);
        for _ in 0..rng.random_range(2..5) {
            specs.push(Spec::street_object(
                rng,
                Kind::Car,
                5.0..20.0,
                0.45,
                [1.8, 1.5, 4.2],
                car,
            ));
        }
        for _ in 0..rng.random_range(1..4) {
            let person = HeatDraw::Fixed(0.95);
            let size = [0.5, 1.75, 0.4];
            specs.push(Spec::street_object(
                rng,
                Kind::Person,
                3.0..14.0,
                0.4,
                size,
                person,
            ));
        }
        for _ in 0..rng.random_range(1..4) {
            let pole = HeatDraw::Between(0.3, 0.5);
            let size = [0.15, 5.0, 0.15];
            specs.push(Spec::street_object(
                rng,
                Kind::Pole,
                4.0..25.0,
                0.45,
                size,
                pole,
            ));
        }
        for _ in 0..rng.random_range(1..3) {
            specs.push(Spec::clutter(rng));
        }
        let blocks = specs
            .into_iter()
            .map(|spec| spec.place(ground_y, rng))
            .collect();
        Scene {
            ground_y,
            blocks,
            seed: rng.random(),
        }
    }
}

#[derive(Clone, Copy)]
enum Surface {
    Sky,
    Ground,
    Block(usize, usize), // block, face axis
}

struct Hit {
    point: Vec3,
    surface: Surface,
}

fn trace(scene: &Scene, o: Vec3, d: Vec3) -> Hit {
    let mut best = f64::INFINITY;
    let mut surface = Surface::Sky;
    if d[1] > 1e-9 {
        let s = (scene.ground_y - o[1]) / d[1];
        if s > 0.0 && o[2] + s * d[2] < 300.0 {
            best = s;
            surface = Surface::Ground;
        }
    }
    for (i, b) in scene.blocks.iter().enumerate() {
        let (mut t0, mut t1, mut axis) = (0.0f64, best, usize::MAX);
        let mut miss = false;
        for a in 0..3 {
            if d[a].abs() < 1e-12 {
                if o[a] < b.min[a] || o[a] > b.max[a] {
                    miss = true;
                    break;
                }
                continue;
            }
            let (mut n, mut f) = ((b.min[a] - o[a]) / d[a], (b.max[a] - o[a]) / d[a]);
            if n > f {
                std::mem::swap(&mut n, &mut f);
            }
            if n > t0 {
                t0 = n;
                axis = a;
            }
            t1 = t1.min(f);
            if t0 > t1 {
                miss = true;
                break;
            }
        }
        if !miss && axis != usize::MAX && t0 < best {
            best = t0;
            surface = Surface::Block(i, axis);
        }
    }
    let point = if best.is_finite() {
        [o[0] + best * d[0], o[1] + best * d[1], o[2] + best * d[2]]
    } else {
        [0.0; 3]
    };
    Hit { point, surface }
}

fn hash(x: i64, y: i64, z: i64, seed: u32) -> f32 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (z as u64).wrapping_mul(0x1656_67B1_9E37_79F9)
        ^ (seed as u64).wrapping_mul(0x27D4_EB2F_1656_67C5);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    (h & 0xFFFF) as f32 / 65535.0 * 2.0 - 1.0
}

/// Smooth 3-D value noise in [-1, 1] with unit cell size.
fn noise(p: Vec3, seed: u32) -> f32 {
    let f = p.map(|c| c.floor());
    let t = [0, 1, 2].map(|i| {
        let x = (p[i] - f[i]) as f32;
        x * x * (3.0 - 2.0 * x)
    });
    let (ix, iy, iz) = (f[0] as i64, f[1] as i64, f[2] as i64);
    let mut acc = 0.0;
    for c in 0..8 {
        let (dx, dy, dz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        let w = (if dx == 1 { t[0] } else { 1.0 - t[0] })
            * (if dy == 1 { t[1] } else { 1.0 - t[1] })
            * (if dz == 1 { t[2] } else { 1.0 - t[2] });
        acc += w * hash(ix + dx, iy + dy, iz + dz, seed);
    }
    acc
}

fn scaled(p: Vec3, s: f64) -> Vec3 {
    p.map(|c| c * s)
}

fn is_window(p: Vec3, axis: usize) -> bool {
    let horizontal = if axis == 0 { p[2] } else { p[0] };
    let (a, b) = (
        (horizontal / 2.5).rem_euclid(1.0),
        (p[1] / 3.0).rem_euclid(1.0),
    );
    (0.25..0.75).contains(&a) && (0.2..0.65).contains(&b)
}

/// Visible-band colour.
fn shade_rgb(scene: &Scene, hit: &Hit) -> [f32; 3] {
    let p = hit.point;
    match hit.surface {
        Surface::Sky => [0.55, 0.7, 0.95],
        Surface::Ground => {
            let g = 0.35
                + 0.08 * noise(scaled(p, 4.0), scene.seed)
                + 0.05 * noise(scaled(p, 0.5), scene.seed ^ 1);
            // Painted lane markings: visible only in RGB.
            let lane = (p[0].abs() - 1.8).abs() < 0.07
                || (p[0].abs() < 0.07 && (p[2] / 6.0).rem_euclid(1.0) < 0.5);
            let v = if lane { 0.9 } else { g };
            [v, v, v * 1.02]
        }
        Surface::Block(i, axis) => {
            let b = &scene.blocks[i];
            // Face shading by orientation: an RGB-only edge at box corners.
            let light = [0.75f32, 1.0, 0.9][axis];
            let tex = 1.0 + 0.12 * noise(scaled(p, 6.0), b.seed);
            let mut c = b.rgb.map(|x| (x * light * tex).clamp(0.0, 1.0));
            if b.kind == Kind::Building && is_window(p, axis) {
                c = [0.12, 0.15, 0.2];
            }
            if b.kind == Kind::Person && p[1] < b.min[1] + 0.3 {
                c = [0.8, 0.6, 0.5]; // face/hair band
            }
            c
        }
    }
}

/// Thermal band in [0, 1].
fn shade_thermal(scene: &Scene, hit: &Hit) -> f32 {
    let p = hit.point;
    match hit.surface {
        Surface::Sky => 0.05,
        Surface::Ground => {
            let base = 0.55 + 0.04 * noise(scaled(p, 0.7), scene.seed ^ 7);
            // Heated patches (sun, manholes): visible only in thermal.
            let patch = noise(scaled(p, 0.35), scene.seed ^ 9) > 0.45;
            if patch {
                base + 0.15
            } else {
                base
            }
        }
        Surface::Block(i, axis) => {
            let b = &scene.blocks[i];
            let tex = 0.03 * noise(scaled(p, 1.5), b.seed ^ 3);
            match b.kind {
                Kind::Building if is_window(p, axis) => b.heat - 0.12 + tex,
                Kind::Car if p[2] < b.min[2] + 1.2 => 0.85 + tex, // warm engine bay
                _ => b.heat + tex,
            }
        }
    }
}

/// Renders (RGB bytes, z-depth in mm) of a pinhole camera at `origin` with the RGB intrinsics.
fn render_rgb(
    scene: &Scene,
    cam: &RgbCamera,
    origin: Vec3,
    with_depth: bool,
) -> (Vec<u8>, Vec<u16>) {
    let (w, h) = (cam.width, cam.height);
    let rows: Vec<(Vec<u8>, Vec<u16>)> = (0..h)
        .into_par_iter()
        .map(|v| {
            let mut rgb = Vec::with_capacity(w * 3);
            let mut depth = Vec::with_capacity(w);
            for u in 0..w {
                let mut acc = [0.0f32; 3];
                for (du, dv) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                    let d = cam.back_project(u as f64 + du, v as f64 + dv, 1.0);
                    let c = shade_rgb(scene, &trace(scene, origin, d));
                    for k in 0..3 {
                        acc[k] += c[k] / 4.0;
                    }
                }
                rgb.extend(acc.map(|x| (x * 255.0).round().clamp(0.0, 255.0) as u8));
                if with_depth {
                    let hit = trace(scene, origin, cam.back_project(u as f64, v as f64, 1.0));
                    let z = match hit.surface {
                        Surface::Sky => 0.0,
                        _ => (hit.point[2] - origin[2]) * 1000.0,
                    };
                    depth.push(z.round().clamp(0.0, 65535.0) as u16);
                }
            }
            (rgb, depth)
        })
        .collect();
    let (mut rgb, mut depth) = (Vec::new(), Vec::new());
    for (r, d) in rows {
        rgb.extend(r);
        depth.extend(d);
    }
    (rgb, depth)
}

/// Renders the thermal image (values in [0, 1] before sensor effects) through the true camera.
fn render_thermal(scene: &Scene, spec: &ThermalSpec, truth: &Calibration) -> Vec<f32> {
    let to_rgb = truth.extrinsic.inverse();
    let origin = to_rgb.translation;
    (0..spec.height)
        .into_par_iter()
        .flat_map_iter(|v| {
            let to_rgb = &to_rgb;
            (0..spec.width).map(move |u| {
                let mut acc = 0.0;
                for (du, dv) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                    let ray = truth.thermal.ray(u as f64 + du, v as f64 + dv);
                    let d = crate::se3::mat_vec(&to_rgb.rotation, ray);
                    acc += shade_thermal(scene, &trace(scene, origin, d)) / 4.0;
                }
                acc
            })
        })
        .collect()
}

/// Sensor effects on rendered thermal values: fixed-pattern vignetting and noise drawn
/// from the frame's generator.
fn sensor_effects(heat: &[f32], spec: &ThermalSpec, frame_rng: &mut ChaCha8Rng) -> Vec<f32> {
    let (cx, cy) = (spec.width as f32 / 2.0, spec.height as f32 / 2.0);
    heat.iter()
        .enumerate()
        .map(|(k, t)| {
            let (x, y) = ((k % spec.width) as f32 - cx, (k / spec.width) as f32 - cy);
            let r2 = (x * x + y * y) / (cx * cx + cy * cy);
            t - 0.04 * r2 + 0.004 * frame_rng.random_range(-1.0f32..1.0)
        })
        .collect()
}

/// The thermal frame as a 16-bit PNG of raw-like counts (21000 + 4000·t) or an 8-bit one.
fn write_thermal(path: &Path, spec: &ThermalSpec, values: &[f32], sixteen_bit: bool) -> Result<()> {
    if sixteen_bit {
        let raw = values
            .iter()
            .map(|t| (21000.0 + 4000.0 * t).round().clamp(0.0, 65535.0) as u16)
            .collect();
        write_gray16(path, spec.width, spec.height, raw)
    } else {
        let raw = values
            .iter()
            .map(|t| (255.0 * t).round().clamp(0.0, 255.0) as u8)
            .collect();
        write_gray8(path, spec.width, spec.height, raw)
    }
}

/// The rig to evaluate against: a stereo-only rig's twin with the rendered depth listed
/// (`rig_depth.yaml`), else the rig itself.
fn save_eval_rig(out: &Path, rig: &Rig, rig_path: &Path, depth: DepthSource) -> Result<PathBuf> {
    if depth != DepthSource::Stereo {
        return Ok(rig_path.to_path_buf());
    }
    let mut with_depth = rig.clone();
    for (i, f) in with_depth.frames.iter_mut().enumerate() {
        f.depth = Some(format!("f/{i:03}_depth.png").into());
    }
    let path = out.join("rig_depth.yaml");
    with_depth.save(&path)?;
    Ok(path)
}

/// Writes `rig.yaml`, frames under `f/`, and `ground_truth.yaml` into `out`.
pub fn write_rig(out: &Path, cfg: &RigSynthConfig) -> Result<SynthRig> {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let rgb = RgbCamera::of_generated_rig(cfg.width, cfg.height);
    let spec = thermal_spec(cfg.width);
    let truth = draw_truth(&mut rng, &spec);
    let dir = out.join("f");
    std::fs::create_dir_all(&dir).map_err(|e| crate::CalibError::io(&dir, e))?;
    let frames = (0..cfg.frames)
        .map(|i| write_frame(out, cfg, i, &rgb, &spec, &truth))
        .collect::<Result<Vec<_>>>()?;
    let rig = Rig {
        rgb,
        thermal: spec,
        frames,
        stereo: Some(StereoSpec {
            baseline_m: cfg.baseline_m,
        }),
        optimizer: None,
        prior: None,
    };
    let rig_path = out.join("rig.yaml");
    rig.save(&rig_path)?;
    let eval_rig_path = save_eval_rig(out, &rig, &rig_path, cfg.depth)?;
    // Hand back the rig as a reader sees it (paths resolved against `out`).
    let rig = Rig::load(&rig_path)?;
    let ground_truth_path = out.join("ground_truth.yaml");
    CalibFile::from_calibration(&truth, None).save(&ground_truth_path)?;
    Ok(SynthRig {
        eval_rig_path,
        rig_path,
        ground_truth_path,
        rig,
        truth,
    })
}

/// Renders frame `i` (its own random scene, seeded from the rig's seed and `i`) and writes
/// its RGB, depth, right view (unless depth is given) and thermal image under `out/f/`.
fn write_frame(
    out: &Path,
    cfg: &RigSynthConfig,
    i: usize,
    rgb: &RgbCamera,
    spec: &ThermalSpec,
    truth: &Calibration,
) -> Result<FrameSpec> {
    let mut frame_rng =
        ChaCha8Rng::seed_from_u64(cfg.seed.wrapping_mul(1_000_003).wrapping_add(i as u64 + 1));
    let scene = Scene::random(&mut frame_rng);
    let (image, depth) = render_rgb(&scene, rgb, [0.0; 3], true);
    let name = |suffix: &str| format!("f/{i:03}_{suffix}.png");
    write_rgb8(&out.join(name("rgb")), rgb.width, rgb.height, image)?;
    let wants_depth = cfg.depth != DepthSource::Stereo;
    let wants_right = cfg.depth != DepthSource::Given;
    // The rendered depth is always written (stereo-only rigs list it in rig_depth.yaml
    // for evaluation only).
    write_gray16(&out.join(name("depth")), rgb.width, rgb.height, depth)?;
    if wants_right {
        let (right, _) = render_rgb(&scene, rgb, [cfg.baseline_m, 0.0, 0.0], false);
        write_rgb8(&out.join(name("right")), rgb.width, rgb.height, right)?;
    }
    let heat = render_thermal(&scene, spec, truth);
    let values = sensor_effects(&heat, spec, &mut frame_rng);
    write_thermal(&out.join(name("thermal")), spec, &values, cfg.thermal_16bit)?;
    Ok(FrameSpec {
        rgb: name("rgb").into(),
        thermal: name("thermal").into(),
        depth: wants_depth.then(|| name("depth").into()),
        rgb_right: wants_right.then(|| name("right").into()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_a_loadable_rig_with_truth_and_band_specific_edges() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = RigSynthConfig {
            width: 80,
            height: 60,
            frames: 2,
            ..Default::default()
        };
        let synth = write_rig(dir.path(), &cfg).unwrap();
        let rig = Rig::load(&synth.rig_path).unwrap();
        assert_eq!(rig.frames.len(), 2);
        let truth = CalibFile::load(&synth.ground_truth_path)
            .unwrap()
            .calibration();
        let (angle, dist) = truth.extrinsic.difference(&synth.truth.extrinsic);
        assert!(angle < 1e-9 && dist < 1e-12);
        let deg = truth.extrinsic.angle().to_degrees();
        assert!((0.5..3.0).contains(&deg), "rotation {deg}°");
        let depth = crate::imageio::read_depth(rig.frames[0].depth.as_ref().unwrap()).unwrap();
        assert!(
            depth.data.iter().any(|&d| d > 0.0) && depth.data.contains(&0.0),
            "depth and sky"
        );
        let thermal = crate::imageio::read_thermal_raw(&rig.frames[0].thermal).unwrap();
        assert_eq!((thermal.width, thermal.height), (80, 64));
        // Same seed, same rig.
        let dir2 = tempfile::tempdir().unwrap();
        write_rig(dir2.path(), &cfg).unwrap();
        assert_eq!(
            std::fs::read(dir.path().join("f/001_thermal.png")).unwrap(),
            std::fs::read(dir2.path().join("f/001_thermal.png")).unwrap()
        );
    }

    #[test]
    fn thermal_and_rgb_materials_differ() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let scene = Scene::random(&mut rng);
        let lane = Hit {
            point: [1.8, scene.ground_y, 10.0],
            surface: Surface::Ground,
        };
        let asphalt = Hit {
            point: [1.0, scene.ground_y, 10.0],
            surface: Surface::Ground,
        };
        assert!(
            shade_rgb(&scene, &lane)[0] - shade_rgb(&scene, &asphalt)[0] > 0.3,
            "lane visible in RGB"
        );
        assert!(
            (shade_thermal(&scene, &lane) - shade_thermal(&scene, &asphalt)).abs() < 0.1,
            "lane ~invisible in thermal"
        );
    }
}
