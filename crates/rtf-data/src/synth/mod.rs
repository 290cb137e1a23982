//! Synthetic RGB-thermal street scenes written in the real dataset layouts.
//!
//! Each frame is an independent 3-D scene ([`scene::Scene`]) rendered by a pinhole camera:
//! RGB through a camera model (day: sun and sky; night: street lamps, low exposure, high gain
//! noise, blooming headlights), thermal from per-material temperature and emissivity with its
//! own blur and noise. Frame `i` depends only on (seed, i), so generation is parallel and
//! deterministic.

mod freiburg;
pub mod noise;
mod plain;
pub mod scene;

use crate::augment::{gaussian, Planar};
use crate::loader::mix;
use crate::pngio::write_png_u8;
use crate::DataError;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use scene::{box_blur, Scene, Sem};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SynthFormat {
    /// MF layout (spec §1): RGBA PNG with thermal in alpha, 9 classes.
    Mf,
    /// Freiburg Thermal layout (spec §5): 8-bit RGB, 16-bit IR, 13 classes.
    Freiburg,
    /// The plain layout (dataset.yaml): 8-bit RGB, 16-bit thermal, MF's 9 classes.
    Plain,
}

/// RGB–thermal misalignment, as between the MF cameras: a random shift, rotation and time
/// offset (moving objects move) per frame, each uniformly up to the given maximum.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Misalignment {
    /// Pixels at 640 px width (scaled with the image).
    pub max_shift_px: f32,
    pub max_rotation_deg: f32,
    pub max_time_offset_s: f32,
}

