//! Real-imagery calibration trials (issue 12), run by `cargo xtask calib-check`:
//! `cargo run --release -p rtf-lab --bin real_trials -- [--trials 20] [--width 640]
//! [--frames 20] [--out target/calib-check/real] [--data ../shared/data] [--first-seed 1]
//! [--only 2,5] [--rejudge]`.
//!
//! Each trial builds a rig from real MSRS frames ([`rtf_calib::real_rig`]) whose thermal
//! camera spans the range users meet (thermal focal length 0.75–1.35 × the RGB one, i.e. wider
//! and narrower fields of view, spread evenly over the trials; rotations up to 3°, offsets up
//! to 20 cm; day, night and mixed frames in turn), calibrates it with the default recipe on
//! one libtorch thread, and records the start and final map errors, the fx/fy ratio, the time
//! and the quality verdict. Writes `trials.json`, `trials.md` and `success_vs_start.png`
//! (success rate against the start error, plotted with `plotters`).

use plotters::prelude::*;
use rtf_calib::frames::load_frames;
use rtf_calib::optimize::{self, Recipe, Settings};
use rtf_calib::real_rig::{write_real_rig, RealRigConfig};
use std::path::PathBuf;

#[derive(serde::Serialize, serde::Deserialize)]
struct Trial {
    seed: u64,
    daylight: String,
    focal_ratio: f64,
    start_px: f64,
    final_px: f64,
    aspect_error: f64,
    seconds: f64,
    verdict: String,
    reason: String,
    /// Quality figures (no ground truth), for setting the verdict's thresholds.
    score: f64,
    sharpness: f64,
    frames_agreeing: f64,
    moved_px: f64,
    split_px: f64,
    /// Wrong-basin check: how far the restarts moved the main run's solution, and how far
    /// apart solutions of about the same cost lie (px).
    restart_improved_px: f64,
    restart_spread_px: f64,
    restart_cost_drop: f64,
    /// The stated bound on the map error (issue 28; absent in files written before it).
    #[serde(default)]
    bound_px: Option<f64>,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let get = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .map(|i| args[i + 1].clone())
    };
    let trials: usize = get("--trials").map_or(Ok(20), |s| s.parse())?;
    let width: usize = get("--width").map_or(Ok(640), |s| s.parse())?;
    let frames: usize = get("--frames").map_or(Ok(20), |s| s.parse())?;
    let first: u64 = get("--first-seed").map_or(Ok(1), |s| s.parse())?;
    let out = PathBuf::from(get("--out").unwrap_or_else(|| "target/calib-check/real".into()));
    let data = match get("--data") {
        Some(d) => PathBuf::from(d),
        None => rtf_calib::real_rig::default_data_dir()
            .ok_or("../shared/data (msrs-samples) not found; pass --data")?,
    };
    tch::set_num_threads(1);
    std::fs::create_dir_all(&out)?;
    let mut results: Vec<Trial> = Vec::new();
    // `--only 2,5`: run just these seeds of the set (same thermal lens and frames as in the
    // full run, so single trials can be repeated).
    let only: Option<Vec<u64>> =
        get("--only").map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect());
    // `--rejudge`: no calibration; re-reads `trials.json` from `--out` and applies the
    // current sharpness rule (`quality::SHARPNESS_UNCERTAIN`) to its recorded figures (the
    // verdict rules before it are unchanged, so only an `ok` can change), then rewrites the
    // table and the plot.
    let rejudge = args.iter().any(|a| a == "--rejudge");
    if rejudge {
        let path = out.join("trials.json");
        let text = std::fs::read_to_string(&path)
            .map_err(|e| format!("--rejudge reads {}: {e}", path.display()))?;
        results = serde_json::from_str(&text)
            .map_err(|e| format!("{}: not a real_trials result: {e}", path.display()))?;
        for t in results.iter_mut() {
            if t.verdict == "ok" && t.sharpness < rtf_calib::quality::SHARPNESS_UNCERTAIN {
                t.verdict = "uncertain".into();
                t.reason = format!(
                    "a shallow optimum: perturbing by {} px lowers the score by only {:.1} % (rejudged from the recorded figures)",
                    rtf_calib::quality::DELTA_PX,
                    100.0 * t.sharpness
                );
            }
        }
    }
    for k in 0..if rejudge { 0 } else { trials } {
        let seed = first + k as u64;
        if only.as_ref().is_some_and(|o| !o.contains(&seed)) {
            continue;
        }
        let cfg = RealRigConfig::new(&data, seed, width, frames).in_trial_set(k, trials);
        let ratio = cfg.focal_ratio.expect("set by in_trial_set");
        let dir = out.join(format!("rig-{seed}"));
        let _ = std::fs::remove_dir_all(&dir);
        let real = write_real_rig(&dir, &cfg)?;
        let loaded = load_frames(&real.rig, &mut |w| eprintln!("warning: {w}"))?;
        let mut settings = Settings::resolve(Recipe::Default, Default::default(), None, 0)?;
        // The bound's walks on stderr with RTF_CALIB_DEBUG set (the library's `Settings::debug`).
        settings.debug = std::env::var_os("RTF_CALIB_DEBUG").is_some();
        let t0 = std::time::Instant::now();
        // `RTF_CALIB_PROFILE=1`: time per stage (pyramid level, restarts) and iterations.
        let profile = std::env::var_os("RTF_CALIB_PROFILE").is_some();
        let mut stages: Vec<(String, usize, f64)> = Vec::new();
        let mut last = std::time::Instant::now();
        let outcome = rtf_calib::solve::calibrate(&real.rig, &loaded, &settings, &mut |p| {
            if profile {
                let dt = last.elapsed().as_secs_f64();
                last = std::time::Instant::now();
                match stages.last_mut() {
                    Some(s) if s.0 == p.stage => {
                        s.1 += 1;
                        s.2 += dt;
                    }
                    _ => stages.push((p.stage.clone(), 1, dt)),
                }
            }
        })?;
        if profile {
            for (stage, n, secs) in &stages {
                println!("profile seed {seed}: {stage}: {n} iterations, {secs:.1} s");
            }
        }
        let seconds = t0.elapsed().as_secs_f64();
        let start_px = optimize::mean_map_error(&real.rig, &loaded, &outcome.initial, &real.truth);
        let final_px =
            optimize::mean_map_error(&real.rig, &loaded, &outcome.calibration, &real.truth);
        let k_est = outcome.calibration.thermal;
        let k_true = real.truth.thermal;
        let a = outcome.assessment.as_ref().expect("assessed");
        let t = Trial {
            seed,
            daylight: format!("{:?}", cfg.daylight).to_lowercase(),
            focal_ratio: ratio,
            start_px,
            final_px,
            aspect_error: (k_est.fx / k_est.fy) / (k_true.fx / k_true.fy) - 1.0,
            seconds,
            verdict: a.verdict.to_string(),
            reason: a.reason.clone(),
            score: a.score.at_solution,
            sharpness: a.score.sharpness,
            frames_agreeing: a.frames_agreeing,
            moved_px: a.moved_px,
            split_px: a.split_px,
            restart_improved_px: a.restarts.as_ref().map_or(0.0, |r| r.improved_px),
            restart_spread_px: a.restarts.as_ref().map_or(0.0, |r| r.spread_px),
            restart_cost_drop: a.restarts.as_ref().map_or(0.0, |r| r.cost_drop),
            bound_px: a.map_error_bound_px,
        };
        println!(
            "trial seed {seed} ({}, thermal f/rgb f {ratio:.2}): map error {start_px:.2} -> {final_px:.3} px, fx/fy error {:.3} %, {seconds:.1} s, score {:.3}, sharpness {:.3}, agree {:.2}, moved {:.1} px, split {:.3} px, restarts improved {:.2} px (cost -{:.2} %) spread {:.2} px, bound {:.3} px, verdict {} ({})",
            t.daylight,
            100.0 * t.aspect_error,
            t.score,
            t.sharpness,
            t.frames_agreeing,
            t.moved_px,
            t.split_px,
            t.restart_improved_px,
            100.0 * t.restart_cost_drop,
            t.restart_spread_px,
            t.bound_px.unwrap_or(f64::NAN),
            t.verdict,
            t.reason
        );
        results.push(t);
    }
    std::fs::write(
        out.join("trials.json"),
        serde_json::to_string_pretty(&results)?,
    )?;
    let ok = results.iter().filter(|t| t.final_px < 1.0).count();
    let silent = results
        .iter()
        .filter(|t| t.final_px >= 1.0 && t.verdict == "ok")
        .count();
    let stated: Vec<&Trial> = results.iter().filter(|t| t.bound_px.is_some()).collect();
    let covered = stated
        .iter()
        .filter(|t| t.bound_px.is_some_and(|b| t.final_px <= b))
        .count();
    let mut md = format!(
        "{ok}/{} trials < 1 px; failures flagged uncertain/failed: {}/{}; the bound covers the true error in {covered}/{}\n\n| seed | frames | thermal f / RGB f | start px | final px | fx/fy error | s | sharpness | agree | split px | bound px | verdict |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n",
        results.len(),
        results.len() - ok - silent,
        results.len() - ok,
        stated.len()
    );
    for t in &results {
        md += &format!(
            "| {} | {} | {:.2} | {:.2} | {:.3} | {:.3} % | {:.1} | {:.3} | {:.2} | {:.3} | {} | {} |\n",
            t.seed,
            t.daylight,
            t.focal_ratio,
            t.start_px,
            t.final_px,
            100.0 * t.aspect_error,
            t.seconds,
            t.sharpness,
            t.frames_agreeing,
            t.split_px,
            t.bound_px.map_or("–".into(), |b| format!("{b:.3}")),
            t.verdict
        );
    }
    std::fs::write(out.join("trials.md"), &md)?;
    println!("\n{md}");
    plot(&results, &out.join("success_vs_start.png"))?;
    println!("wrote {}", out.join("success_vs_start.png").display());
    Ok(())
}

