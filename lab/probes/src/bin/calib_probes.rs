//! Research probes of the calibrator (issues 5 and 12): experiments that print numbers for a
//! person to read, kept runnable so that docs/src/calibration.md's measurements can be
//! repeated. They are not tests (they assert little and need `../shared/data`); the real
//! tests live beside the code in `rtf_calib`. One command per probe:
//!
//! ```sh
//! [KNOBS=..] cargo run --release -p rtf-lab --bin calib_probes -- NAME
//! ```
//!
//! with NAME one of the functions below (`--list` prints them) and the knobs each probe's
//! doc names (WIDTH, SEED, N_FRAMES, TRIALS, RTF_CALIB_DEBUG=1 for per-iteration output, ...).
//! Each probe used to be a `#[test]` in `optimize.rs` gated by its own environment
//! variable; the runner sets that variable, so the probes' bodies are unchanged.

#![allow(clippy::too_many_lines, clippy::type_complexity)]

use rtf_calib::camera::Calibration;
use rtf_calib::frames::{load_frames, Frame};
use rtf_calib::model::{self, NUM_PARAMS};
use rtf_calib::optimize::*;
use rtf_calib::real_rig::{bands_from_profile, parallax_profile};
use rtf_calib::rig::Rig;
use rtf_calib::solve::{calibrate, Outcome};
use rtf_calib::synth_rig::{DepthSource, RigSynthConfig};
use rtf_calib::synth_run::{calibrate_synthetic, SyntheticRun};
use tch::{Device, Kind, Tensor};

/// (name, the environment variable that gated it as a test, the probe).
const PROBES: &[(&str, Option<&str>, fn())] = &[
    ("bound_of_file", None, bound_of_file),
    ("explore", Some("RTF_CALIB_DEBUG"), explore),
    ("probe_pairs", Some("RTF_CALIB_PROBE_PAIRS"), probe_pairs),
    (
        "probe_registration",
        Some("RTF_CALIB_PROBE_REG"),
        probe_registration,
    ),
    (
        "probe_parallax_bands",
        Some("RTF_CALIB_PROBE_BANDS"),
        probe_parallax_bands,
    ),
    (
        "probe_residual_field",
        Some("RTF_CALIB_PROBE_FIELD"),
        probe_residual_field,
    ),
    ("probe_real", Some("RTF_CALIB_PROBE"), probe_real),
    ("probe_trial", Some("RTF_CALIB_TRIAL"), probe_trial),
    (
        "probe_frame_pulls",
        Some("RTF_CALIB_PULLS"),
        probe_frame_pulls,
    ),
    ("probe_calibrate_rig", None, probe_calibrate_rig),
    ("probe_stages", Some("RTF_CALIB_STAGES"), probe_stages),
    ("probe_restarts", Some("RTF_CALIB_RESTARTS"), probe_restarts),
    ("probe_speed", Some("RTF_CALIB_SPEED"), probe_speed),
    ("probe_bias", Some("RTF_CALIB_BIAS"), probe_bias),
];

fn main() {
    let name = std::env::args().nth(1).unwrap_or_else(|| "--list".into());
    let Some(&(_, gate, probe)) = PROBES.iter().find(|p| p.0 == name) else {
        eprintln!("usage: calib_probes NAME; probes:");
        PROBES.iter().for_each(|p| eprintln!("  {}", p.0));
        std::process::exit(if name == "--list" { 0 } else { 2 });
    };
    if let Some(gate) = gate {
        if std::env::var_os(gate).is_none() {
            std::env::set_var(gate, "1");
        }
    }
    probe();
}

fn run_rig(cfg: &RigSynthConfig, settings: &Settings) -> (f64, f64, f64, Outcome) {
    let dir = tempfile::tempdir().unwrap();
    let run = calibrate_synthetic(dir.path(), cfg, settings).unwrap();
    let SyntheticRun {
        rig,
        frames,
        synth,
        outcome: out,
        ..
    } = &run;
    if debug() {
        let used: Vec<&Frame> = frames.iter().collect();
        let scaling = Scaling::new(&rig.rgb, initial_params(rig), &used);
        let pt = model::from_calibration(&synth.truth);
        let pe = model::from_calibration(&out.calibration);
        let tt: [f64; NUM_PARAMS] =
            std::array::from_fn(|i| (pt[i] - scaling.p0[i]) / scaling.scale[i]);
        let te: [f64; NUM_PARAMS] =
            std::array::from_fn(|i| (pe[i] - scaling.p0[i]) / scaling.scale[i]);
        let all = Tensor::from_slice(&(0..used.len() as i64).collect::<Vec<_>>());
        for factor in pyramid_factors(rig.rgb.width) {
            let sigma = 1.0;
            let level = Level::build(
                &rig.rgb,
                &used,
                factor,
                settings.recipe == Recipe::Paper,
                sigma,
                7,
            );
            eprintln!(
                "level 1/{factor}: cost at truth {:.6}, at estimate {:.6}",
                cost(&level, &scaling, &tt, &all),
                cost(&level, &scaling, &te, &all)
            );
        }
        eprintln!("theta truth {tt:.2?}\ntheta est   {te:.2?}");
    }
    eprintln!("est {:?}\ntruth {:?}", out.calibration, synth.truth);
    (
        run.after_px,
        run.rotation_deg,
        run.translation_m,
        run.outcome,
    )
}