impl Default for Misalignment {
    fn default() -> Self {
        Self {
            max_shift_px: 4.0,
            max_rotation_deg: 1.0,
            max_time_offset_s: 0.05,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SynthConfig {
    pub count: usize,
    pub seed: u64,
    pub width: usize,
    pub height: usize,
    pub format: SynthFormat,
    pub misalignment: Option<Misalignment>,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            count: 48,
            seed: 0,
            width: 640,
            height: 480,
            format: SynthFormat::Mf,
            misalignment: None,
        }
    }
}

/// One generated frame, before it is encoded.
pub struct SynthFrame {
    pub name: String,
    pub night: bool,
    pub width: usize,
    pub height: usize,
    /// Interleaved 8-bit RGB.
    pub rgb: Vec<u8>,
    /// Apparent temperature per pixel, °C, after the thermal camera's blur and noise.
    pub temperature: Vec<f32>,
    /// Air temperature of the scene, °C (the thermal camera's gain is centred on it).
    pub ambient: f32,
    pub sem: Vec<Sem>,
}

impl SynthFrame {
    /// MF-style 8-bit thermal: the camera maps [ambient − 12 °C, ambient + 28 °C] to 0–255.
    pub fn thermal_u8(&self) -> Vec<u8> {
        let lo = self.ambient - 12.0;
        self.temperature
            .iter()
            .map(|t| (((t - lo) / 40.0).clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect()
    }

    /// Freiburg-style radiometric 16-bit counts: 64 counts per kelvin, 21800 at −10 °C, so the
    /// reference clip [21800, 25000] spans −10 … 40 °C.
    pub fn thermal_u16(&self) -> Vec<u16> {
        self.temperature
            .iter()
            .map(|t| (21800.0 + (t + 10.0) * 64.0).round().clamp(0.0, 65535.0) as u16)
            .collect()
    }

    pub fn mf_label(&self) -> Vec<u8> {
        self.sem.iter().map(|s| s.mf_id()).collect()
    }

    pub fn freiburg_label(&self) -> Vec<u8> {
        self.sem.iter().map(|s| s.freiburg_id()).collect()
    }
}

/// Frame names: 1-based index, then `D` (even indices, day) or `N` (night).
pub fn frame_name(index: usize) -> String {
    let day = index & 1 == 0;
    format!("{:05}{}", index + 1, if day { 'D' } else { 'N' })
}

/// Renders frame `index` of a dataset (day for even, night for odd indices).
pub fn render_frame(cfg: &SynthConfig, index: usize) -> SynthFrame {
    let night = index % 2 == 1;
    let mut rng = ChaCha8Rng::seed_from_u64(mix(cfg.seed, index as u64, 0x5EED));
    let scene = Scene::random(cfg.width, cfg.height, night, &mut rng);
    let mis = cfg.misalignment.map(|m| {
        // Its own stream, so switching misalignment on leaves RGB and labels unchanged.
        let mut rng = ChaCha8Rng::seed_from_u64(mix(cfg.seed, index as u64, 0x3A11));
        let scale = cfg.width as f32 / 640.0;
        (
            rng.random_range(-1.0..=1.0) * m.max_shift_px * scale,
            rng.random_range(-1.0..=1.0) * m.max_shift_px * scale,
            rng.random_range(-1.0..=1.0) * m.max_rotation_deg,
            rng.random_range(-1.0..=1.0) * m.max_time_offset_s,
        )
    });
    let planes = scene.render(0.0);
    let rgb = scene.expose_rgb(&planes.radiance, &mut rng);
    let mut temperature = match mis {
        Some((_, _, _, dt)) if dt != 0.0 => scene.render(dt).temperature,
        _ => planes.temperature,
    };
    thermal_camera(&mut temperature, cfg.width, cfg.height, &mut rng);
    if let Some((dx, dy, deg, _)) = mis {
        temperature = warp(&temperature, cfg.width, cfg.height, dx, dy, deg);
    }
    SynthFrame {
        name: frame_name(index),
        night,
        width: cfg.width,
        height: cfg.height,
        rgb,
        temperature,
        ambient: scene.ambient,
        sem: planes.sem,
    }
}

/// Thermal optics and sensor: lower resolution than RGB (blur), temporal noise (~0.1 K NETD)
/// and fixed-pattern column offsets.
fn thermal_camera(temp: &mut [f32], w: usize, h: usize, rng: &mut ChaCha8Rng) {
    let radius = (w / 400).max(1);
    box_blur(temp, w, h, radius);
    let columns: Vec<f32> = (0..w).map(|_| 0.08 * gaussian(rng)).collect();
    for (i, t) in temp.iter_mut().enumerate() {
        *t += 0.1 * gaussian(rng) + columns[i % w];
    }
}

/// Shifts and rotates a plane about its centre (bilinear, edges clamped).
fn warp(plane: &[f32], w: usize, h: usize, dx: f32, dy: f32, deg: f32) -> Vec<f32> {
    let img = Planar {
        channels: 1,
        width: w,
        height: h,
        data: plane.to_vec(),
    };
    let (s, c) = deg.to_radians().sin_cos();
    let (cx, cy) = ((w as f32 - 1.0) / 2.0, (h as f32 - 1.0) / 2.0);
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let (px, py) = (x as f32 - cx - dx, y as f32 - cy - dy);
            let sx = (c * px + s * py + cx).clamp(0.0, w as f32 - 1.0);
            let sy = (-s * px + c * py + cy).clamp(0.0, h as f32 - 1.0);
            let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (fx, fy) = (sx - x0 as f32, sy - y0 as f32);
            let p = &img.data;
            out[y * w + x] = p[y0 * w + x0] * (1.0 - fx) * (1.0 - fy)
                + p[y0 * w + x1] * fx * (1.0 - fy)
                + p[y1 * w + x0] * (1.0 - fx) * fy
                + p[y1 * w + x1] * fx * fy;
        }
    }
    out
}

/// What `generate` wrote.
#[derive(Debug, Clone, Serialize)]
pub struct SynthSummary {
    pub frames: usize,
    pub splits: Vec<(String, usize)>,
}

/// Split assignment: per daytime, 50 % train, 25 % val, 25 % test (at least one each).
fn assign_splits(count: usize) -> Result<Vec<(&'static str, Vec<usize>)>, DataError> {
    if count < 6 {
        return Err(DataError::Config(format!(
            "--count {count}: at least 6 frames are needed (train, val and test each need a day and a night frame)"
        )));
    }
    let mut train = Vec::new();
    let mut val = Vec::new();
    let mut test = Vec::new();
    for parity in [0, 1] {
        let idx: Vec<usize> = (0..count).filter(|i| i % 2 == parity).collect();
        let n = idx.len();
        let n_val = (n / 4).max(1);
        let n_test = (n / 4).max(1);
        let n_train = n - n_val - n_test;
        train.extend_from_slice(&idx[..n_train]);
        val.extend_from_slice(&idx[n_train..n_train + n_val]);
        test.extend_from_slice(&idx[n_train + n_val..]);
    }
    for v in [&mut train, &mut val, &mut test] {
        v.sort_unstable();
    }
    let test_day = test.iter().copied().filter(|i| i % 2 == 0).collect();
    let test_night = test.iter().copied().filter(|i| i % 2 == 1).collect();
    Ok(vec![
        ("train", train),
        ("val", val),
        ("test", test),
        ("test_day", test_day),
        ("test_night", test_night),
    ])
}

/// Writes a synthetic dataset to `out` (created if needed). Every file is written atomically;
/// the split files come last, so an interrupted run never looks complete.
pub fn generate(out: &Path, cfg: &SynthConfig) -> Result<SynthSummary, DataError> {
    if cfg.width < 16 || cfg.height < 16 || cfg.width > 8192 || cfg.height > 8192 {
        return Err(DataError::Config(format!(
            "size {}x{}: width and height must be 16..=8192",
            cfg.width, cfg.height
        )));
    }
    let splits = assign_splits(cfg.count)?;
    match cfg.format {
        SynthFormat::Mf => write_mf(out, cfg, &splits),
        SynthFormat::Freiburg => freiburg::write_synthetic(out, cfg, &splits),
        SynthFormat::Plain => plain::write_synthetic(out, cfg, &splits),
    }
}

fn write_mf(
    out: &Path,
    cfg: &SynthConfig,
    splits: &[(&'static str, Vec<usize>)],
) -> Result<SynthSummary, DataError> {
    for sub in ["images", "labels"] {
        let dir = out.join(sub);
        std::fs::create_dir_all(&dir).map_err(|e| DataError::io(&dir, e))?;
    }
    (0..cfg.count).into_par_iter().try_for_each(|i| {
        let f = render_frame(cfg, i);
        let thermal = f.thermal_u8();
        let mut rgba = Vec::with_capacity(4 * f.width * f.height);
        for (px, t) in f.rgb.chunks_exact(3).zip(&thermal) {
            rgba.extend_from_slice(px);
            rgba.push(*t);
        }
        write_png_u8(
            &out.join("images").join(format!("{}.png", f.name)),
            f.width,
            f.height,
            4,
            &rgba,
        )?;
        write_png_u8(
            &out.join("labels").join(format!("{}.png", f.name)),
            f.width,
            f.height,
            1,
            &f.mf_label(),
        )
    })?;
    write_split_files(out, splits)?;
    write_provenance(out, cfg)?;
    Ok(SynthSummary {
        frames: cfg.count,
        splits: splits
            .iter()
            .map(|(n, v)| (n.to_string(), v.len()))
            .collect(),
    })
}

fn write_split_files(out: &Path, splits: &[(&'static str, Vec<usize>)]) -> Result<(), DataError> {
    for (name, idx) in splits {
        let text: String = idx
            .iter()
            .map(|&i| format!("{}\n", frame_name(i)))
            .collect();
        rtf_core::write_bytes_atomic(&out.join(format!("{name}.txt")), text.as_bytes())?;
    }
    Ok(())
}

pub(crate) fn write_provenance(out: &Path, cfg: &SynthConfig) -> Result<(), DataError> {
    let json =
        serde_json::to_vec_pretty(&serde_json::json!({ "generator": "rtf synth", "config": cfg }))
            .map_err(|e| DataError::Write {
                path: out.join("synth.json"),
                message: e.to_string(),
            })?;
    rtf_core::write_bytes_atomic(&out.join("synth.json"), &json)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{FrameSource, MfDataset};

    fn small(count: usize, seed: u64) -> SynthConfig {
        SynthConfig {
            count,
            seed,
            width: 96,
            height: 72,
            ..SynthConfig::default()
        }
    }

    fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
        let mut out = Vec::new();
        for sub in ["", "images", "labels"] {
            for e in std::fs::read_dir(dir.join(sub)).unwrap() {
                let p = e.unwrap().path();
                if p.is_file() {
                    out.push((
                        p.strip_prefix(dir).unwrap().display().to_string(),
                        std::fs::read(&p).unwrap(),
                    ));
                }
            }
        }
        out.sort();
        out
    }

    #[test]
    fn writes_the_mf_layout_that_the_reader_accepts() {
        let dir = tempfile::tempdir().unwrap();
        let summary = generate(dir.path(), &small(16, 1)).unwrap();
        assert_eq!(summary.frames, 16);
        let ds = MfDataset::open(dir.path()).unwrap();
        assert_eq!(
            ds.split_names(),
            ["test", "test_day", "test_night", "train", "val"]
        );
        let count = |s: &str| ds.split(s).unwrap().len();
        assert_eq!((count("train"), count("val"), count("test")), (8, 4, 4));
        assert_eq!(count("test_day") + count("test_night"), count("test"));
        let test_day = ds.split("test_day").unwrap();
        assert!((0..test_day.len()).all(|i| test_day.daytime(i) == Some(rtf_core::Daytime::Day)));
        let train = ds.split("train").unwrap();
        let days = (0..train.len())
            .filter(|&i| train.daytime(i) == Some(rtf_core::Daytime::Day))
            .count();
        assert_eq!(days * 2, train.len(), "half day, half night");
        for i in 0..train.len() {
            let f = train.load(i).unwrap();
            assert_eq!((f.width, f.height), (96, 72));
        }
    }

    #[test]
    fn same_seed_writes_identical_files_and_another_seed_does_not() {
        let (a, b, c) = (
            tempfile::tempdir().unwrap(),
            tempfile::tempdir().unwrap(),
            tempfile::tempdir().unwrap(),
        );
        generate(a.path(), &small(6, 5)).unwrap();
        generate(b.path(), &small(6, 5)).unwrap();
        generate(c.path(), &small(6, 6)).unwrap();
        assert_eq!(files(a.path()), files(b.path()));
        assert_ne!(files(a.path()), files(c.path()));
    }

    #[test]
    fn misalignment_moves_thermal_only() {
        let base = SynthConfig {
            count: 6,
            seed: 3,
            width: 96,
            height: 72,
            ..SynthConfig::default()
        };
        let shifted = SynthConfig {
            misalignment: Some(Misalignment {
                max_shift_px: 20.0,
                ..Misalignment::default()
            }),
            ..base.clone()
        };
        let (a, b) = (render_frame(&base, 0), render_frame(&shifted, 0));
        assert_eq!(a.sem, b.sem, "labels follow RGB");
        assert_eq!(a.rgb, b.rgb, "RGB unchanged");
        let diff = a
            .temperature
            .iter()
            .zip(&b.temperature)
            .filter(|(x, y)| (*x - *y).abs() > 1.0)
            .count();
        assert!(
            diff > a.temperature.len() / 50,
            "thermal moved ({diff} pixels differ by > 1 K)"
        );
    }

    #[test]
    fn too_few_frames_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let err = generate(dir.path(), &small(4, 0)).unwrap_err().to_string();
        assert!(err.contains("at least 6"), "{err}");
    }

    /// Mean |inside − ring| of a class against the unlabelled pixels within `r` px of it, for
    /// RGB luminance and thermal, averaged over the frames where the class appears.
    fn contrast(frames: &[crate::Frame], class: u8, r: usize) -> (f64, f64, usize) {
        let (mut rgb_sum, mut t_sum, mut count) = (0.0, 0.0, 0);
        for f in frames {
            let (w, h) = (f.width, f.height);
            let label = f.label.as_ref().unwrap();
            let inside: Vec<bool> = label.iter().map(|&l| l == class).collect();
            if inside.iter().filter(|&&v| v).count() < 20 {
                continue;
            }
            // Box dilation of the class mask.
            let mut near = vec![false; w * h];
            for y in 0..h {
                for x in 0..w {
                    if inside[y * w + x] {
                        for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                            for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                                near[yy * w + xx] = true;
                            }
                        }
                    }
                }
            }
            let lum = |i: usize| {
                (f.rgb[3 * i] as f64 + f.rgb[3 * i + 1] as f64 + f.rgb[3 * i + 2] as f64) / 765.0
            };
            let mean = |sel: &dyn Fn(usize) -> bool, v: &dyn Fn(usize) -> f64| {
                let (s, n) = (0..w * h)
                    .filter(|&i| sel(i))
                    .fold((0.0, 0usize), |(s, n), i| (s + v(i), n + 1));
                (n > 0).then(|| s / n as f64)
            };
            let is_in = |i: usize| inside[i];
            let is_ring = |i: usize| near[i] && !inside[i] && label[i] == 0;
            let thermal = |i: usize| f.thermal[i] as f64;
            if let (Some(a), Some(b), Some(c), Some(d)) = (
                mean(&is_in, &lum),
                mean(&is_ring, &lum),
                mean(&is_in, &thermal),
                mean(&is_ring, &thermal),
            ) {
                rgb_sum += (a - b).abs();
                t_sum += (c - d).abs();
                count += 1;
            }
        }
        (
            rgb_sum / count.max(1) as f64,
            t_sum / count.max(1) as f64,
            count,
        )
    }

    #[test]
    fn the_papers_effects_are_in_the_data_itself() {
        let dir = tempfile::tempdir().unwrap();
        generate(
            dir.path(),
            &SynthConfig {
                count: 64,
                seed: 9,
                width: 160,
                height: 120,
                ..SynthConfig::default()
            },
        )
        .unwrap();
        let ds = MfDataset::open(dir.path()).unwrap();
        let load = |split: &str| {
            let s = ds.split(split).unwrap();
            (0..s.len()).map(|i| s.load(i).unwrap()).collect::<Vec<_>>()
        };
        let all = [load("train"), load("val"), load("test")].concat();
        let (day, night): (Vec<_>, Vec<_>) = all
            .into_iter()
            .partition(|f| f.daytime == Some(rtf_core::Daytime::Day));
        let (person_rgb_day, person_t_day, n_day) = contrast(&day, 2, 3);
        let (person_rgb_night, person_t_night, n_night) = contrast(&night, 2, 3);
        assert!(
            n_day >= 10 && n_night >= 10,
            "people in {n_day} day / {n_night} night frames"
        );
        let (cone_rgb_day, cone_t_day, n_cone) = contrast(&day, 7, 2);
        eprintln!(
            "person contrast RGB day {person_rgb_day:.3} night {person_rgb_night:.3}; thermal day {person_t_day:.3} night {person_t_night:.3}; cone (day, {n_cone} frames) RGB {cone_rgb_day:.3} thermal {cone_t_day:.3}"
        );
        // Night RGB hides people; thermal shows them about equally well by day and night.
        assert!(
            person_rgb_night < 0.5 * person_rgb_day,
            "RGB person contrast day {person_rgb_day:.3} night {person_rgb_night:.3}"
        );
        let ratio = person_t_night / person_t_day;
        assert!(
            person_t_day > 0.04 && (0.5..1.75).contains(&ratio),
            "thermal person contrast day {person_t_day:.3} night {person_t_night:.3}"
        );
        // Painted cones: obvious in daylight RGB, invisible in thermal.
        assert!(n_cone >= 2, "cones in {n_cone} day frames");
        assert!(
            cone_rgb_day > 0.1 && cone_t_day < 0.25 * person_t_day,
            "cone contrast RGB {cone_rgb_day:.3} thermal {cone_t_day:.3}"
        );
        // Night frames are dark overall and noisier.
        let mean_lum = |fs: &[crate::Frame]| {
            fs.iter()
                .map(|f| f.rgb.iter().map(|&v| v as f64).sum::<f64>() / f.rgb.len() as f64)
                .sum::<f64>()
                / fs.len() as f64
        };
        assert!(
            mean_lum(&night) < 0.4 * mean_lum(&day),
            "mean brightness day {:.1} night {:.1}",
            mean_lum(&day),
            mean_lum(&night)
        );
    }
}
