//! `cargo xtask calib-check`: the full-size (640×480) accuracy and timing run of `rtf
//! calibrate` on synthetic rigs with ground truth. Runs the release `rtf` binary (xtask has no
//! libtorch), prints one line per run and a Markdown table for docs/src/calibration.md.

use anyhow::{bail, Context, Result};
use std::path::Path;
use std::time::Instant;

struct Options {
    real_trials: usize,
    real_width: usize,
    real_frames: usize,
    seeds: Vec<u64>,
    frames: usize,
    width: usize,
    paper_iterations: usize,
    out: String,
}

fn parse(args: &[String]) -> Result<Options> {
    let mut o = Options {
        real_trials: 20,
        real_width: 640,
        real_frames: 20,
        seeds: vec![1, 2, 3],
        frames: 20,
        width: 640,
        paper_iterations: 40,
        out: "target/calib-check".into(),
    };
    let mut it = args.iter();
    while let Some(flag) = it.next() {
        let mut value = || it.next().with_context(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--seeds" => o.seeds = value()?.split(',').filter(|s| !s.trim().is_empty()).map(|s| s.trim().parse()).collect::<Result<_, _>>().context("--seeds: list like 1,2,3")?,
            "--frames" => o.frames = value()?.parse().context("--frames: a number")?,
            "--width" => o.width = value()?.parse().context("--width: a number")?,
            "--paper-iterations" => o.paper_iterations = value()?.parse().context("--paper-iterations: a number")?,
            "--out" => o.out = value()?.clone(),
            "--real-trials" => o.real_trials = value()?.parse().context("--real-trials: a number")?,
            "--real-width" => o.real_width = value()?.parse().context("--real-width: a number")?,
            "--real-frames" => o.real_frames = value()?.parse().context("--real-frames: a number")?,
            other => bail!("calib-check: unknown option `{other}` (--seeds 1,2,3 --frames 20 --width 640 --paper-iterations 40 --real-trials 20 --real-width 640 --real-frames 20 --out DIR; --seeds '' skips the synthetic rigs, --real-trials 0 the real ones)"),
        }
    }
    Ok(o)
}

/// The "vs ground truth:" line of `rtf calibrate --ground-truth`.
fn truth_line(stdout: &str) -> String {
    stdout
        .lines()
        .find(|l| l.starts_with("vs ground truth:"))
        .unwrap_or("(no comparison printed)")
        .to_string()
}

fn s(v: &[&str]) -> Vec<String> {
    v.iter().map(|x| x.to_string()).collect()
}

pub fn calib_check(root: &Path, extra: &[String]) -> Result<()> {
    let o = parse(extra)?;
    crate::setup::ensure_libtorch(root)?;
    if o.real_trials > 0 {
        real_trials(root, &o)?;
    }
    if o.seeds.is_empty() {
        return Ok(());
    }
    crate::run(root, "cargo", &["build", "--release", "-p", "rtf-cli"])?;
    let mut rows = Vec::new();
    for &seed in &o.seeds {
        rows.push(default_recipe(root, &o, seed, "given", "given", &[])?);
    }
    let seed = o.seeds[0];
    rows.push(default_recipe(
        root,
        &o,
        seed,
        "stereo",
        "stereo (SGM)",
        &s(&["--eval-rig", "{dir}/rig_depth.yaml"]),
    )?);
    time_paper_recipe(root, &o, seed)?;
    println!("\n| recipe | depth | seed | result | wall s |\n|---|---|---|---|---|");
    for r in rows {
        println!("{r}");
    }
    Ok(())
}

/// Real-imagery rigs (MSRS frames through a known thermal camera): trials, table and the
/// success-rate plot, from the lab's `real_trials` program (`lab/probes`, package rtf-lab: it
/// needs libtorch; xtask does not).
fn real_trials(root: &Path, o: &Options) -> Result<()> {
    crate::run(
        root,
        "cargo",
        &[
            "run",
            "--release",
            "-p",
            "rtf-lab",
            "--bin",
            "real_trials",
            "--",
            "--trials",
            &o.real_trials.to_string(),
            "--width",
            &o.real_width.to_string(),
            "--frames",
            &o.real_frames.to_string(),
            "--out",
            &format!("{}/real", o.out),
        ],
    )
}

