//! `rtf calibrate`: targetless RGB-thermal calibration (HeatNet §IV-A) of a rig described by
//! rig.yaml; writes calib.yaml atomically, optionally overlays and a comparison with a known
//! calibration.

use anyhow::{bail, Result};
use indicatif::{ProgressBar, ProgressStyle};
use rtf_calib::calibfile::CalibFile;
use rtf_calib::frames::{load_frames, Frame};
use rtf_calib::optimize::{self, Recipe};
use rtf_calib::quality::{Assessment, Verdict};
use rtf_calib::rig::{OptimizerOverrides, Rig};
use rtf_calib::run::{refuse_overwriting_inputs, CalibrateOptions, Calibrated, Prepared};
use std::path::{Path, PathBuf};

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum RecipeArg {
    /// Coarse-to-fine pyramid, robust edge features, shift search, Levenberg-Marquardt.
    Default,
    /// The paper: full resolution, σ = 3 / 51 px gradient loss, Adam, 8000 iterations.
    Paper,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FormatArg {
    /// calib.yaml only.
    Yaml,
    /// calib.yaml and a Kalibr-style camchain (`<out stem>-camchain.yaml`).
    Kalibr,
}

#[derive(clap::Args)]
pub struct Args {
    /// The rig description (paths inside are relative to it).
    #[arg(long)]
    pub rig: PathBuf,
    /// Where to write calib.yaml.
    #[arg(long)]
    pub out: PathBuf,
    /// Write per-frame overlays (initial, final, residual) into this directory.
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    /// Random seed (frame subsets and batches).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[arg(long, value_enum, default_value_t = RecipeArg::Default)]
    pub recipe: RecipeArg,
    /// paper: Adam iterations; default: Levenberg-Marquardt iterations per pyramid level.
    #[arg(long)]
    pub iterations: Option<usize>,
    /// paper: pairs per step; default: frames used.
    #[arg(long)]
    pub batch_size: Option<usize>,
    /// paper: initial Adam step (pixel-scaled units); default: first LM damping = 1e-5 / LR.
    #[arg(long)]
    pub learning_rate: Option<f64>,
    /// libtorch CPU threads. The model's many small tensor operations run fastest on one
    /// thread on a busy machine: threads that share loaded cores wait for each other
    /// (measured: docs/src/calibration.md, section "Method").
    #[arg(long, default_value_t = 1)]
    pub threads: i32,
    /// A known calibration (calib.yaml schema) to compare with: prints the mean RGB→thermal
    /// pixel-map distance over pixels with depth, and the rotation/translation differences.
    #[arg(long)]
    pub ground_truth: Option<PathBuf>,
    /// Rig whose depth is used for --ground-truth (default: --rig).
    #[arg(long)]
    pub eval_rig: Option<PathBuf>,
    /// Output format: `kalibr` also writes a Kalibr camchain YAML beside --out.
    #[arg(long, value_enum, default_value_t = FormatArg::Yaml)]
    pub format: FormatArg,
}

pub fn run(args: Args) -> Result<()> {
    let (rig_path, out) = (args.rig.clone(), args.out.clone());
    tch::set_num_threads(args.threads.max(1));
    let options = CalibrateOptions {
        recipe: match args.recipe {
            RecipeArg::Default => Recipe::Default,
            RecipeArg::Paper => Recipe::Paper,
        },
        overrides: OptimizerOverrides {
            iterations: args.iterations,
            batch_size: args.batch_size,
            learning_rate: args.learning_rate,
        },
        seed: args.seed,
    };
    let rig = Rig::load(&rig_path)?;
    let camchain = rtf_calib::kalibr::camchain_path(&out);
    let mut outputs: Vec<(&str, &Path)> = vec![("--out", out.as_path())];
    if let Some(dir) = &args.overlay {
        outputs.push(("--overlay", dir.as_path()));
    }
    if args.format == FormatArg::Kalibr {
        outputs.push(("--format kalibr (camchain)", camchain.as_path()));
    }
    refuse_overwriting_inputs(&rig_path, &rig, &outputs)?;
    let mut prepared = Prepared::new(&rig_path, rig, &options, &mut |w| eprintln!("warning: {w}"))?;
    // Development output of the bound's walks on stderr (rtf_calib's `Settings::debug`).
    prepared.settings.debug = std::env::var_os("RTF_CALIB_DEBUG").is_some();
    let (settings, frames) = (&prepared.settings, &prepared.frames);
    let stereo = frames.iter().filter(|f| f.depth_from_stereo).count();
    eprintln!(
        "{} usable frames ({} with stereo depth); recipe {:?}: iterations {}, batch size {}, learning rate {}",
        frames.len(),
        stereo,
        options.recipe,
        settings.iterations,
        settings.batch_size,
        settings.learning_rate
    );
    let start = std::time::Instant::now();
    let calibrated = calibrate_with_progress(&prepared)?;
    let seconds = start.elapsed().as_secs_f64();
    let outcome = &calibrated.outcome;
    if let Some(reason) = &outcome.stopped {
        eprintln!("warning: stopped early: {reason}");
    }
    write_calibration(&args, &prepared.rig, &calibrated, &camchain, seconds)?;
    if let Some(dir) = &args.overlay {
        let written = rtf_calib::overlay::write_overlays(
            dir,
            &prepared.rig.rgb,
            frames,
            &outcome.initial,
            &outcome.calibration,
        )?;
        println!(
            "wrote {} overlay images to {}",
            written.len(),
            dir.display()
        );
    }
    if let Some(truth_path) = &args.ground_truth {
        compare_with_truth(&args, truth_path, &prepared.rig, frames, outcome, seconds)?;
    }
    match &outcome.assessment {
        Some(a) => report_verdict(a, &out),
        None => Ok(()),
    }
}

/// The library's calibration ([`Prepared::calibrate`]) under a progress bar (stage, step,
/// loss, ETA).
fn calibrate_with_progress(prepared: &Prepared) -> Result<Calibrated> {
    let bar = ProgressBar::new(1);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {msg} ETA {eta}",
        )
        .expect("valid template"),
    );
    let calibrated = prepared.calibrate(&mut |p| {
        bar.set_length(p.total as u64);
        bar.set_position(p.step as u64);
        bar.set_message(format!("{} loss {:.6}", p.stage, p.loss));
    })?;
    bar.finish_and_clear();
    Ok(calibrated)
}

