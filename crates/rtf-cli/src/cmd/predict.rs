use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use rtf_core::ClassSet;
use rtf_data::images::{self, ThermalSamples};
use rtf_data::thermal::ThermalNormalisation;
use rtf_data::{Frame, TrainedOn};
use rtf_train::config::available_device;
use tch::Kind;

use rtf_models::Network;

use super::load_network;
use crate::output_guard::OutputGuard;

#[derive(clap::Args)]
pub struct Args {
    /// Network name (see `rtf models`).
    #[arg(long, default_value = "mfnet")]
    pub model: String,
    /// Weights (safetensors, reference names).
    #[arg(long)]
    pub weights: PathBuf,
    /// Output folder: <stem>.png (class ids), <stem>_color.png (palette), <stem>.npy (--logits).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the logits as float32 .npy of shape [classes, H, W].
    #[arg(long)]
    pub logits: bool,
    /// Class set of the weights: mf (9), freiburg (13), or a dataset root / dataset.yaml whose
    /// class set (its N classes and palette) the weights were trained on. Default: the class
    /// set the weights record (rtf train writes it), else from the model (HeatNet: freiburg,
    /// others mf). Refused when the weights record another class set.
    #[arg(long)]
    pub classes: Option<String>,
    /// RGB image (PNG or JPEG) of a pair given as separate files (with --thermal).
    #[arg(long, requires = "thermal")]
    pub rgb: Option<PathBuf>,
    /// Thermal image of a pair given as separate files (with --rgb): PNG (8/16-bit), TIFF
    /// (8/16-bit, 32-bit float) or .npy, as the datasets' readers take them.
    #[arg(long, requires = "rgb")]
    pub thermal: Option<PathBuf>,
    /// 16-bit or float thermal: raw counts (or the float file's degrees) LO:HI mapped to
    /// [0, 1] (clipped). Default: the thermal rule the weights record (a dataset.yaml's
    /// `thermal:`), else HeatNet models use the Freiburg reference 21800:25000 and others each
    /// 16-bit frame's own min:max (a float thermal then needs this option).
    #[arg(long, value_parser = parse_range)]
    pub thermal_range: Option<(f64, f64)>,
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// Run the fast inference path (BatchNorm folded, channels-last) in fp32 or bf16; default:
    /// the plain path.
    #[arg(long, value_parser = rtf_models::fast::Precision::parse_inference)]
    pub precision: Option<rtf_models::fast::Precision>,
    /// Channels the network sees (rgb_t, rgb, thermal; the others zeroed). Default: what the
    /// weights file records (rtf writes it), else all four; needed only for files without it.
    #[arg(long, value_parser = rtf_models::Modality::parse)]
    pub inputs: Option<rtf_models::Modality>,
    /// Load weights whose metadata names another network (e.g. renamed or converted files);
    /// names and shapes must still match.
    #[arg(long)]
    pub foreign_weights: bool,
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
    #[arg(required_unless_present = "rgb")]
    pub images: Vec<PathBuf>,
}

/// The class set of a dataset root in a described layout (dataset.yaml, MSRS, PST900, FMB) or
/// of a dataset.yaml file.
fn described_class_set(path: &Path) -> Result<ClassSet> {
    let described = rtf_data::dataset::recognise(path).filter(|f| f.is_described());
    let description = match described {
        _ if path.is_file() => rtf_data::description::read_description(path)?,
        Some(format) => rtf_data::Dataset::open_as(path, format)?
            .description()
            .cloned()
            .context("a described layout has a description")?,
        None => bail!(
            "--classes {}: not mf, freiburg, a dataset.yaml or a dataset root with one \
             (or an MSRS, PST900 or FMB root)",
            path.display()
        ),
    };
    eprintln!(
        "classes: {} ({}): {}",
        description.class_set.name,
        description.layout.name(),
        description.class_set.names().join(", ")
    );
    Ok(description.class_set)
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

fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// How `--thermal` becomes [0, 1]: `--thermal-range`, else the rule the weights were trained
/// with (except byte / 255, which leaves 16-bit files to the default), else the default.
#[derive(Clone, Copy)]
enum ThermalRule<'a> {
    Range(Option<(f64, f64)>),
    Trained(&'a ThermalNormalisation),
}

impl ThermalRule<'_> {
    /// The normalisation of one thermal image: 8-bit counts / 255; 16-bit counts clipped to the
    /// range (or the frame's min:max); temperatures clipped to the range (none: refused by the
    /// byte rule, naming the file).
    fn for_samples(self, samples: &ThermalSamples) -> ThermalNormalisation {
        let eight_bit = matches!(samples, ThermalSamples::Counts { bits: 8, .. });
        match self {
            Self::Trained(rule) => rule.clone(),
            Self::Range(_) if eight_bit => ThermalNormalisation::Byte,
            Self::Range(Some((lo, hi))) => ThermalNormalisation::Range { lo, hi, map: None },
            Self::Range(None) => match samples {
                ThermalSamples::Counts { .. } => ThermalNormalisation::MinMax,
                ThermalSamples::Degrees(_) => ThermalNormalisation::Byte,
            },
        }
    }
}