/// The folder (relative to the root) of the synthetic rig of `seed` with `depth`.
fn rig_dir(o: &Options, depth: &str, seed: u64) -> String {
    format!("{}/rig-{}-{}-{}", o.out, o.width, depth, seed)
}

/// `rtf synth --format calibration-rig` afresh into [`rig_dir`]; returns that folder.
fn synth_rig(root: &Path, o: &Options, seed: u64, depth: &str) -> Result<String> {
    let dir = rig_dir(o, depth, seed);
    let _ = std::fs::remove_dir_all(root.join(&dir));
    crate::rtf_stdout(
        root,
        &s(&[
            "synth",
            "--format",
            "calibration-rig",
            "--out",
            &dir,
            "--size",
            &format!("{}x{}", o.width, o.width * 3 / 4),
            "--count",
            &o.frames.to_string(),
            "--rig-depth",
            depth,
            "--seed",
            &seed.to_string(),
        ]),
    )?;
    Ok(dir)
}

/// Default recipe on one fresh rig against its ground truth: prints a line and returns the
/// table row. `extra` flags may name the rig's folder as `{dir}`.
fn default_recipe(
    root: &Path,
    o: &Options,
    seed: u64,
    depth: &str,
    label: &str,
    extra: &[String],
) -> Result<String> {
    let dir = synth_rig(root, o, seed, depth)?;
    let start = Instant::now();
    let mut args = s(&[
        "calibrate",
        "--rig",
        &format!("{dir}/rig.yaml"),
        "--out",
        &format!("{dir}/calib.yaml"),
    ]);
    args.extend(s(&["--ground-truth", &format!("{dir}/ground_truth.yaml")]));
    args.extend(extra.iter().map(|a| a.replace("{dir}", &dir)));
    let line = truth_line(&crate::rtf_stdout(root, &args)?);
    let secs = start.elapsed().as_secs_f64();
    println!("default, {label} depth, seed {seed}: {line} (wall {secs:.1} s)");
    Ok(format!(
        "| default | {label} | {seed} | {line} | {secs:.1} |"
    ))
}

/// Paper recipe: a short run on the given-depth rig of `seed` (made by [`default_recipe`]),
/// timed and extrapolated to the recipe's 8000 iterations.
fn time_paper_recipe(root: &Path, o: &Options, seed: u64) -> Result<()> {
    let dir = rig_dir(o, "given", seed);
    let start = Instant::now();
    let paper = s(&[
        "calibrate",
        "--recipe",
        "paper",
        "--iterations",
        &o.paper_iterations.to_string(),
        "--rig",
        &format!("{dir}/rig.yaml"),
        "--out",
        &format!("{dir}/calib-paper-short.yaml"),
    ]);
    let output = crate::rtf_output(root, &paper)?;
    let secs = start.elapsed().as_secs_f64();
    // This run only times the recipe: a few dozen of its 8000 iterations do not align the
    // rig, so `rtf calibrate` judges the result `failed` (exit 1, file kept); anything else
    // that fails is an error.
    let stderr = String::from_utf8_lossy(&output.stderr);
    if !output.status.success() {
        if !stderr.contains("calibration failed:") {
            bail!("`rtf {}` failed:\n{stderr}", paper.join(" "));
        }
        println!(
            "paper recipe: verdict `failed` after {} iterations, as expected of a short run (timing only)",
            o.paper_iterations
        );
    }
    let per_iter = secs / o.paper_iterations as f64;
    println!(
        "paper recipe: {} iterations (batch 10, {}x{}) in {secs:.1} s = {:.2} s/iteration -> 8000 iterations ≈ {:.1} h (extrapolated)",
        o.paper_iterations,
        o.width,
        o.width * 3 / 4,
        per_iter,
        per_iter * 8000.0 / 3600.0
    );
    Ok(())
}