/// Writes calib.yaml (and the Kalibr camchain if asked) and prints the solution.
fn write_calibration(
    args: &Args,
    rig: &Rig,
    calibrated: &Calibrated,
    camchain: &Path,
    seconds: f64,
) -> Result<()> {
    let (outcome, file) = (&calibrated.outcome, &calibrated.file);
    file.save(&args.out)?;
    if args.format == FormatArg::Kalibr {
        rtf_calib::kalibr::Camchain::new(
            &rig.rgb,
            (rig.thermal.width, rig.thermal.height),
            &outcome.calibration,
        )
        .save(camchain)?;
        println!("wrote {} (Kalibr camchain)", camchain.display());
    }
    let k = &file.thermal;
    println!(
        "wrote {}: fx {:.2} fy {:.2} cx {:.2} cy {:.2} distortion {:?}; t {:?} m; rotation {:.3}°; loss {:.6}; {} iterations in {:.1} s",
        args.out.display(),
        k.fx,
        k.fy,
        k.cx,
        k.cy,
        k.distortion,
        file.extrinsic.translation,
        outcome.calibration.extrinsic.angle().to_degrees(),
        outcome.loss,
        outcome.iterations,
        seconds
    );
    Ok(())
}

/// `--ground-truth`: the pixel-map error before and after, and the extrinsic's error, over the
/// frames of `--eval-rig` (default: the calibrated `frames`).
fn compare_with_truth(
    args: &Args,
    truth_path: &Path,
    rig: &Rig,
    frames: &[Frame],
    outcome: &rtf_calib::solve::Outcome,
    seconds: f64,
) -> Result<()> {
    let truth = CalibFile::load(truth_path)?.calibration();
    let loaded;
    let eval_frames = match &args.eval_rig {
        Some(path) => {
            loaded = load_frames(&Rig::load(path)?, &mut |w| eprintln!("warning: {w}"))?;
            &loaded
        }
        None => frames,
    };
    let before = optimize::mean_map_error(rig, eval_frames, &outcome.initial, &truth);
    let after = optimize::mean_map_error(rig, eval_frames, &outcome.calibration, &truth);
    let (deg, metres) = outcome.calibration.extrinsic.difference(&truth.extrinsic);
    println!(
        "vs ground truth: pixel-map error {after:.4} px (initial {before:.3} px); rotation error {deg:.4} deg; translation error {:.3} cm; time {seconds:.1} s",
        metres * 100.0
    );
    Ok(())
}

/// Prints the quality verdict; a `failed` one is an error (the file stays for inspection).
fn report_verdict(a: &Assessment, out: &Path) -> Result<()> {
    println!(
        "verdict: {} ({}); alignment score {:.4} (start {:.4}, ±{} px {:.4}); {:.0} % of frames agree; split-half {:.2} px; map moved {:.1} px",
        a.verdict,
        a.reason,
        a.score.at_solution,
        a.score.at_start,
        a.score.delta_px,
        a.score.perturbed_mean,
        100.0 * a.frames_agreeing,
        a.split_px,
        a.moved_px
    );
    if let Some(r) = &a.restarts {
        println!(
            "restarts (wrong-basin check): {} solutions from starts perturbed by {:.1} px; the best moved the first run's map {:.2} px; equal-scoring solutions within {:.2} px of each other",
            r.count, r.perturbation_px, r.improved_px, r.spread_px
        );
    }
    print_bound(a);
    if a.verdict == Verdict::Failed {
        bail!(
            "calibration failed: {} ({} kept for inspection)",
            a.reason,
            out.display()
        );
    }
    Ok(())
}

/// The stated error bound (issue 28) and, for each quantity with a rig.yaml prior, whether
/// the images or the prior set it.
fn print_bound(a: &Assessment) {
    let (Some(px), Some(b)) = (a.map_error_bound_px, &a.bound) else {
        return;
    };
    if b.capped {
        // The walks reached the search's edge: the number is where the search stopped, not a
        // bound (on a 2-frame rig it runs to millions of px).
        // What to do about it is the verdict's reason (quality::Assessment::with_bound).
        println!(
            "map error bound: none — the data leave the map free (search stopped at {px:.0} px)"
        );
    } else {
        println!(
            "map error bound: {px:.2} px (solutions the data cannot tell apart; flattest direction {:.2} px)",
            b.flattest_px
        );
    }
    for (name, r) in &b.priors {
        println!(
            "  {name}: set by the {} ({:.0} % of the information from the prior; ±{:.4} after, prior σ {})",
            r.set_by,
            100.0 * r.prior_share,
            r.posterior_half_width,
            r.prior_sigma
        );
    }
    for w in &b.warnings {
        eprintln!("warning: {w}");
    }
}