/// Success rate (< 1 px) per start-error bin, and every trial's final error, against the start.
fn plot(results: &[Trial], path: &std::path::Path) -> Result<(), Box<dyn std::error::Error>> {
    let font = ["/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"]
        .iter()
        .find_map(|p| std::fs::read(p).ok())
        .ok_or("no TrueType font found for the plot (DejaVuSans.ttf)")?;
    plotters::style::register_font(
        "sans-serif",
        FontStyle::Normal,
        Box::leak(font.into_boxed_slice()),
    )
    .map_err(|_| "cannot register the font")?;
    let max_start = results.iter().map(|t| t.start_px).fold(5.0, f64::max) * 1.05;
    let bins = 6;
    let width = max_start / bins as f64;
    let root = BitMapBackend::new(path, (900, 520)).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(450);
    let mut chart = ChartBuilder::on(&left)
        .caption("success rate (< 1 px) vs start error", ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..max_start, 0.0..1.05)?;
    chart
        .configure_mesh()
        .x_desc("start map error (px)")
        .y_desc("share of trials < 1 px")
        .draw()?;
    let mut points = Vec::new();
    for b in 0..bins {
        let (lo, hi) = (b as f64 * width, (b + 1) as f64 * width);
        let inside: Vec<&Trial> = results
            .iter()
            .filter(|t| t.start_px >= lo && t.start_px < hi)
            .collect();
        if !inside.is_empty() {
            let rate =
                inside.iter().filter(|t| t.final_px < 1.0).count() as f64 / inside.len() as f64;
            points.push(((lo + hi) / 2.0, rate));
        }
    }
    chart.draw_series(LineSeries::new(points.clone(), &BLUE))?;
    chart.draw_series(points.iter().map(|&p| Circle::new(p, 5, BLUE.filled())))?;
    let max_final = results.iter().map(|t| t.final_px).fold(2.0, f64::max) * 1.1;
    let mut chart = ChartBuilder::on(&right)
        .caption("final vs start map error", ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..max_start, 0.0..max_final)?;
    chart
        .configure_mesh()
        .x_desc("start map error (px)")
        .y_desc("final map error (px)")
        .draw()?;
    chart.draw_series(LineSeries::new(vec![(0.0, 1.0), (max_start, 1.0)], &BLACK))?;
    chart.draw_series(results.iter().map(|t| {
        let colour = match t.verdict.as_str() {
            "ok" => GREEN.filled(),
            "uncertain" => RGBColor(230, 150, 0).filled(),
            _ => RED.filled(),
        };
        Circle::new((t.start_px, t.final_px), 4, colour)
    }))?;
    root.present()?;
    Ok(())
}