/// Development aid, run with RTF_CALIB_DEBUG=1 [WIDTH=.. SEED=.. N_FRAMES=..].
fn explore() {
    if !debug() {
        return;
    }
    tch::set_num_threads(1);
    let frames: usize = std::env::var("N_FRAMES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(6);
    let seed: u64 = std::env::var("SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let width: usize = std::env::var("WIDTH")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(160);
    let cfg = RigSynthConfig {
        width,
        height: width * 3 / 4,
        frames,
        depth: DepthSource::Given,
        seed,
        ..Default::default()
    };
    let settings = default_settings();
    let (err, _, _, out) = run_rig(&cfg, &settings);
    assert!(err.is_finite() && out.stopped.is_none());
}

/// Development probe: the scale and shift that best align MSRS's own vi/ir pairs
/// (`RTF_CALIB_PROBE_PAIRS=1`), i.e. how well the source pairs are registered.
fn probe_pairs() {
    let (Some(_), Some(data)) = (
        std::env::var_os("RTF_CALIB_PROBE_PAIRS"),
        rtf_calib::real_rig::default_data_dir(),
    ) else {
        return;
    };
    tch::set_num_threads(1);
    let (day, night) = rtf_calib::real_rig::scene_names(&data).unwrap();
    let msrs = data.join("msrs-samples");
    let mut best_scales = Vec::new();
    for name in day.iter().chain(night.iter()) {
        let vi = rtf_calib::imageio::read_gray(&msrs.join(format!("vi/{name}.png"))).unwrap();
        let ir = rtf_calib::imageio::read_gray(&msrs.join(format!("ir/{name}.png"))).unwrap();
        let (vi, ir) = (model::downsample(&vi, 2), model::downsample(&ir, 2));
        let fa = model::edge_features(&model::plane_tensor(&vi, Device::Cpu));
        let fb = model::edge_features(&model::plane_tensor(&ir, Device::Cpu));
        let fa = &fa - fa.mean_dim(&[2i64, 3][..], true, Kind::Float);
        let fb = &fb - fb.mean_dim(&[2i64, 3][..], true, Kind::Float);
        let mut best = (f64::NEG_INFINITY, 0.0, 0.0, 0.0);
        for si in -12..=12 {
            let sc = 1.0 + si as f64 * 0.005;
            for dy in -4..=4 {
                for dx in -4..=4 {
                    let (tx, ty) = (dx as f64 * 0.5 * 2.0 / 320.0, dy as f64 * 0.5 * 2.0 / 240.0);
                    let theta =
                        Tensor::from_slice(&[sc as f32, 0.0, tx as f32, 0.0, sc as f32, ty as f32])
                            .view([1, 2, 3]);
                    let grid = Tensor::affine_grid_generator(&theta, [1, 3, 240, 320], true);
                    let w = fb.grid_sampler_2d(&grid, 0, 0, true);
                    let score = (&fa * &w)
                        .narrow(2, 20, 200)
                        .narrow(3, 20, 280)
                        .sum(Kind::Double)
                        .double_value(&[]);
                    if score > best.0 {
                        best = (score, sc, dx as f64 * 0.5, dy as f64 * 0.5);
                    }
                }
            }
        }
        eprintln!(
            "PAIR {name}: scale {:.3} shift ({:.1}, {:.1}) px at 320",
            best.1, best.2, best.3
        );
        best_scales.push(best.1);
    }
    best_scales.sort_by(f64::total_cmp);
    eprintln!(
        "PAIRS median scale {:.4}",
        best_scales[best_scales.len() / 2]
    );
}

/// Development probe: re-registers MSRS's vi/ir pairs with a scale, a radial term, a
/// rotation and a shift (`RTF_CALIB_PROBE_REG=1`, full 640×480, coordinate search on the
/// centred edge-feature correlation, `REG_NCC=1` normalised by the warped thermal energy);
/// prints the `MSRS_REGISTRATION` table and each scene's distance to it.
fn probe_registration() {
    let (Some(_), Some(data)) = (
        std::env::var_os("RTF_CALIB_PROBE_REG"),
        rtf_calib::real_rig::default_data_dir(),
    ) else {
        return;
    };
    tch::set_num_threads(1);
    let (day, night) = rtf_calib::real_rig::scene_names(&data).unwrap();
    let msrs = data.join("msrs-samples");
    let factor: usize = std::env::var("REG_FACTOR")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let ncc = std::env::var_os("REG_NCC").is_some();
    let mut rows = Vec::new();
    let mut moved = Vec::new();
    for name in day.iter().chain(night.iter()) {
        let vi = rtf_calib::imageio::read_gray(&msrs.join(format!("vi/{name}.png"))).unwrap();
        let ir = rtf_calib::imageio::read_gray(&msrs.join(format!("ir/{name}.png"))).unwrap();
        let (vi, ir) = (
            model::downsample(&vi, factor),
            model::downsample(&ir, factor),
        );
        let (w, h) = (vi.width as i64, vi.height as i64);
        let fa = model::edge_features(&model::plane_tensor(&vi, Device::Cpu));
        let fb = model::edge_features(&model::plane_tensor(&ir, Device::Cpu));
        let fa = &fa - fa.mean_dim(&[2i64, 3][..], true, Kind::Float);
        let fb = &fb - fb.mean_dim(&[2i64, 3][..], true, Kind::Float);
        let (cu, cv) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
        let us = Tensor::arange(w, (Kind::Double, Device::Cpu)).view([1, w]) - cu;
        let vs = Tensor::arange(h, (Kind::Double, Device::Cpu)).view([h, 1]) - cv;
        let margin = (8 / factor) as i64;
        // p = [s, k (radial, r normalised by the half width), rot (deg), du, dv (px at 640), k2]
        let score = |p: &[f64; 6]| -> f64 {
            let (sn, cs) = p[2].to_radians().sin_cos();
            let r2 = (&us * &us + &vs * &vs) / (cu * cu);
            let g = (&r2 * p[1] + r2.square() * p[5] + 1.0) * p[0];
            let su = (&us * cs - &vs * sn) * &g + cu + p[3] / factor as f64;
            let sv = (&us * sn + &vs * cs) * &g + cv + p[4] / factor as f64;
            let grid = Tensor::stack(&[su / cu - 1.0, sv / cv - 1.0], 2)
                .unsqueeze(0)
                .to_kind(Kind::Float);
            let warped = fb
                .grid_sampler_2d(&grid, 0, 0, true)
                .narrow(2, margin, h - 2 * margin)
                .narrow(3, margin, w - 2 * margin);
            let cross = (&fa
                .narrow(2, margin, h - 2 * margin)
                .narrow(3, margin, w - 2 * margin)
                * &warped)
                .sum(Kind::Double)
                .double_value(&[]);
            // `REG_NCC=1`: normalised by the warped thermal energy, so a scale that brings
            // more (or less) thermal edge energy into the frame gains nothing by it.
            if ncc {
                cross / warped.square().sum(Kind::Double).double_value(&[]).sqrt()
            } else {
                cross
            }
        };
        let mut p = [1.027, -0.026, 0.0, 0.0, 2.0, 0.0];
        let n_par = if std::env::var_os("REG_K2").is_some() {
            6
        } else {
            5
        };
        let mut steps = [0.004, 0.004, 0.1, 1.0, 1.0, 0.004];
        let mut best = score(&p);
        for _round in 0..6 {
            for _sweep in 0..3 {
                for i in 0..n_par {
                    loop {
                        let mut improved = false;
                        for sign in [-1.0, 1.0] {
                            let mut q = p;
                            q[i] += sign * steps[i];
                            let sc = score(&q);
                            if sc > best {
                                best = sc;
                                p = q;
                                improved = true;
                                break;
                            }
                        }
                        if !improved {
                            break;
                        }
                    }
                }
            }
            steps = steps.map(|x| x / 2.0);
        }
        // Mean distance (px at 640×480) between this registration's sampling map and the
        // table's (`MSRS_REGISTRATION`) over the image less the margin.
        let map = |q: &[f64; 6]| {
            let (sn, cs) = q[2].to_radians().sin_cos();
            let r2 = (&us * &us + &vs * &vs) / (cu * cu);
            let g = (&r2 * q[1] + r2.square() * q[5] + 1.0) * q[0];
            (
                (&us * cs - &vs * sn) * &g + q[3] / factor as f64,
                (&us * sn + &vs * cs) * &g + q[4] / factor as f64,
            )
        };
        let table = rtf_calib::real_rig::MSRS_REGISTRATION
            .iter()
            .find(|r| r.0 == name.as_str())
            .map(|r| [r.1, r.2, r.4, r.5, r.6, r.3]);
        let d = table.map(|t| {
            let ((a, b), (c, e)) = (map(&p), map(&t));
            ((a - c).square() + (b - e).square())
                .sqrt()
                .narrow(0, margin, h - 2 * margin)
                .narrow(1, margin, w - 2 * margin)
                .mean(Kind::Double)
                .double_value(&[])
                * factor as f64
        });
        eprintln!(
            "    (\"{name}\", {:.4}, {:.4}, {:.4}, {:.3}, {:.2}, {:.2}), // {:.2} px from the table",
            p[0], p[1], p[5], p[2], p[3], p[4], d.unwrap_or(f64::NAN)
        );
        moved.extend(d);
        rows.push(p);
    }
    moved.sort_by(f64::total_cmp);
    if !moved.is_empty() {
        eprintln!(
            "REG distance to the table's maps: median {:.2} px, range {:.2}..{:.2} px (at 640×480)",
            moved[moved.len() / 2],
            moved[0],
            moved[moved.len() - 1]
        );
    }
    for i in 0..6 {
        let mut v: Vec<f64> = rows.iter().map(|r| r[i]).collect();
        v.sort_by(f64::total_cmp);
        eprintln!(
            "REG param {i}: median {:.4}, range {:.4}..{:.4}",
            v[v.len() / 2],
            v[0],
            v[v.len() - 1]
        );
    }
}

/// Sub-pixel offset of a peak `c` between its neighbours `m` and `p` (parabola through
/// the three; 0 where they do not make a peak).
fn parabolic_offset(m: f64, c: f64, p: f64) -> f64 {
    let den = m - 2.0 * c + p;
    if den < 0.0 {
        0.5 * (m - p) / den
    } else {
        0.0
    }
}

/// The centred edge features [3, 480, 640] of MSRS scene `name`'s RGB image and of its
/// thermal image re-registered by [`rtf_calib::real_rig::register_msrs_ir`] (`parallax`:
/// with the per-band vertical correction, else the global 2-D model only).
fn registered_features(data: &std::path::Path, name: &str, parallax: bool) -> (Tensor, Tensor) {
    let (vi, ir) =
        rtf_calib::real_rig::load_msrs_pair(&data.join("msrs-samples"), name, parallax).unwrap();
    assert_eq!((vi.width, vi.height), (640, 480), "{name}");
    let centred = |p: &rtf_calib::imageio::Plane| {
        let f = model::edge_features(&model::plane_tensor(p, Device::Cpu));
        (&f - f.mean_dim(&[2i64, 3][..], true, Kind::Float)).squeeze_dim(0)
    };
    (centred(&vi), centred(&ir))
}

/// Development probe that measures `MSRS_PARALLAX` (`RTF_CALIB_PROBE_BANDS=1 cargo test
/// --release -p rtf-calib --lib probe_parallax_bands -- --nocapture`): per scene and per
/// band of 60 rows at 640×480, the vertical shift of the registered thermal edge features
/// that best correlates (normalised) with the RGB ones over the band less a 16 px border,
/// searched over ±8 px with a parabolic sub-pixel peak; a band whose peak is weak (< 0.15)
/// or on the search border follows the scenes' common profile ([`parallax_profile`]),
/// offset like its measured neighbours ([`bands_from_profile`]). Prints the profile and the
/// table's rows.
fn probe_parallax_bands() {
    let Some(data) = probe_data("RTF_CALIB_PROBE_BANDS") else {
        return;
    };
    let (day, night) = rtf_calib::real_rig::scene_names(&data).unwrap();
    let (radius, bands, rows, border) = (8i64, 8i64, 60i64, 16i64);
    // `BANDS_MIN_PEAK=x`: another weak-peak threshold; `BANDS_PEAKS=1` prints the peaks.
    let min_peak: f64 = std::env::var("BANDS_MIN_PEAK")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0.15);
    let show_peaks = std::env::var_os("BANDS_PEAKS").is_some();
    let mut measured = Vec::new();
    for name in day.iter().chain(night.iter()) {
        let (fa, fb) = registered_features(&data, name, false);
        let mut shifts = Vec::new();
        let mut peaks = Vec::new();
        for band in 0..bands {
            // Keep every shifted band inside the image.
            let y0 = (band * rows).clamp(radius, 480 - rows - radius);
            let a = fa.narrow(1, y0, rows).narrow(2, border, 640 - 2 * border);
            let ea = a.square().sum(Kind::Double).double_value(&[]);
            let score: Vec<f64> = (-radius..=radius)
                .map(|dy| {
                    let b = fb
                        .narrow(1, y0 + dy, rows)
                        .narrow(2, border, 640 - 2 * border);
                    let eb = b.square().sum(Kind::Double).double_value(&[]);
                    (&a * &b).sum(Kind::Double).double_value(&[]) / (ea * eb).sqrt()
                })
                .collect();
            let best = (0..score.len())
                .max_by(|&i, &j| score[i].total_cmp(&score[j]))
                .unwrap();
            peaks.push(format!("{:.2}", score[best]));
            if best == 0 || best == score.len() - 1 || score[best] < min_peak {
                shifts.push(None);
                continue;
            }
            let sub = parabolic_offset(score[best - 1], score[best], score[best + 1]);
            shifts.push(Some(best as f64 - radius as f64 + sub));
        }
        measured.push((name, shifts, peaks));
    }
    let profile = parallax_profile(&measured.iter().map(|m| m.1.clone()).collect::<Vec<_>>());
    eprintln!("profile {profile:.2?}");
    for (name, shifts, peaks) in &measured {
        let cells: Vec<String> = bands_from_profile(shifts, &profile)
            .iter()
            .map(|v| format!("{v:.2}"))
            .collect();
        let peaks = if show_peaks {
            format!(" // peaks {}", peaks.join(" "))
        } else {
            String::new()
        };
        eprintln!("    (\"{name}\", [{}]),{peaks}", cells.join(", "));
    }
}

/// Development probe of the parallax hypothesis (`RTF_CALIB_PROBE_FIELD=1 cargo test
/// --release -p rtf-calib --lib probe_residual_field -- --nocapture`): what the per-scene
/// 2-D registration of `MSRS_REGISTRATION` leaves. Each registered pair at 640×480 is cut
/// into 8×6 blocks of 76×76 px; in each block the shift of the thermal edge features that
/// best correlates (normalised) with the RGB ones is searched over ±`FIELD_RADIUS` px
/// (parabolic sub-pixel peak). A per-scene residual that is random averages out over the
/// scenes; one shared by them (the parallax of street scenes' common layout) survives in
/// the mean field. The field is also fitted with a radial model, d = a·x + b·|x|²·x + t
/// (x from the centre, normalised by the half width), to tell a radial pattern apart.
/// `FIELD_SCENES=a,b,..` restricts the scenes (a trial's frames); `FIELD_GLOBAL_ONLY=1`
/// leaves out `MSRS_PARALLAX` (what the global model alone leaves).
fn probe_residual_field() {
    let Some(data) = probe_data("RTF_CALIB_PROBE_FIELD") else {
        return;
    };
    let (day, night) = rtf_calib::real_rig::scene_names(&data).unwrap();
    let only: Option<Vec<String>> = std::env::var("FIELD_SCENES")
        .ok()
        .map(|s| s.split(',').map(str::to_string).collect());
    let scenes: Vec<String> = day
        .into_iter()
        .chain(night)
        .filter(|n| only.as_ref().is_none_or(|o| o.contains(n)))
        .collect();
    let radius = env("FIELD_RADIUS", 5) as i64;
    let (bw, nx, ny) = (76i64, 8i64, 6i64);
    let (x0, y0) = ((640 - nx * bw) / 2, (480 - ny * bw) / 2);
    assert!(x0 >= radius && y0 >= radius, "FIELD_RADIUS too large");
    // Per scene, per block: the shift (u, v) and its peak, or None.
    let mut fields: Vec<Vec<Option<(f64, f64, f64)>>> = Vec::new();
    let parallax = std::env::var_os("FIELD_GLOBAL_ONLY").is_none();
    // The blocks sit inside a border wider than `radius`: every shift stays in the image.
    let (h, w) = (ny * bw, nx * bw);
    let block_sums = |t: &Tensor| -> Tensor {
        // [C, h, w] → [ny, nx]
        t.sum_dim_intlist(&[0i64][..], false, Kind::Double)
            .view([ny, bw, nx, bw])
            .sum_dim_intlist(&[1i64, 3][..], false, Kind::Double)
    };
    for name in &scenes {
        let (fa, fb) = registered_features(&data, name, parallax);
        let a = fa.narrow(1, y0, h).narrow(2, x0, w);
        let ea = block_sums(&a.square());
        let side = 2 * radius + 1;
        let mut scores = Vec::with_capacity((side * side) as usize);
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                let b = fb.narrow(1, y0 + dy, h).narrow(2, x0 + dx, w);
                let eb = block_sums(&b.square());
                scores.push(block_sums(&(&a * &b)) / (&ea * eb).sqrt());
            }
        }
        let scores = Tensor::stack(&scores, 0).view([side, side, ny, nx]);
        let mut field = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                let s = scores.select(3, i).select(2, j);
                let flat = s.view([-1]);
                let best = flat.argmax(0, false).int64_value(&[]);
                let (by, bx) = (best / side, best % side);
                let at = |y: i64, x: i64| s.double_value(&[y, x]);
                let peak = at(by, bx);
                // A peak on the search border, or a weak one, says nothing.
                if by == 0 || bx == 0 || by == side - 1 || bx == side - 1 || peak < 0.2 {
                    field.push(None);
                    continue;
                }
                let sx =
                    (bx - radius) as f64 + parabolic_offset(at(by, bx - 1), peak, at(by, bx + 1));
                let sy =
                    (by - radius) as f64 + parabolic_offset(at(by - 1, bx), peak, at(by + 1, bx));
                field.push(Some((sx, sy, peak)));
            }
        }
        let ok: Vec<_> = field.iter().flatten().collect();
        let mean = |f: fn(&&(f64, f64, f64)) -> f64| {
            ok.iter().map(f).sum::<f64>() / ok.len().max(1) as f64
        };
        eprintln!(
            "FIELD {name}: {} of {} blocks, mean shift ({:+.2}, {:+.2}) px, mean |shift| {:.2} px",
            ok.len(),
            field.len(),
            mean(|b| b.0),
            mean(|b| b.1),
            mean(|b| b.0.hypot(b.1))
        );
        fields.push(field);
    }
    // The mean field over the scenes, block by block (blocks measured in ≥ 3 scenes).
    let (cu, cv) = (319.5, 239.5);
    let mut rows = Vec::new();
    eprintln!(
        "FIELD mean over {} scenes (u, v px; n scenes):",
        scenes.len()
    );
    for j in 0..ny as usize {
        let mut line = String::new();
        for i in 0..nx as usize {
            let k = j * nx as usize + i;
            let got: Vec<(f64, f64)> = fields
                .iter()
                .filter_map(|f| f[k].map(|b| (b.0, b.1)))
                .collect();
            if got.len() < 3 {
                line.push_str("      ---       ");
                continue;
            }
            let n = got.len() as f64;
            let (mu, mv) = (
                got.iter().map(|g| g.0).sum::<f64>() / n,
                got.iter().map(|g| g.1).sum::<f64>() / n,
            );
            line.push_str(&format!("({mu:+.2},{mv:+.2};{:2}) ", got.len()));
            let half = bw as f64 / 2.0;
            let x = (x0 as f64 + half + (bw as usize * i) as f64 - cu) / cu;
            let y = (y0 as f64 + half + (bw as usize * j) as f64 - cv) / cu;
            rows.push((x, y, mu, mv, n));
        }
        eprintln!("  {line}");
    }
    // Weighted least squares for (a, b, tu, tv): du = a·x + b·r²·x + tu, dv = a·y + b·r²·y + tv.
    let mut ata = vec![vec![0.0f64; 4]; 4];
    let mut atb = vec![0.0f64; 4];
    for &(x, y, du, dv, n) in &rows {
        let r2 = x * x + y * y;
        for (row, d) in [([x, r2 * x, 1.0, 0.0], du), ([y, r2 * y, 0.0, 1.0], dv)] {
            for p in 0..4 {
                atb[p] += n * row[p] * d;
                for q in 0..4 {
                    ata[p][q] += n * row[p] * row[q];
                }
            }
        }
    }
    let sol = solve_spd(&ata, &atb).expect("enough blocks for the fit");
    let residual: f64 = rows
        .iter()
        .map(|&(x, y, du, dv, _)| {
            let r2 = x * x + y * y;
            let (pu, pv) = (
                sol[0] * x + sol[1] * r2 * x + sol[2],
                sol[0] * y + sol[1] * r2 * y + sol[3],
            );
            (du - pu).hypot(dv - pv)
        })
        .sum::<f64>()
        / rows.len() as f64;
    let magnitude: f64 = rows.iter().map(|r| r.2.hypot(r.3)).sum::<f64>() / rows.len() as f64;
    eprintln!(
        "FIELD radial fit (px; x = 1 at the left and right borders): a {:+.4}, b {:+.4}, \
         t ({:+.2}, {:+.2}); mean |mean field| {:.2} px, mean |fit residual| {:.2} px",
        sol[0], sol[1], sol[2], sol[3], magnitude, residual
    );
}

