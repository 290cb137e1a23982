//! `rtf predict`: parses its flags, plans and runs the prediction (rtf_eval::predict) and
//! prints each frame's outputs and the progress.

use std::path::{Path, PathBuf};

use std::sync::Arc;

use anyhow::{bail, Result};
use rtf_data::FrameSource;
use rtf_eval::predict::{self, Prediction};

use super::load_network;
use crate::output_guard::{resolved, OutputGuard};

#[derive(clap::Args)]
pub struct Args {
    /// Network name (see `rtf models`).
    #[arg(long, default_value = "mfnet")]
    pub model: String,
    /// Weights (safetensors, reference names).
    #[arg(long)]
    pub weights: PathBuf,
    /// Output folder: <stem>.png (class ids), <stem>_color.png (palette), <stem>.npy (--logits);
    /// with --data, <frame name>.png etc. (a folder per `/` of the name).
    #[arg(long)]
    pub out: PathBuf,
    /// Predict every frame of a split of this dataset root (any layout rtf reads; a
    /// dataset.yaml or the folder holding it), each written under its frame's name. The class
    /// set defaults to the dataset's; --out must be outside the dataset.
    #[arg(long, conflicts_with_all = ["rgb", "images"], value_parser = rtf_data::dataset::parse_root)]
    pub data: Option<PathBuf>,
    /// The split of --data to predict.
    #[arg(long, default_value = "test", requires = "data")]
    pub split: String,
    /// Also write the logits as float32 .npy of shape [classes, H, W].
    #[arg(long)]
    pub logits: bool,
    /// Class set of the weights: mf (9), freiburg (13), or a dataset root / dataset.yaml whose
    /// class set (its N classes and palette) the weights were trained on. Default: the class
    /// set the weights record (rtf train writes it), else from the model (HeatNet: freiburg,
    /// others mf). Refused when the weights record another class set.
    #[arg(long)]
    pub classes: Option<String>,
    /// RGB image (PNG or JPEG) of a pair given as separate files (with --thermal); repeat
    /// both for several pairs (the n-th --rgb with the n-th --thermal).
    #[arg(long, requires = "thermal")]
    pub rgb: Vec<PathBuf>,
    /// Thermal image of a pair given as separate files (with --rgb): PNG (8/16-bit), JPEG
    /// (grey), TIFF (8/16-bit, 32-bit float) or .npy, as the datasets' readers take them.
    #[arg(long, requires = "rgb")]
    pub thermal: Vec<PathBuf>,
    /// 16-bit or float thermal: raw counts (or the float file's degrees) LO:HI mapped to
    /// [0, 1] (clipped). Default: the thermal rule the weights record (a dataset.yaml's
    /// `thermal:`), else HeatNet models use the Freiburg reference 21800:25000 and others each
    /// 16-bit frame's own min:max (a float thermal then needs this option).
    #[arg(long, value_parser = parse_range)]
    pub thermal_range: Option<(f64, f64)>,
    #[command(flatten)]
    pub run: super::RunFlags,
    /// Replace existing files that rtf did not write (or files of the dataset given with
    /// --classes). Without it such a file stops the run before anything is written; rtf's own
    /// outputs (a previous prediction) are replaced either way, inputs never.
    #[arg(long)]
    pub overwrite: bool,
    /// Skip a frame whose outputs all exist already (a stopped run re-run: outputs are only
    /// ever complete under their final names).
    #[arg(long)]
    pub skip_existing: bool,
    /// A progress line (frames, rate, ETA) every N frames when stderr is not a terminal; on a
    /// terminal a progress bar is redrawn instead.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..))]
    pub progress_every: u64,
    /// RGBA PNGs, thermal in the alpha channel (MF layout), or folders of them (their `.png`
    /// files, by name).
    #[arg(required_unless_present_any = ["rgb", "data"])]
    pub images: Vec<PathBuf>,
}