/// Reads a pair given as separate files into a frame, by the readers the datasets use
/// (rtf_data::images: RGB PNG or JPEG; thermal PNG, TIFF or .npy, grey stored as RGB read as
/// grey), so every file `rtf train` and `rtf eval` read, predict reads.
fn read_pair(rgb_path: &Path, thermal_path: &Path, rule: ThermalRule) -> Result<Frame> {
    let rgb = images::read_rgb(rgb_path)?;
    let thermal = images::read_thermal(thermal_path)?;
    if (thermal.width, thermal.height) != (rgb.width, rgb.height) {
        bail!(
            "{} is {}x{} but {} is {}x{}: the pair must be registered at the same size",
            thermal_path.display(),
            thermal.width,
            thermal.height,
            rgb_path.display(),
            rgb.width,
            rgb.height
        );
    }
    let values = rule
        .for_samples(&thermal.samples)
        .apply_samples(&thermal.samples, thermal_path)?;
    Ok(Frame {
        daytime: None,
        name: stem(rgb_path),
        width: rgb.width,
        height: rgb.height,
        rgb: rgb.rgb,
        thermal: values,
        label: None,
    })
}

/// One frame to predict: its input and its outputs in `--out`.
struct Planned {
    source: PathBuf,
    /// `<stem>.png`: class ids.
    ids: PathBuf,
    /// `<stem>_color.png`: the class set's palette.
    color: PathBuf,
    /// `<stem>.npy` (with `--logits`).
    logits: Option<PathBuf>,
}

impl Planned {
    fn outputs(&self) -> impl Iterator<Item = &Path> {
        [&self.ids, &self.color]
            .into_iter()
            .chain(self.logits.as_ref())
            .map(PathBuf::as_path)
    }

    /// Every output exists under its final name (written whole: temp + rename).
    fn done(&self) -> bool {
        self.outputs().all(Path::is_file)
    }
}

/// The images to predict: files as given, and for a folder its `.png` files by name (hidden
/// ones, such as a stopped run's temporary files, left out).
fn expand_images(images: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut all = Vec::with_capacity(images.len());
    for path in images {
        if !path.is_dir() {
            all.push(path.clone());
            continue;
        }
        let mut found = Vec::new();
        let entries =
            std::fs::read_dir(path).with_context(|| format!("cannot list {}", path.display()))?;
        for entry in entries {
            let entry = entry.with_context(|| format!("cannot list {}", path.display()))?;
            let file = entry.path();
            let png = file
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("png"));
            let hidden = entry.file_name().to_string_lossy().starts_with('.');
            if png && !hidden && file.is_file() {
                found.push(file);
            }
        }
        if found.is_empty() {
            bail!(
                "{}: a folder without .png images (predict takes RGBA PNGs, thermal in \
                 alpha, or folders of them)",
                path.display()
            );
        }
        found.sort();
        all.extend(found);
    }
    Ok(all)
}

/// Refuses a missing input or a directory (images are expanded before) and an `--out` that
/// is a file.
fn check_inputs(out: &Path, inputs: &[&Path]) -> Result<()> {
    if out.exists() && !out.is_dir() {
        bail!("--out {}: exists and is not a directory", out.display());
    }
    for input in inputs {
        if input.is_dir() {
            bail!("{}: is a directory, expected a file", input.display());
        }
        if !input.exists() {
            bail!("{}: no such file", input.display());
        }
    }
    Ok(())
}