/// `RTF_CALIB_DEBUG` set: per-iteration and per-walk output on stderr (the library's
/// `Settings::debug`, and the probes' own extra lines).
fn debug() -> bool {
    std::env::var_os("RTF_CALIB_DEBUG").is_some()
}

/// The default recipe's settings (seed 0), with the library's development output when
/// [`debug`].
fn default_settings() -> Settings {
    let mut settings = Settings::resolve(Recipe::Default, Default::default(), None, 0).unwrap();
    settings.debug = debug();
    settings
}

/// A development probe's set-up: the real data folder when `gate` is set and the data is
/// there (else the probe does nothing), libtorch on one thread.
fn probe_data(gate: &str) -> Option<std::path::PathBuf> {
    std::env::var_os(gate)?;
    let data = rtf_calib::real_rig::default_data_dir()?;
    tch::set_num_threads(1);
    Some(data)
}

/// A probe's numeric setting from the environment, `default` when unset or unreadable.
fn env(key: &str, default: usize) -> usize {
    std::env::var(key)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// The `real_trials` rig of trial `seed` (thermal lens and frames as in the trial set of
/// `TRIALS`, default 20), at `WIDTH` and `N_FRAMES` or the given defaults.
fn trial_config(
    data: &std::path::Path,
    seed: u64,
    width: usize,
    frames: usize,
) -> rtf_calib::real_rig::RealRigConfig {
    rtf_calib::real_rig::RealRigConfig::new(
        data,
        seed,
        env("WIDTH", width),
        env("N_FRAMES", frames),
    )
    .in_trial_set((seed - 1) as usize, env("TRIALS", 20))
}

/// A trial-set rig written to a temporary folder (kept alive by the returned guard) and
/// its frames loaded.
fn trial_rig(
    cfg: &rtf_calib::real_rig::RealRigConfig,
) -> (tempfile::TempDir, rtf_calib::real_rig::RealRig, Vec<Frame>) {
    let dir = tempfile::tempdir().unwrap();
    let real = rtf_calib::real_rig::write_real_rig(dir.path(), cfg).unwrap();
    let frames = load_frames(&real.rig, &mut |w| eprintln!("{w}")).unwrap();
    (dir, real, frames)
}

/// Development probe on a real-imagery rig (`RTF_CALIB_PROBE=1 WIDTH=.. SEED=..
/// N_FRAMES=.. cargo test --release -p rtf-calib probe_real -- --nocapture`): the cost of
/// the truth and of the estimate at every level, and the map error.
fn probe_real() {
    let Some(data) = probe_data("RTF_CALIB_PROBE") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let cfg = rtf_calib::real_rig::RealRigConfig::new(
        &data,
        env("SEED", 1) as u64,
        env("WIDTH", 320),
        env("N_FRAMES", 10),
    );
    let mut cfg = cfg;
    cfg.degrade = match std::env::var("DEGRADE").as_deref() {
        Ok("shuffle") => rtf_calib::real_rig::Degrade::ShuffleThermal,
        Ok("textureless") => rtf_calib::real_rig::Degrade::Textureless,
        _ => rtf_calib::real_rig::Degrade::None,
    };
    let real = rtf_calib::real_rig::write_real_rig(dir.path(), &cfg).unwrap();
    let rig = &real.rig;
    let frames = load_frames(rig, &mut |w| eprintln!("{w}")).unwrap();
    let settings = default_settings();
    let t0 = std::time::Instant::now();
    let out = calibrate(rig, &frames, &settings, &mut |p| {
        if debug() {
            eprintln!(
                "{:>7.2}s {} {}/{} loss {:.6}",
                t0.elapsed().as_secs_f64(),
                p.stage,
                p.step,
                p.total,
                p.loss
            )
        }
    })
    .unwrap();
    let secs = t0.elapsed().as_secs_f64();
    let used: Vec<&Frame> = frames.iter().collect();
    let scaling = Scaling::new(&rig.rgb, initial_params(rig), &used);
    let to_theta = |c: &Calibration| -> [f64; NUM_PARAMS] {
        let p = model::from_calibration(c);
        std::array::from_fn(|i| (p[i] - scaling.p0[i]) / scaling.scale[i])
    };
    let (tt, te) = (to_theta(&real.truth), to_theta(&out.calibration));
    let all = Tensor::from_slice(&(0..used.len() as i64).collect::<Vec<_>>());
    for factor in pyramid_factors(rig.rgb.width) {
        let level = Level::build(&rig.rgb, &used, factor, false, 0.0, 1);
        eprintln!(
            "level 1/{factor}: cost at start {:.6} truth {:.6}, at estimate {:.6}",
            cost(&level, &scaling, &[0.0; NUM_PARAMS], &all),
            cost(&level, &scaling, &tt, &all),
            cost(&level, &scaling, &te, &all)
        );
    }
    eprintln!("theta truth {tt:.2?}\ntheta est   {te:.2?}");
    eprintln!("ASSESS {:?}", out.assessment);
    let before = mean_map_error(rig, &frames, &out.initial, &real.truth);
    let after = mean_map_error(rig, &frames, &out.calibration, &real.truth);
    let (deg, m) = out.calibration.extrinsic.difference(&real.truth.extrinsic);
    let (k, kt) = (out.calibration.thermal, real.truth.thermal);
    eprintln!(
        "PROBE seed {} map error {before:.2} -> {after:.3} px; rot {deg:.3}°, trans {:.1} cm; fx/fy {:.4} (truth {:.4}); f {:.1} (truth {:.1}); {secs:.1} s",
        cfg.seed, m * 100.0, k.fx / k.fy, kt.fx / kt.fy, k.fx, kt.fx
    );
}

/// Development probe of one `real_trials` rig at full size (`RTF_CALIB_TRIAL=1 SEED=1
/// TRIALS=20 WIDTH=640 N_FRAMES=20 [CONTROL=1] cargo test --release -p rtf-calib --lib
/// probe_trial -- --nocapture`): calibrates with the default recipe, then compares the
/// cost of the truth and of the estimate at the two finest levels (the pipeline's
/// subsampled level and the full one) and refines from the truth at the finest level (all
/// parameters) to see where the objective's own optimum lies. `CONTROL=1` renders the
/// "thermal" from the RGB image (no cross-modal differences, no MSRS registration error).
fn probe_trial() {
    let Some(data) = probe_data("RTF_CALIB_TRIAL") else {
        return;
    };
    let seed = env("SEED", 1) as u64;
    let mut cfg = trial_config(&data, seed, 640, 20);
    if std::env::var_os("CONTROL").is_some() {
        cfg.degrade = rtf_calib::real_rig::Degrade::RgbAsThermal;
    }
    let (_dir, real, frames) = trial_rig(&cfg);
    let rig = &real.rig;
    let settings = default_settings();
    let t0 = std::time::Instant::now();
    let out = calibrate(rig, &frames, &settings, &mut |_| {}).unwrap();
    let secs = t0.elapsed().as_secs_f64();
    let used: Vec<&Frame> = out.used.iter().map(|&i| &frames[i]).collect();
    let pipe = Pipeline::new(rig, used.clone(), initial_params(rig), &settings);
    let sc = &pipe.scaling;
    let to_theta = |c: &Calibration| sc.theta_of(c);
    let calib = |t: &[f64; NUM_PARAMS]| sc.calibration(t);
    let (tt, te) = (to_theta(&real.truth), to_theta(&out.calibration));
    let all_i: Vec<i64> = (0..used.len() as i64).collect();
    let all = Tensor::from_slice(&all_i);
    let err = |c: &Calibration| mean_map_error(rig, &frames, c, &real.truth);
    eprintln!(
        "TRIAL seed {seed} control {}: {:.2} -> {:.3} px in {secs:.1} s, f {:.2} (truth {:.2}), k1 {:.4} (truth {:.4}), verdict {:?}",
        cfg.degrade == rtf_calib::real_rig::Degrade::RgbAsThermal,
        err(&out.initial),
        err(&out.calibration),
        out.calibration.thermal.fx,
        real.truth.thermal.fx,
        out.calibration.thermal.distortion[0],
        real.truth.thermal.distortion[0],
        out.assessment.as_ref().map(|a| (a.verdict, a.split_px, a.score.sharpness))
    );
    let fine = pipe.levels.len() - 1;
    for li in [fine - 1, fine] {
        let full = Level::build(&rig.rgb, &used, pipe.factors[li], false, 0.0, 1);
        eprintln!(
            "level 1/{}: cost truth / estimate: pipeline {:.6} / {:.6}, full {:.6} / {:.6}",
            pipe.factors[li],
            cost(&pipe.levels[li], sc, &tt, &all),
            cost(&pipe.levels[li], sc, &te, &all),
            cost(&full, sc, &tt, &all),
            cost(&full, sc, &te, &all)
        );
    }
    let dirs = directions(&(0..NUM_PARAMS).collect::<Vec<_>>(), sc, pipe.square);
    let (tw, th) = (rig.thermal.width as f64, rig.thermal.height as f64);
    let variants = std::env::var("VARIANTS").unwrap_or_else(|_| "squares".into());
    for variant in variants.split(',') {
        let level = pipe.levels[fine].shallow();
        let level = match variant {
            "corr" => level.into_correlation(),
            "margin" => restrict_support(level, sc, &te, tw, th, 0.03 * tw),
            "margin-corr" => restrict_support(level, sc, &te, tw, th, 0.03 * tw).into_correlation(),
            "gain" => with_gain(level, sc, &te),
            // The finest level without the pipeline's pixel subset.
            "full" => Level::build(&rig.rgb, &used, pipe.factors[fine], false, 0.0, 1),
            _ => level,
        };
        for (name, from) in [("truth", tt), ("estimate", te)] {
            let mut priors = Priors::new(rig);
            let run = lm_level(
                &level,
                sc,
                &mut priors,
                from,
                &dirs,
                &all_i,
                40,
                pipe.lambda0,
                &mut |_| {},
            );
            let c = calib(&run.theta);
            eprintln!(
                "{variant}: refined at 1/1 from the {name} ({} iterations): {:.3} px from the truth, {:.3} px from the estimate, f {:.2}, k1 {:.4}",
                run.iterations,
                err(&c),
                mean_map_error(rig, &frames, &c, &out.calibration),
                c.thermal.fx,
                c.thermal.distortion[0],
            );
        }
    }
}

/// Development probe of where each frame of a `real_trials` rig pulls at the truth
/// (`RTF_CALIB_PULLS=1 SEED=20 [WIDTH=640 N_FRAMES=20] cargo test --release -p rtf-calib
/// --lib probe_frame_pulls -- --nocapture`): per frame, the vertex of the parabola
/// through its alignment score at the truth and at ±δ px in u and v (the quality
/// figures' level and score), i.e. the image shift that frame prefers, and its curvature.
/// A shift shared by the frames is a bias of the data or of the objective; a scatter
/// averages out. No calibration is run.
fn probe_frame_pulls() {
    let Some(data) = probe_data("RTF_CALIB_PULLS") else {
        return;
    };
    let seed = env("SEED", 20) as u64;
    let (_dir, real, frames) = trial_rig(&trial_config(&data, seed, 640, 20));
    let rig = &real.rig;
    let used: Vec<&Frame> = frames.iter().collect();
    let scaling = Scaling::new(&rig.rgb, initial_params(rig), &used);
    let theta = scaling.theta_of(&real.truth);
    let (_, level) = rtf_calib::quality::assessment_level(rig, &used);
    let delta = rtf_calib::quality::DELTA_PX;
    let s0 = rtf_calib::quality::frame_scores(&level, &scaling, &theta);
    let mut pulls = Vec::new();
    for axis in [2usize, 3] {
        let at = |s: f64| {
            let mut t = theta;
            t[axis] += s * delta;
            rtf_calib::quality::frame_scores(&level, &scaling, &t)
        };
        let (m, p) = (at(-1.0), at(1.0));
        pulls.push(
            (0..s0.len())
                .map(|f| {
                    let curv = m[f] + p[f] - 2.0 * s0[f];
                    let slope = (p[f] - m[f]) / 2.0;
                    (-slope / curv * delta, curv)
                })
                .collect::<Vec<_>>(),
        );
    }
    let mut sum = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (f, scene) in real.scenes.iter().enumerate() {
        let ((u, cu), (v, cv)) = (pulls[0][f], pulls[1][f]);
        eprintln!(
            "PULL {scene}: score {:.3}, u {u:+.2} px (curv {cu:.4}), v {v:+.2} px (curv {cv:.4})",
            s0[f]
        );
        // Curvature-weighted mean (a sharp frame counts more), peaks only.
        if cu < 0.0 && cv < 0.0 {
            sum.0 += -cu * u.clamp(-3.0, 3.0);
            sum.1 += -cv * v.clamp(-3.0, 3.0);
            sum.2 += -cu;
            sum.3 += -cv;
            sum.4 += 1.0;
        }
    }
    eprintln!(
        "PULL seed {seed}: {} of {} frames peaked; curvature-weighted mean pull u {:+.2} px, v {:+.2} px",
        sum.4,
        s0.len(),
        sum.0 / sum.2.max(1e-12),
        sum.1 / sum.3.max(1e-12)
    );
}

/// Development probe on a rig with a ground truth on disk (`RTF_CALIB_RIG=dir
/// [RTF_CALIB_PP_FREE=0.05] cargo test --release -p rtf-calib --lib probe_calibrate_rig --
/// --nocapture`, `dir` holding rig.yaml and ground_truth.yaml): the default recipe's map
/// error, rotation error and principal point against the truth's.
fn probe_calibrate_rig() {
    let Some(dir) = std::env::var_os("RTF_CALIB_RIG").map(std::path::PathBuf::from) else {
        return;
    };
    tch::set_num_threads(1);
    let rig = Rig::load(&dir.join("rig.yaml")).unwrap();
    let truth = rtf_calib::calibfile::CalibFile::load(&dir.join("ground_truth.yaml")).unwrap();
    let truth = Calibration {
        thermal: rtf_calib::camera::ThermalIntrinsics {
            fx: truth.thermal.fx,
            fy: truth.thermal.fy,
            cx: truth.thermal.cx,
            cy: truth.thermal.cy,
            distortion: truth.thermal.distortion,
        },
        extrinsic: rtf_calib::se3::Rigid {
            rotation: truth.extrinsic.rotation,
            translation: truth.extrinsic.translation,
        },
    };
    let frames = load_frames(&rig, &mut |w| eprintln!("{w}")).unwrap();
    let settings = default_settings();
    let out = calibrate(&rig, &frames, &settings, &mut |_| {}).unwrap();
    let (a, b) = (out.calibration.extrinsic.rotation, truth.extrinsic.rotation);
    let trace: f64 = (0..3)
        .flat_map(|i| (0..3).map(move |k| (i, k)))
        .map(|(i, k)| a[k][i] * b[k][i])
        .sum();
    eprintln!(
        "map error {:.4} px, rotation error {:.3} deg, c ({:.2}, {:.2}) truth ({:.2}, {:.2})",
        mean_map_error(&rig, &frames, &out.calibration, &truth),
        ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees(),
        out.calibration.thermal.cx,
        out.calibration.thermal.cy,
        truth.thermal.cx,
        truth.thermal.cy,
    );
}

/// Development probe of where the default pipeline leaves the truth's basin
/// (`RTF_CALIB_STAGES=1 SEED=6 WIDTH=640 N_FRAMES=20 cargo test --release -p rtf-calib
/// --lib probe_stages -- --nocapture`): the map error after the search and after each
/// level of a run in each [`Staging`], with the time of each level and the cost of the
/// solution and of the truth at that level; then the whole calibration.
fn probe_stages() {
    let Some(data) = probe_data("RTF_CALIB_STAGES") else {
        return;
    };
    let seed = env("SEED", 6) as u64;
    let (_dir, real, frames) = trial_rig(&trial_config(&data, seed, 640, 20));
    let rig = &real.rig;
    let settings = default_settings();
    let used: Vec<&Frame> = frames.iter().collect();
    let pipe = Pipeline::new(rig, used, initial_params(rig), &settings);
    let sc = &pipe.scaling;
    let tt = sc.theta_of(&real.truth);
    let all = Tensor::from_slice(&(0..frames.len() as i64).collect::<Vec<_>>());
    let err = |t: &[f64; NUM_PARAMS]| mean_map_error(rig, &frames, &sc.calibration(t), &real.truth);
    let show = |stage: &str, li: usize, t: &[f64; NUM_PARAMS]| {
        let c = sc.calibration(t);
        eprintln!(
            "{stage:>12}: {:.3} px, cost {:.6} (truth {:.6}), f {:.2}, c ({:.1}, {:.1}), k1 {:.4}, t ({:.3}, {:.3}, {:.3})",
            err(t),
            cost(&pipe.levels[li], sc, t, &all),
            cost(&pipe.levels[li], sc, &tt, &all),
            c.thermal.fx,
            c.thermal.cx,
            c.thermal.cy,
            c.thermal.distortion[0],
            c.extrinsic.translation[0],
            c.extrinsic.translation[1],
            c.extrinsic.translation[2],
        );
    };
    show("truth", pipe.levels.len() - 1, &tt);
    let (_, start) = pipe.search([0.0; NUM_PARAMS], 1)[0];
    show("search", 0, &start);
    let q = pipe.check_level();
    let mut early = pipe.shallow();
    early.staging = Staging::Early;
    for p in [&pipe, &early] {
        eprintln!("staging {:?}", p.staging);
        let mut theta = start;
        for li in 0..p.levels.len() {
            let t0 = std::time::Instant::now();
            theta = p.refine_between(theta, li, li, &mut |_, _| {});
            let secs = t0.elapsed().as_secs_f64();
            show(
                &format!("level 1/{} {secs:.1} s", p.factors[li]),
                li,
                &theta,
            );
            if li == q {
                eprintln!(
                    "cost at the check level {:.6}",
                    cost(&p.levels[q], sc, &theta, &all)
                );
            }
        }
    }
    let t0 = std::time::Instant::now();
    let out = calibrate(rig, &frames, &settings, &mut |_| {}).unwrap();
    eprintln!(
        "calibrate: {:.3} px in {:.1} s",
        mean_map_error(rig, &frames, &out.calibration, &real.truth),
        t0.elapsed().as_secs_f64()
    );
}

/// Development probe of wrong basins on the `real_trials` rigs (`RTF_CALIB_RESTARTS=1
/// TRIALS=20 WIDTH=160 N_FRAMES=6 SEEDS=3,12,7 cargo test --release -p rtf-calib --lib
/// probe_restarts -- --nocapture`): the main solution against restarts (from the truth,
/// the coarse search's other minima, other focal starts, perturbed solutions), with each
/// one's cost, alignment score, distance to the main solution and error.
fn probe_restarts() {
    let Some(data) = probe_data("RTF_CALIB_RESTARTS") else {
        return;
    };
    let seeds: Vec<u64> = std::env::var("SEEDS")
        .unwrap_or_else(|_| "3,12,7".into())
        .split(',')
        .map(|s| s.trim().parse().unwrap())
        .collect();
    for seed in seeds {
        let (_dir, real, frames) = trial_rig(&trial_config(&data, seed, 160, 6));
        let rig = &real.rig;
        let settings = default_settings();
        let used: Vec<&Frame> = frames.iter().collect();
        let pipe = Pipeline::new(rig, used.clone(), initial_params(rig), &settings);
        let sc = &pipe.scaling;
        let to_theta = |c: &Calibration| sc.theta_of(c);
        let calib = |t: &[f64; NUM_PARAMS]| sc.calibration(t);
        let qlevel = Level::build(&rig.rgb, &used, 1, false, 0.0, 1).into_correlation();
        let fine = pipe.levels.len() - 1;
        let all = Tensor::from_slice(&(0..used.len() as i64).collect::<Vec<_>>());
        let main = {
            let (_, s) = pipe.search([0.0; NUM_PARAMS], 1)[0];
            pipe.refine(s, 0, &mut |_, _| {}).theta
        };
        let report = |name: &str, t: &[f64; NUM_PARAMS]| {
            let c = cost(&pipe.levels[fine], sc, t, &all);
            let mut pr = Priors::new(rig);
            pr.weight = 1.0;
            let ncc = rtf_calib::quality::frame_scores(&qlevel, sc, t);
            let nccm = ncc.iter().sum::<f64>() / ncc.len() as f64;
            eprintln!(
                "RESTART seed {seed} {name:<14} cost {c:.6} prior {:.3} ncc {nccm:.4} d_main {:.3} err {:.3}",
                pr.cost(sc, t),
                mean_map_error(rig, &frames, &calib(t), &calib(&main)),
                mean_map_error(rig, &frames, &calib(t), &real.truth),
            );
        };
        let tt = to_theta(&real.truth);
        report("main", &main);
        let mut its = Vec::new();
        let _ = pipe.refine(main, 0, &mut |f, _| its.push(f));
        eprintln!("RESTART seed {seed} iterations per level factor {its:?}");
        let mut t = main;
        for round in 0..3 {
            let r = pipe.refine(t, fine, &mut |_, _| {});
            t = r.theta;
            report(&format!("main->fine{round}"), &t);
        }
        report("truth", &tt);
        report("truth->fine", &pipe.refine(tt, fine, &mut |_, _| {}).theta);
        report(
            "truth->2",
            &pipe
                .refine(tt, fine.saturating_sub(1), &mut |_, _| {})
                .theta,
        );
        for (i, (c0, s)) in pipe.search([0.0; NUM_PARAMS], 5).iter().enumerate() {
            let r = pipe.refine(*s, 0, &mut |_, _| {});
            report(&format!("search#{i} {c0:.4}"), &r.theta);
        }
        for df in [-8.0, -4.0, 4.0, 8.0] {
            let mut t0 = [0.0; NUM_PARAMS];
            t0[0] = df;
            t0[1] = df * sc.scale[0] / sc.scale[1];
            let (_, s) = pipe.search(t0, 1)[0];
            report(
                &format!("f{df:+}"),
                &pipe.refine(s, 0, &mut |_, _| {}).theta,
            );
        }
        for (i, d) in [
            (2usize, 3.0),
            (2, -3.0),
            (3, 3.0),
            (3, -3.0),
            (0, 3.0),
            (0, -3.0),
        ] {
            let mut t = main;
            t[i] += d;
            if i == 0 {
                t[1] += d * sc.scale[0] / sc.scale[1];
            }
            report(
                &format!("pert{i}{d:+}"),
                &pipe.refine(t, fine.saturating_sub(1), &mut |_, _| {}).theta,
            );
        }
    }
}

/// Development probe of the cost per Levenberg-Marquardt iteration at each level of a
/// real-imagery rig (`RTF_CALIB_SPEED=1 WIDTH=640 N_FRAMES=20 cargo test --release -p
/// rtf-calib --lib probe_speed -- --nocapture`): one normal-equation evaluation (all
/// parameters) and one cost evaluation, full levels against the subsampled finest level.
fn probe_speed() {
    let Some(data) = probe_data("RTF_CALIB_SPEED") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let cfg =
        rtf_calib::real_rig::RealRigConfig::new(&data, 1, env("WIDTH", 640), env("N_FRAMES", 20));
    let real = rtf_calib::real_rig::write_real_rig(dir.path(), &cfg).unwrap();
    let rig = &real.rig;
    let frames = load_frames(rig, &mut |w| eprintln!("{w}")).unwrap();
    let used: Vec<&Frame> = frames.iter().collect();
    let scaling = Scaling::new(&rig.rgb, initial_params(rig), &used);
    let dirs = directions(&(0..NUM_PARAMS).collect::<Vec<_>>(), &scaling, true);
    let all: Vec<i64> = (0..used.len() as i64).collect();
    let idx = Tensor::from_slice(&all);
    let theta = [0.5; NUM_PARAMS];
    for factor in pyramid_factors(rig.rgb.width) {
        let full = Level::build(&rig.rgb, &used, factor, false, 0.0, 1);
        let mut variants = vec![("full", full)];
        if (variants[0].1.h * variants[0].1.w) as usize > MAX_LEVEL_PIXELS {
            let sub =
                Level::build(&rig.rgb, &used, factor, false, 0.0, 1).subsample(MAX_LEVEL_PIXELS, 1);
            variants.push(("subsampled", sub));
        }
        for (name, level) in &variants {
            let t0 = std::time::Instant::now();
            let _ = normal_equations(level, &scaling, &theta, &dirs, &all);
            let ne = t0.elapsed().as_secs_f64();
            let t0 = std::time::Instant::now();
            let c = cost(level, &scaling, &theta, &idx);
            let ce = t0.elapsed().as_secs_f64();
            eprintln!(
                "SPEED 1/{factor} {name}: normal equations {ne:.2} s, cost {ce:.3} s (cost {c:.5})"
            );
        }
    }
}

/// Development probe of the objective's bias on real-imagery rigs (`RTF_CALIB_BIAS=1
/// WIDTH=320 N_FRAMES=10 SEEDS=1,2,3 SOURCE=ir|vi cargo test --release -p rtf-calib --lib
/// probe_bias -- --nocapture`): at every pyramid level, the cost along each parameter
/// direction through the truth (±3 px in steps of 0.25), and where its minimum lies.
fn probe_bias() {
    let Some(data) = probe_data("RTF_CALIB_BIAS") else {
        return;
    };
    let seeds: Vec<u64> = std::env::var("SEEDS")
        .unwrap_or_else(|_| "1,2,3".into())
        .split(',')
        .map(|s| s.trim().parse().unwrap())
        .collect();
    let variant = std::env::var("VARIANT").unwrap_or_default();
    for seed in seeds {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = rtf_calib::real_rig::RealRigConfig::new(
            &data,
            seed,
            env("WIDTH", 320),
            env("N_FRAMES", 10),
        );
        if std::env::var("SOURCE").as_deref() == Ok("vi") {
            cfg.degrade = rtf_calib::real_rig::Degrade::RgbAsThermal;
        }
        let real = rtf_calib::real_rig::write_real_rig(dir.path(), &cfg).unwrap();
        let rig = &real.rig;
        let frames = load_frames(rig, &mut |w| eprintln!("{w}")).unwrap();
        let used: Vec<&Frame> = frames.iter().collect();
        let scaling = Scaling::new(&rig.rgb, initial_params(rig), &used);
        let pt = model::from_calibration(&real.truth);
        let tt: [f64; NUM_PARAMS] =
            std::array::from_fn(|i| (pt[i] - scaling.p0[i]) / scaling.scale[i]);
        let all = Tensor::from_slice(&(0..used.len() as i64).collect::<Vec<_>>());
        let names = ["f", "cx", "cy", "roll", "pan", "tilt", "k1", "tz"];
        let mut dirs = vec![directions(&[0], &scaling, true)[0]];
        for i in [2usize, 3, 13, 12, 11, 4, 10] {
            let mut d = [0.0; NUM_PARAMS];
            d[i] = 1.0;
            dirs.push(d);
        }
        let ratio = real.truth.thermal.fx / rig.rgb.fx;
        for factor in pyramid_factors(rig.rgb.width) {
            let mut level = Level::build(&rig.rgb, &used, factor, false, 0.0, 1);
            if variant == "corr" {
                level = level.into_correlation();
            }
            let mut line = format!("BIAS seed {seed} ratio {ratio:.2} 1/{factor}:");
            for (name, d) in names.iter().zip(&dirs) {
                let steps: Vec<f64> = (-12..=12).map(|k| k as f64 * 0.25).collect();
                let costs: Vec<f64> = steps
                    .iter()
                    .map(|s| {
                        let t: [f64; NUM_PARAMS] = std::array::from_fn(|i| tt[i] + s * d[i]);
                        cost(&level, &scaling, &t, &all)
                    })
                    .collect();
                let k = (0..costs.len())
                    .min_by(|&a, &b| costs[a].total_cmp(&costs[b]))
                    .unwrap();
                let k = k.clamp(1, costs.len() - 2);
                let (a, b, c) = (costs[k - 1], costs[k], costs[k + 1]);
                let off = steps[k] + 0.25 * 0.5 * (a - c) / (a - 2.0 * b + c);
                let depth = (costs[0] + costs[24]) / 2.0 / b - 1.0;
                line += &format!(" {name} {off:+.2} ({:.1}%)", depth * 100.0);
            }
            eprintln!("{line}");
        }
    }
}

// Loss variants tried in `probe_residual_field` (not used by the calibrator).

/// Keeps in the loss support only the pixels that `theta` maps inside the thermal image
/// (`tw`×`th` full-resolution pixels) with `margin` px to spare. Fixed for a level run, so
/// the support still does not depend on the parameters being optimised.
fn restrict_support(
    mut level: Level,
    scaling: &Scaling,
    theta: &[f64; NUM_PARAMS],
    tw: f64,
    th: f64,
    margin: f64,
) -> Level {
    let (u, v) = model::project(&level.points, &scaling.tensor(theta));
    let inside = u
        .ge(margin)
        .logical_and(&u.le(tw - 1.0 - margin))
        .logical_and(&v.ge(margin))
        .logical_and(&v.le(th - 1.0 - margin))
        .to_kind(Kind::Float)
        .view(level.mask.size().as_slice());
    level.mask = &level.mask * inside;
    level
}

/// Scales each frame's thermal features (and their gradients) by its least-squares gain
/// β = Σ M·a·t / Σ M·t² at `theta` (clamped to [0.05, 1]): the squared difference
/// Σ(a − β·t)² then weighs the Σt² term by β² against the cross term's β, so thermal edge
/// energy that matches nothing in the RGB image pulls less on the map.
fn with_gain(mut level: Level, scaling: &Scaling, theta: &[f64; NUM_PARAMS]) -> Level {
    let b = level.points.size()[0];
    let idx = Tensor::arange(b, (Kind::Int64, Device::Cpu));
    let t = level.warp(&scaling.tensor(theta), &idx) * &level.mask;
    let dims = &[1i64, 2, 3][..];
    let at = (&level.rgb_feat * &t).sum_dim_intlist(dims, true, Kind::Float);
    let tt = t.square().sum_dim_intlist(dims, true, Kind::Float);
    let beta = (at / tt.clamp_min(1e-12)).clamp(0.05, 1.0);
    level.thermal_src = &level.thermal_src * &beta;
    level.thermal_grad = &level.thermal_grad * &beta;
    level
}

/// The stated bound (issue 28) of an existing calib.yaml, without re-calibrating: RIG=rig.yaml
/// CALIB=calib.yaml (the solution, its `split_px` and restart spread); the start is the rig's
/// nominal one, the frames the rig's first 20 (`rtf calibrate` assesses on the first 20 it
/// used, in its own order, so the pixel subsets differ slightly). Prints the bound, the
/// straight-line bound and the seconds it took.
fn bound_of_file() {
    use rtf_calib::bound::{bound, BoundInputs};
    use rtf_calib::calibfile::CalibFile;
    tch::set_num_threads(1);
    let var = |k: &str| std::env::var(k).unwrap_or_else(|_| panic!("{k}=... needed"));
    let rig = Rig::load(std::path::Path::new(&var("RIG"))).unwrap();
    let file = CalibFile::load(std::path::Path::new(&var("CALIB"))).unwrap();
    let frames = load_frames(&rig, &mut |w| eprintln!("{w}")).unwrap();
    let chosen: Vec<&Frame> = frames.iter().take(20).collect();
    let a = file.quality.as_ref().and_then(|q| q.assessment.clone());
    let split_px = a.as_ref().map_or(0.0, |a| a.split_px);
    let spread = a
        .as_ref()
        .and_then(|a| a.restarts.as_ref())
        .map_or(0.0, |r| r.spread_px);
    let initial = model::to_calibration(&initial_params(&rig));
    let t0 = std::time::Instant::now();
    let (px, b) = bound(
        &rig,
        &chosen,
        &BoundInputs {
            initial: &initial,
            solution: &file.calibration(),
            split_px,
            restart_spread_px: spread,
            debug: debug(),
        },
    );
    println!(
        "bound {px:.3} px (straight-line ellipsoid {:.3}, flattest {:.3}, objective gap {:.3}, \
         split {split_px:.3}, spread {spread:.3}, capped {}) in {:.1} s",
        b.straight_line_px,
        b.flattest_px,
        b.objective_gap_px,
        b.capped,
        t0.elapsed().as_secs_f64()
    );
}