fn parse_range(text: &str) -> Result<(f64, f64), String> {
    let parsed = text
        .split_once(':')
        .and_then(|(a, b)| Some((a.trim().parse().ok()?, b.trim().parse().ok()?)));
    match parsed {
        Some((lo, hi)) if f64::is_finite(lo) && f64::is_finite(hi) && lo < hi => Ok((lo, hi)),
        _ => Err(format!("`{text}` is not LO:HI with LO < HI")),
    }
}

/// The outputs of every input (`--images` expanded, the `--rgb` pair), refused before
/// anything is written where they would land on an input, each other or a file rtf may not
/// replace (crate::output_guard).
fn plan(args: &Args) -> Result<Vec<predict::Planned>> {
    if args.rgb.len() != args.thermal.len() {
        bail!(
            "{} --rgb but {} --thermal: give one thermal file per RGB file, in the same order (nothing was written)",
            args.rgb.len(),
            args.thermal.len()
        );
    }
    let images = predict::expand_images(&args.images)?;
    let mut sources: Vec<PathBuf> = images.clone();
    sources.extend(args.rgb.iter().cloned());
    let mut inputs: Vec<&Path> = images.iter().map(PathBuf::as_path).collect();
    inputs.extend(args.rgb.iter().map(PathBuf::as_path));
    inputs.extend(args.thermal.iter().map(PathBuf::as_path));
    inputs.push(&args.weights);
    let mut guard = OutputGuard::new(args.overwrite).reading(inputs.iter().copied());
    if let Some(root) = args
        .classes
        .as_deref()
        .map(Path::new)
        .filter(|p| p.is_dir())
    {
        guard = guard.dataset(root);
    }
    let may_write = |path: &Path| guard.check(path, "predict").map_err(|e| format!("{e:#}"));
    Ok(predict::plan_outputs(
        &args.out,
        &sources,
        &inputs,
        args.logits,
        &may_write,
    )?)
}

/// `--data ROOT --split S`: the split opened (every file of it checked to exist and pair up)
/// and its frames' outputs planned by name; the outputs must be outside the dataset, so that
/// no file of it changes.
/// Also returns the class set to ask for: the dataset's.
fn plan_split(
    args: &Args,
    data: &Path,
) -> Result<(Vec<predict::Planned>, Arc<dyn FrameSource>, String)> {
    let dataset = super::open_dataset(data, "a prediction")?;
    let split = dataset.split(&args.split, false)?;
    let (root, out) = (resolved(data), resolved(&args.out));
    if out.starts_with(&root) {
        bail!(
            "--out {} is inside the dataset {}: predict into a folder outside it, so that no file of the dataset changes (nothing was written)",
            args.out.display(),
            data.display()
        );
    }
    let names: Vec<String> = (0..split.len())
        .map(|i| split.frame_name(i).to_string())
        .collect();
    let guard = OutputGuard::new(args.overwrite).reading([args.weights.as_path()]);
    let may_write = |path: &Path| guard.check(path, "predict").map_err(|e| format!("{e:#}"));
    let planned = predict::plan_frames(&args.out, &names, args.logits, &may_write)?;
    eprintln!(
        "predict: {} frames of split '{}' of {} ({})",
        split.len(),
        args.split,
        data.display(),
        dataset.layout_name()
    );
    let classes = match dataset.format() {
        rtf_data::DatasetFormat::Mf => "mf".to_string(),
        rtf_data::DatasetFormat::Freiburg => "freiburg".to_string(),
        _ => data.display().to_string(),
    };
    Ok((planned, split, classes))
}