/// The files written for the inputs `sources` (one per frame, named by its stem) in `out`:
/// `<stem>.png`, `<stem>_color.png` and, with `logits`, `<stem>.npy`. Refuses, before anything
/// is read or written, an output that two inputs would share and an output that is one of
/// `inputs` (every file the run reads), so that no input is overwritten.
fn plan_outputs(
    out: &Path,
    sources: &[PathBuf],
    inputs: &[&Path],
    logits: bool,
    guard: &OutputGuard,
) -> Result<Vec<Planned>> {
    check_inputs(out, inputs)?;
    let mut writer: std::collections::HashMap<PathBuf, &Path> = Default::default();
    let mut planned = Vec::with_capacity(sources.len());
    for source in sources {
        let stem = stem(source);
        if stem.is_empty() {
            bail!(
                "{}: no file name to name the outputs after",
                source.display()
            );
        }
        let names = [
            format!("{stem}.png"),
            format!("{stem}_color.png"),
            format!("{stem}.npy"),
        ];
        for name in &names[..if logits { 3 } else { 2 }] {
            let path = out.join(name);
            if let Some(other) = writer.insert(path.clone(), source) {
                bail!(
                    "{} and {} would both write {}: give the inputs distinct file names or \
                     predict them into separate --out folders (nothing was written)",
                    other.display(),
                    source.display(),
                    path.display()
                );
            }
            guard.check(&path, "predict")?;
        }
        let [ids, color, npy] = names.map(|n| out.join(n));
        planned.push(Planned {
            source: source.clone(),
            ids,
            color,
            logits: logits.then_some(npy),
        });
    }
    Ok(planned)
}

/// Width, height and whether the file is an 8-bit RGBA PNG, from its header alone.
fn rgba_header(path: &Path) -> Option<(usize, usize, bool)> {
    use image::ImageDecoder;
    let decoder = image::ImageReader::open(path)
        .ok()?
        .with_guessed_format()
        .ok()?
        .into_decoder()
        .ok()?;
    let (w, h) = decoder.dimensions();
    let rgba = decoder.color_type() == image::ColorType::Rgba8;
    Some((w as usize, h as usize, rgba))
}

/// Checks, before anything is written and without decoding, that every image is an 8-bit
/// RGBA PNG (a file whose header says otherwise is decoded for the reader's own error) and
/// that a frame of each size fits in memory.
fn preflight(images: &[&Path], network: &dyn Network, device: tch::Device) -> Result<()> {
    let mut sizes: std::collections::BTreeMap<(usize, usize), &Path> = Default::default();
    for &path in images {
        let (w, h) = match rgba_header(path) {
            Some((w, h, true)) => (w, h),
            _ => {
                let frame = rtf_data::mf::read_mf_image(path)?;
                (frame.width, frame.height)
            }
        };
        sizes.entry((h, w)).or_insert(path);
    }
    for ((h, w), path) in sizes {
        rtf_eval::evaluate::check_memory(network, 1, h, w, device)
            .with_context(|| path.display().to_string())?;
    }
    Ok(())
}

/// Removes the temporary files (`.<output>.tmp-<pid>.<ext>`, see [`rtf_core::write_atomic`])
/// that a stopped run left beside the planned outputs, when their process is gone. Returns
/// how many.
fn remove_stale_temporaries(out: &Path, planned: &[Planned]) -> usize {
    let names: std::collections::HashSet<String> = planned
        .iter()
        .flat_map(Planned::outputs)
        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    let Ok(entries) = std::fs::read_dir(out) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let file = entry.file_name().to_string_lossy().into_owned();
        let Some((name, rest)) = file.strip_prefix('.').and_then(|f| f.rsplit_once(".tmp-")) else {
            continue;
        };
        let pid = rest.split('.').next().and_then(|p| p.parse::<i32>().ok());
        // SAFETY: kill with signal 0 only checks whether the process exists.
        let alive = pid.is_some_and(|pid| unsafe { libc::kill(pid, 0) } == 0);
        if names.contains(name) && !alive && std::fs::remove_file(entry.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

pub fn run(args: Args) -> Result<()> {
    let images = expand_images(&args.images)?;
    let mut sources: Vec<PathBuf> = images.clone();
    sources.extend(args.rgb.clone());
    let mut inputs: Vec<&Path> = images.iter().map(PathBuf::as_path).collect();
    inputs.extend(args.rgb.as_deref());
    inputs.extend(args.thermal.as_deref());
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
    let planned = plan_outputs(&args.out, &sources, &inputs, args.logits, &guard)?;
    let device = available_device(&args.device).map_err(anyhow::Error::msg)?;
    let trained = super::trained_on(&args.weights)?;
    let classes = class_set(&args, trained.as_ref())?;
    let network = load_network(
        &args.model,
        classes.len() as i64,
        &args.weights,
        device,
        args.precision,
        args.foreign_weights,
        args.inputs,
    )?
    .net;
    rtf_eval::evaluate::install_quiet_panic_hook();
    let todo: Vec<&Planned> = planned
        .iter()
        .filter(|p| !(args.skip_existing && p.done()))
        .collect();
    let pair = read_pair_checked(&args, trained.as_ref(), &todo, network.as_ref(), device)?;
    let mf: Vec<&Path> = todo
        .iter()
        .map(|p| p.source.as_path())
        .filter(|p| Some(*p) != args.rgb.as_deref())
        .collect();
    preflight(&mf, network.as_ref(), device)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let stale = remove_stale_temporaries(&args.out, &planned);
    if stale > 0 {
        eprintln!(
            "removed {stale} temporary file(s) a stopped run left in {}",
            args.out.display()
        );
    }
    let skipped = planned.len() - todo.len();
    let summary = predict_all(&args, todo, pair, network.as_ref(), &classes, device)?;
    match args.skip_existing {
        true => eprintln!("{summary}; skipped {skipped} already predicted"),
        false => eprintln!("{summary}"),
    }
    Ok(())
}

/// Predicts `todo` one frame at a time (read, run, written and dropped: memory bounded by a
/// frame) under a progress display; returns the summary line.
fn predict_all(
    args: &Args,
    todo: Vec<&Planned>,
    mut pair: Option<Frame>,
    network: &dyn Network,
    classes: &ClassSet,
    device: tch::Device,
) -> Result<String> {
    let mut progress = Progress::new(todo.len(), args.progress_every);
    let _guard = tch::no_grad_guard();
    for plan in todo {
        let frame = match pair.take() {
            Some(frame) if Some(plan.source.as_path()) == args.rgb.as_deref() => frame,
            kept => {
                pair = kept;
                rtf_data::mf::read_mf_image(&plan.source)?
            }
        };
        predict_frame(network, &frame, plan, classes, device)?;
        println!("{} -> {}", plan.source.display(), plan.ids.display());
        progress.tick();
    }
    Ok(progress.finish())
}

/// The separate RGB + thermal pair (one frame, read whole and its memory checked before
/// anything is written), unless it is not given or skipped.
fn read_pair_checked(
    args: &Args,
    trained: Option<&TrainedOn>,
    todo: &[&Planned],
    network: &dyn Network,
    device: tch::Device,
) -> Result<Option<Frame>> {
    let (Some(rgb), Some(thermal)) = (&args.rgb, &args.thermal) else {
        return Ok(None);
    };
    if !todo.iter().any(|p| &p.source == rgb) {
        return Ok(None);
    }
    let frame = read_pair(rgb, thermal, thermal_rule(args, trained))?;
    rtf_eval::evaluate::check_memory(network, 1, frame.height, frame.width, device)
        .with_context(|| rgb.display().to_string())?;
    Ok(Some(frame))
}

/// Runs the network on one frame and writes its outputs, each whole (temp + rename).
fn predict_frame(
    network: &dyn Network,
    frame: &Frame,
    plan: &Planned,
    classes: &ClassSet,
    device: tch::Device,
) -> Result<()> {
    let source = plan.source.display().to_string();
    let input = rtf_eval::figure::frame_input(frame, network.input_convention()).to_device(device);
    let logits = rtf_eval::evaluate::logits(network, &input)
        .with_context(|| source.clone())?
        .get(0)
        .to_kind(Kind::Float)
        .to_device(tch::Device::Cpu);
    let ids = Vec::<u8>::try_from(logits.argmax(0, false).to_kind(Kind::Uint8).flatten(0, -1))?;
    let (w, h) = (frame.width as u32, frame.height as u32);
    let colors = classes.colorize(&ids);
    // Ids as the dataset has them (its label values), colours by the network's outputs.
    let values: Vec<u8> = ids.iter().map(|&i| classes.label_value(i)).collect();
    save_png(&plan.ids, w, h, 1, &values)?;
    save_png(&plan.color, w, h, 3, &colors)?;
    if let Some(npy) = &plan.logits {
        let shape: Vec<usize> = logits.size().iter().map(|&d| d as usize).collect();
        let values = Vec::<f32>::try_from(logits.flatten(0, -1))?;
        rtf_core::npy::write_f32(npy, &shape, &values)
            .with_context(|| format!("writing {}", npy.display()))?;
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

/// `--classes`, else the class set the weights record (announced), else the model's; a
/// `--classes` other than the weights' record is refused naming both.
fn class_set(args: &Args, trained: Option<&TrainedOn>) -> Result<ClassSet> {
    let classes = match (args.classes.as_deref(), trained) {
        (Some("mf"), _) => ClassSet::mf(),
        (Some("freiburg"), _) => ClassSet::freiburg(),
        (Some(other), _) => described_class_set(Path::new(other))?,
        (None, Some(t)) => {
            let list = rtf_data::trained_on::list(&t.classes);
            eprintln!("classes: the weights' {list}");
            t.classes.clone()
        }
        (None, None) if args.model.starts_with("heatnet") => ClassSet::freiburg(),
        (None, None) => ClassSet::mf(),
    };
    if let (Some(t), Some(given)) = (trained, &args.classes) {
        let hint = rtf_data::trained_on::WEIGHTS_HINT;
        t.check_data(&args.weights, Path::new(given), &classes, hint)?;
    }
    Ok(classes)
}

/// `--thermal-range`, else the weights' rule (announced), else the model's default.
fn thermal_rule<'a>(args: &Args, trained: Option<&'a TrainedOn>) -> ThermalRule<'a> {
    let rule = trained.and_then(|t| t.thermal.as_ref());
    match (args.thermal_range, rule) {
        (None, Some(rule)) if *rule != ThermalNormalisation::Byte => {
            eprintln!("thermal: the weights' rule, {}", rule.describe());
            ThermalRule::Trained(rule)
        }
        (range, _) => ThermalRule::Range(
            range.or(args
                .model
                .starts_with("heatnet")
                .then_some((21800.0, 25000.0))),
        ),
    }
}

/// Writes an 8-bit PNG tagged as rtf's output (what a later run may replace without
/// --overwrite: crate::output_guard).
fn save_png(path: &Path, width: u32, height: u32, channels: usize, samples: &[u8]) -> Result<()> {
    let bytes =
        rtf_data::pngio::encode_png_u8_tagged(width as usize, height as usize, channels, samples)
            .map_err(anyhow::Error::msg)?;
    rtf_core::write_bytes_atomic(path, &bytes)
        .with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thermal_ranges() {
        assert_eq!(parse_range("21800:25000"), Ok((21800.0, 25000.0)));
        assert_eq!(parse_range("-5:40.5"), Ok((-5.0, 40.5)));
        assert!(parse_range("5:5").is_err());
        let counts = ThermalSamples::Counts {
            bits: 16,
            values: vec![100, 200, 300],
        };
        let unit = |rule: ThermalRule| {
            rule.for_samples(&counts)
                .apply_samples(&counts, Path::new("t.png"))
                .unwrap()
        };
        assert_eq!(unit(ThermalRule::Range(None)), vec![0.0, 0.5, 1.0]);
        assert_eq!(
            unit(ThermalRule::Range(Some((200.0, 250.0)))),
            vec![0.0, 0.0, 1.0]
        );
        let degrees = ThermalSamples::Degrees(vec![20.0, 30.0]);
        let err = ThermalRule::Range(None)
            .for_samples(&degrees)
            .apply_samples(&degrees, Path::new("t.tiff"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("t.tiff") && err.contains("needs a rule"),
            "{err}"
        );
    }
}