pub fn run(args: Args) -> Result<()> {
    let (planned, split, data_classes) = match &args.data {
        Some(data) => {
            let (planned, split, classes) = plan_split(&args, data)?;
            (planned, Some(split), Some(classes))
        }
        None => (plan(&args)?, None, None),
    };
    let device = args.run.device()?;
    let trained = super::trained_on(&args.weights)?;
    // With --data the dataset's class set, unless --classes says otherwise.
    let asked = args.classes.clone().or(data_classes);
    let classes = predict::class_set(
        asked.as_deref(),
        &args.model,
        &args.weights,
        trained.as_ref(),
    )?;
    let network = load_network(&args.run.request(
        &args.model,
        &args.weights,
        classes.len() as i64,
        device,
    ))?
    .net;
    let pairs: Vec<(PathBuf, PathBuf)> = args
        .rgb
        .iter()
        .cloned()
        .zip(args.thermal.iter().cloned())
        .collect();
    let prediction = Prediction {
        out: &args.out,
        planned: &planned,
        skip_existing: args.skip_existing,
        pairs: &pairs,
        split: split.as_deref(),
        thermal_range: args.thermal_range,
        model: &args.model,
        trained: trained.as_ref(),
        network: network.as_ref(),
        classes: &classes,
        device,
    };
    let prepared = prediction.prepare()?;
    let skipped = prepared.skipped();
    let mut progress = Progress::new(prepared.len(), args.progress_every);
    prepared.run(&mut |plan| {
        println!("{} -> {}", plan.source.display(), plan.ids.display());
        progress.tick();
    })?;
    let summary = progress.finish();
    match args.skip_existing {
        true => eprintln!("{summary}; skipped {skipped} already predicted"),
        false => eprintln!("{summary}"),
    }
    Ok(())
}

/// Progress on stderr: a redrawn bar (frames, rate, ETA) on a terminal, else a plain line
/// every `every` frames and at the end, so that logs stay readable.
struct Progress {
    total: usize,
    done: usize,
    every: u64,
    start: std::time::Instant,
    bar: Option<indicatif::ProgressBar>,
}

impl Progress {
    fn new(total: usize, every: u64) -> Self {
        use std::io::IsTerminal;
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = indicatif::ProgressBar::new(total as u64);
            let style = indicatif::ProgressStyle::with_template(
                "predict [{bar:30}] {pos}/{len} frames, {per_sec}, ETA {eta}",
            )
            .expect("valid template")
            .progress_chars("=> ");
            bar.set_style(style);
            bar
        });
        Progress {
            total,
            done: 0,
            every,
            start: std::time::Instant::now(),
            bar,
        }
    }

    fn tick(&mut self) {
        self.done += 1;
        match &self.bar {
            Some(bar) => bar.inc(1),
            None if (self.done as u64).is_multiple_of(self.every) || self.done == self.total => {
                eprintln!("{}", self.line())
            }
            None => {}
        }
    }

    /// `predict: 300/2000 frames, 4.1 frames/s, elapsed 1m13s, ETA 6m55s`.
    fn line(&self) -> String {
        let elapsed = self.start.elapsed().as_secs_f64();
        let rate = self.done as f64 / elapsed.max(1e-9);
        let eta = (self.total - self.done) as f64 / rate.max(1e-9);
        format!(
            "predict: {}/{} frames, {rate:.1} frames/s, elapsed {}, ETA {}",
            self.done,
            self.total,
            duration(elapsed),
            duration(eta)
        )
    }

    /// Clears the bar; the summary line.
    fn finish(self) -> String {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
        let elapsed = self.start.elapsed().as_secs_f64();
        format!(
            "predicted {} frame(s) in {} ({:.1} frames/s)",
            self.done,
            duration(elapsed),
            self.done as f64 / elapsed.max(1e-9)
        )
    }
}

/// `1h02m03s`, `4m05s`, `12s`.
fn duration(seconds: f64) -> String {
    let s = seconds.round().min(1e9) as u64;
    match (s / 3600, s / 60 % 60, s % 60) {
        (0, 0, s) => format!("{s}s"),
        (0, m, s) => format!("{m}m{s:02}s"),
        (h, m, s) => format!("{h}h{m:02}m{s:02}s"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thermal_ranges() {
        assert_eq!(parse_range("21800:25000"), Ok((21800.0, 25000.0)));
        assert_eq!(parse_range("-5:40.5"), Ok((-5.0, 40.5)));
        assert!(parse_range("5:5").is_err());
    }
}
