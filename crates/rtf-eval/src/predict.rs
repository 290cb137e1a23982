//! Prediction of image files (`rtf predict`): MF-layout RGBA PNGs (thermal in alpha), a
//! separate RGB + thermal pair, or every frame of a dataset split (any layout, read by its
//! readers; outputs named by the frame's name, a folder per `/`), each frame's class ids,
//! palette colours and, if asked, logits written beside it. Everything that can refuse a run does so before a file is written
//! ([`plan_outputs`], [`Prediction::prepare`]): outputs two inputs would share, an output
//! that is an input, a file that is not an RGBA PNG, a frame too large for memory. Frames are
//! then read, run and written one at a time (memory bounded by a frame), each output written
//! whole (temp + rename), so a stopped run leaves only complete outputs and `skip_existing`
//! continues it. It sits above [`crate::evaluate`] and [`crate::figure`], whose forward and
//! input it shares with evaluation.

use rtf_data::thermal::Normalise;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};

use rtf_core::refusal::{refused, Refusal};
use rtf_core::ClassSet;
use rtf_data::images::{self, ThermalSamples};
use rtf_data::thermal::ThermalNormalisation;
use rtf_data::{DataError, Frame, TrainedOn};
use rtf_models::Network;
use tch::Kind;

use crate::evaluate::EvalError;

/// Why a prediction stopped. Each message reads as `rtf predict` says it; a wrapped error
/// keeps its own message as the source.
#[derive(Debug, thiserror::Error)]
pub enum PredictError {
    /// What was asked cannot be predicted (nothing was written), or failed on the file or
    /// frame the message names.
    #[error(transparent)]
    Request(#[from] Refusal),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error(transparent)]
    Tensor(#[from] tch::TchError),
}

/// How a thermal file becomes [0, 1]: a given range, else the rule the weights were trained
/// with (except byte / 255, which leaves 16-bit files to the default), else the default.
#[derive(Clone, Copy)]
pub enum ThermalRule<'a> {
    Range(Option<(f64, f64)>),
    Trained(&'a ThermalNormalisation),
}

impl ThermalRule<'_> {
    /// The normalisation of one thermal image: 8-bit counts / 255; 16-bit counts clipped to the
    /// range (or the frame's min:max); temperatures clipped to the range (none: refused by the
    /// byte rule, naming the file).
    pub fn for_samples(self, samples: &ThermalSamples) -> ThermalNormalisation {
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

/// `range` (`--thermal-range`), else the weights' rule (announced), else the model's default
/// (HeatNet: the Freiburg reference 21800:25000; others: each frame's min:max).
pub fn thermal_rule<'a>(
    range: Option<(f64, f64)>,
    model: &str,
    trained: Option<&'a TrainedOn>,
) -> ThermalRule<'a> {
    let rule = trained.and_then(|t| t.thermal.as_ref());
    match (range, rule) {
        (None, Some(rule)) if *rule != ThermalNormalisation::Byte => {
            eprintln!("thermal: the weights' rule, {}", rule.describe());
            ThermalRule::Trained(rule)
        }
        (range, _) => {
            ThermalRule::Range(range.or(model.starts_with("heatnet").then_some((21800.0, 25000.0))))
        }
    }
}

/// The class set of a dataset root in a described layout (dataset.yaml, MSRS, PST900, FMB) or
/// of a dataset.yaml file.
fn described_class_set(path: &Path) -> Result<ClassSet, PredictError> {
    let described = rtf_data::dataset::recognise(path).filter(|f| f.is_described());
    let description = match described {
        _ if path.is_file() => rtf_data::description::read_description(path)?,
        Some(format) => rtf_data::Dataset::open_as(path, format)?
            .description()
            .cloned()
            .ok_or_else(|| Refusal::Refused("a described layout has a description".into()))?,
        None => {
            return Err(refused(format!(
                "--classes {}: not mf, freiburg, a dataset.yaml or a dataset root with one \
                 (or an MSRS, PST900 or FMB root)",
                path.display()
            )))
        }
    };
    eprintln!(
        "classes: {} ({}): {}",
        description.class_set.name,
        description.layout.name(),
        description.class_set.names().join(", ")
    );
    Ok(description.class_set)
}

/// The class set of `weights`: `asked` (`--classes`: mf, freiburg, a described root or
/// dataset.yaml), else the one the weights record (announced), else the model's (HeatNet:
/// Freiburg's, others MF's); an `asked` other than the weights' record is refused naming both.
pub fn class_set(
    asked: Option<&str>,
    model: &str,
    weights: &Path,
    trained: Option<&TrainedOn>,
) -> Result<ClassSet, PredictError> {
    let classes = match (asked, trained) {
        (Some("mf"), _) => ClassSet::mf(),
        (Some("freiburg"), _) => ClassSet::freiburg(),
        (Some(other), _) => described_class_set(Path::new(other))?,
        (None, Some(t)) => {
            let list = rtf_data::trained_on::list(&t.classes);
            eprintln!("classes: the weights' {list}");
            t.classes.clone()
        }
        (None, None) if model.starts_with("heatnet") => ClassSet::freiburg(),
        (None, None) => ClassSet::mf(),
    };
    if let (Some(t), Some(given)) = (trained, asked) {
        let hint = rtf_data::trained_on::WEIGHTS_HINT;
        rtf_data::trained_on::check_data(t, weights, Path::new(given), &classes, hint)?;
    }
    Ok(classes)
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Reads a pair given as separate files into a frame, by the readers the datasets use
/// (rtf_data::images: RGB PNG or JPEG; thermal PNG, TIFF or .npy, grey stored as RGB read as
/// grey), so every file `rtf train` and `rtf eval` read, predict reads.
pub fn read_pair(
    rgb_path: &Path,
    thermal_path: &Path,
    rule: ThermalRule,
) -> Result<Frame, PredictError> {
    let rgb = images::read_rgb(rgb_path)?;
    let thermal = images::read_thermal(thermal_path)?;
    if (thermal.width, thermal.height) != (rgb.width, rgb.height) {
        return Err(refused(format!(
            "{} is {}x{} but {} is {}x{}: the pair must be registered at the same size",
            thermal_path.display(),
            thermal.width,
            thermal.height,
            rgb_path.display(),
            rgb.width,
            rgb.height
        )));
    }
    let pair = PairSamples {
        name: stem(rgb_path),
        width: rgb.width,
        height: rgb.height,
        rgb: rgb.rgb,
        thermal: &thermal.samples,
    };
    pair.into_frame(rule, thermal_path)
}

/// An RGB + thermal pair of one size as read (interleaved RGB bytes, thermal samples), before
/// the thermal rule: what [`read_pair`] reads from files and rtf-py takes from arrays.
pub struct PairSamples<'a> {
    pub name: String,
    pub width: usize,
    pub height: usize,
    /// Interleaved R, G, B bytes (`3 * width * height`).
    pub rgb: Vec<u8>,
    pub thermal: &'a ThermalSamples,
}

impl PairSamples<'_> {
    /// The frame, its thermal mapped to [0, 1] by `rule`; `source` names the thermal in errors.
    pub fn into_frame(self, rule: ThermalRule, source: &Path) -> Result<Frame, PredictError> {
        let values = rule
            .for_samples(self.thermal)
            .apply_samples(self.thermal, source)?;
        Ok(Frame {
            daytime: None,
            name: self.name,
            width: self.width,
            height: self.height,
            rgb: self.rgb,
            thermal: values,
            label: None,
        })
    }
}

/// One frame to predict: its input and its outputs in the output folder.
pub struct Planned {
    /// The input file, or for a dataset frame its name.
    pub source: PathBuf,
    /// The frame's index in the split predicted ([`Prediction::split`]); `None` for files.
    pub frame: Option<usize>,
    /// `<stem>.png`: class ids.
    pub ids: PathBuf,
    /// `<stem>_color.png`: the class set's palette.
    pub color: PathBuf,
    /// `<stem>.npy` (with logits asked).
    pub logits: Option<PathBuf>,
}

impl Planned {
    pub fn outputs(&self) -> impl Iterator<Item = &Path> {
        [&self.ids, &self.color]
            .into_iter()
            .chain(self.logits.as_ref())
            .map(PathBuf::as_path)
    }

    /// Every output exists under its final name (written whole: temp + rename).
    pub fn done(&self) -> bool {
        self.outputs().all(Path::is_file)
    }
}

/// The `.png` files of a folder, by name (hidden ones, such as a stopped run's temporary
/// files, left out).
fn folder_images(path: &Path) -> Result<Vec<PathBuf>, PredictError> {
    let listing = |e| Refusal::because(format!("cannot list {}", path.display()), e);
    let mut found = Vec::new();
    for entry in std::fs::read_dir(path).map_err(listing)? {
        let entry = entry.map_err(listing)?;
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
        return Err(refused(format!(
            "{}: a folder without .png images (predict takes RGBA PNGs, thermal in \
             alpha, or folders of them)",
            path.display()
        )));
    }
    found.sort();
    Ok(found)
}

/// The images to predict: files as given, and for a folder its `.png` files by name (hidden
/// ones, such as a stopped run's temporary files, left out).
pub fn expand_images(images: &[PathBuf]) -> Result<Vec<PathBuf>, PredictError> {
    let mut all = Vec::with_capacity(images.len());
    for path in images {
        match path.is_dir() {
            true => all.extend(folder_images(path)?),
            false => all.push(path.clone()),
        }
    }
    Ok(all)
}

/// Refuses a missing input or a directory (images are expanded before) and an `out` that
/// is a file.
fn check_inputs(out: &Path, inputs: &[&Path]) -> Result<(), PredictError> {
    if out.exists() && !out.is_dir() {
        return Err(refused(format!(
            "--out {}: exists and is not a directory",
            out.display()
        )));
    }
    for input in inputs {
        if input.is_dir() {
            return Err(refused(format!(
                "{}: is a directory, expected a file",
                input.display()
            )));
        }
        if !input.exists() {
            return Err(refused(format!("{}: no such file", input.display())));
        }
    }
    Ok(())
}

/// The files written for the inputs `sources` (one per frame, named by its stem) in `out`:
/// `<stem>.png`, `<stem>_color.png` and, with `logits`, `<stem>.npy`. Refuses, before anything
/// is read or written, an output that two inputs would share and an output that is one of
/// `inputs` (every file the run reads), so that no input is overwritten; `may_write` refuses
/// (with its message) an output the caller's policy keeps (rtf-cli's output guard).
pub fn plan_outputs(
    out: &Path,
    sources: &[PathBuf],
    inputs: &[&Path],
    logits: bool,
    may_write: &dyn Fn(&Path) -> Result<(), String>,
) -> Result<Vec<Planned>, PredictError> {
    check_inputs(out, inputs)?;
    let named = sources.iter().map(|source| {
        let stem = stem(source);
        if stem.is_empty() {
            return Err(refused(format!(
                "{}: no file name to name the outputs after",
                source.display()
            )));
        }
        Ok((stem, source.clone(), None))
    });
    let named: Vec<_> = named.collect::<Result<_, PredictError>>()?;
    plan_named(out, named, logits, may_write)
}

/// The outputs of every frame of a dataset split, named by the frame's name (`names[i]` is
/// frame `i`'s): a frame `set00/V000/I00050` writes `out/set00/V000/I00050.png` and its
/// `_color.png` (and `.npy`), so same-named files of different sequences never collide. Two
/// frames that would write one file, or a name that is not a relative path, are refused
/// before anything is written.
pub fn plan_frames(
    out: &Path,
    names: &[String],
    logits: bool,
    may_write: &dyn Fn(&Path) -> Result<(), String>,
) -> Result<Vec<Planned>, PredictError> {
    check_inputs(out, &[])?;
    let named = names.iter().enumerate().map(|(i, name)| {
        let relative = Path::new(name);
        let plain = relative
            .components()
            .all(|c| matches!(c, std::path::Component::Normal(_)));
        if name.is_empty() || !plain {
            return Err(refused(format!(
                "frame '{name}': its name is not a relative path to write its outputs under"
            )));
        }
        Ok((name.clone(), PathBuf::from(name), Some(i)))
    });
    let named: Vec<_> = named.collect::<Result<_, PredictError>>()?;
    plan_named(out, named, logits, may_write)
}

/// [`plan_outputs`] of (output stem below `out`, source, frame index) triples.
fn plan_named(
    out: &Path,
    named: Vec<(String, PathBuf, Option<usize>)>,
    logits: bool,
    may_write: &dyn Fn(&Path) -> Result<(), String>,
) -> Result<Vec<Planned>, PredictError> {
    let mut writer: HashMap<PathBuf, PathBuf> = Default::default();
    let mut planned = Vec::with_capacity(named.len());
    for (stem, source, frame) in named {
        let names = [
            format!("{stem}.png"),
            format!("{stem}_color.png"),
            format!("{stem}.npy"),
        ];
        for name in &names[..if logits { 3 } else { 2 }] {
            let path = out.join(name);
            if let Some(other) = writer.insert(path.clone(), source.clone()) {
                return Err(refused(format!(
                    "{} and {} would both write {}: give the inputs distinct file names or \
                     predict them into separate --out folders (nothing was written)",
                    other.display(),
                    source.display(),
                    path.display()
                )));
            }
            may_write(&path).map_err(Refusal::Refused)?;
        }
        let [ids, color, npy] = names.map(|n| out.join(n));
        planned.push(Planned {
            source,
            frame,
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
fn preflight(
    images: &[&Path],
    network: &dyn Network,
    device: tch::Device,
) -> Result<(), PredictError> {
    let mut sizes: BTreeMap<(usize, usize), &Path> = Default::default();
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
        crate::evaluate::check_memory(network, 1, h, w, device)
            .map_err(|e| Refusal::because(path.display().to_string(), e))?;
    }
    Ok(())
}

/// Removes the temporary files (`.<output>.tmp-<pid>.<ext>`, see [`rtf_core::write_atomic`])
/// that a stopped run left beside the planned outputs, when their process is gone. Returns
/// how many.
fn remove_stale_temporaries(out: &Path, planned: &[Planned]) -> usize {
    let names: HashSet<String> = planned
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

/// A prediction run, its outputs planned ([`plan_outputs`]).
pub struct Prediction<'a> {
    pub out: &'a Path,
    pub planned: &'a [Planned],
    /// Frames whose outputs all exist already are skipped.
    pub skip_existing: bool,
    /// The separate RGB + thermal pairs given (each RGB file is one of the planned sources).
    pub pairs: &'a [(PathBuf, PathBuf)],
    /// The dataset split whose frames the plans with a frame index are ([`plan_frames`]).
    pub split: Option<&'a dyn rtf_data::FrameSource>,
    /// `--thermal-range` for the pair ([`thermal_rule`]).
    pub thermal_range: Option<(f64, f64)>,
    /// The network's name (its default thermal rule).
    pub model: &'a str,
    /// What the weights record (class set, thermal rule).
    pub trained: Option<&'a TrainedOn>,
    pub network: &'a dyn Network,
    pub classes: &'a ClassSet,
    pub device: tch::Device,
}

/// A prediction checked and ready to run: the frames to do.
pub struct Prepared<'p, 'a> {
    job: &'p Prediction<'a>,
    todo: Vec<&'p Planned>,
    /// How the pairs' thermal becomes [0, 1] (decided, and said, once).
    rule: Option<ThermalRule<'a>>,
}

impl<'a> Prediction<'a> {
    /// Every check before a file is written: each pair read whole and its memory checked, the
    /// header and memory of every RGBA PNG; then the output folder made, and the temporary
    /// files a stopped run left there removed (said on stderr).
    pub fn prepare(&self) -> Result<Prepared<'_, 'a>, PredictError> {
        crate::evaluate::install_quiet_panic_hook();
        let todo: Vec<&Planned> = self
            .planned
            .iter()
            .filter(|p| !(self.skip_existing && p.done()))
            .collect();
        let rule = (!self.pairs.is_empty())
            .then(|| thermal_rule(self.thermal_range, self.model, self.trained));
        if let Some(rule) = rule {
            self.check_pairs(&todo, rule)?;
        }
        let mf: Vec<&Path> = todo
            .iter()
            .filter(|p| p.frame.is_none() && self.thermal_of(&p.source).is_none())
            .map(|p| p.source.as_path())
            .collect();
        preflight(&mf, self.network, self.device)?;
        self.check_split_memory(&todo)?;
        std::fs::create_dir_all(self.out)
            .map_err(|e| Refusal::because(format!("cannot create {}", self.out.display()), e))?;
        let stale = remove_stale_temporaries(self.out, self.planned);
        if stale > 0 {
            eprintln!(
                "removed {stale} temporary file(s) a stopped run left in {}",
                self.out.display()
            );
        }
        Ok(Prepared {
            job: self,
            todo,
            rule,
        })
    }

    /// A dataset split's first frame to predict, read whole (its files' problems named) and
    /// its memory checked, before anything is written.
    fn check_split_memory(&self, todo: &[&Planned]) -> Result<(), PredictError> {
        let (Some(split), Some(first)) = (self.split, todo.iter().find_map(|p| p.frame)) else {
            return Ok(());
        };
        let frame = split.load_unlabelled(first)?;
        crate::evaluate::check_memory(self.network, 1, frame.height, frame.width, self.device)
            .map_err(|e| Refusal::because(format!("frame '{}'", frame.name), e))?;
        Ok(())
    }

    /// The thermal partner of `rgb` when it is the RGB file of a pair given.
    fn thermal_of(&self, rgb: &Path) -> Option<&Path> {
        (self.pairs.iter())
            .find(|(r, _)| r == rgb)
            .map(|(_, t)| t.as_path())
    }

    /// Every pair to predict read whole (the two files' problems named) and its memory
    /// checked, before anything is written; read again when its turn comes (memory bounded
    /// by a frame).
    fn check_pairs(&self, todo: &[&Planned], rule: ThermalRule) -> Result<(), PredictError> {
        for plan in todo {
            let Some(thermal) = self.thermal_of(&plan.source) else {
                continue;
            };
            let frame = read_pair(&plan.source, thermal, rule)?;
            crate::evaluate::check_memory(self.network, 1, frame.height, frame.width, self.device)
                .map_err(|e| Refusal::because(plan.source.display().to_string(), e))?;
        }
        Ok(())
    }
}

impl Prepared<'_, '_> {
    /// The frames to predict (the planned ones less those skipped).
    pub fn len(&self) -> usize {
        self.todo.len()
    }

    pub fn is_empty(&self) -> bool {
        self.todo.is_empty()
    }

    /// The planned frames skipped as already predicted.
    pub fn skipped(&self) -> usize {
        self.job.planned.len() - self.todo.len()
    }

    /// Predicts the frames one at a time (read, run, written and dropped: memory bounded by
    /// a frame); `done` hears of each once its outputs are written.
    pub fn run(self, done: &mut dyn FnMut(&Planned)) -> Result<(), PredictError> {
        let job = self.job;
        let _guard = tch::no_grad_guard();
        for plan in self.todo {
            let pair = job.thermal_of(&plan.source).zip(self.rule);
            let frame = match (plan.frame.zip(job.split), pair) {
                (Some((index, split)), _) => split.load_unlabelled(index)?,
                (None, Some((thermal, rule))) => read_pair(&plan.source, thermal, rule)?,
                (None, None) => rtf_data::mf::read_mf_image(&plan.source)?,
            };
            predict_frame(job.network, &frame, plan, job.classes, job.device)?;
            done(plan);
        }
        Ok(())
    }
}

/// One frame's logits [classes, H, W], float32 on the CPU, as `rtf predict` computes them
/// (the frame's input after the network's convention, padded to its size multiple); rtf-py's
/// `net.logits` is this function.
pub fn frame_logits(
    network: &dyn Network,
    frame: &Frame,
    device: tch::Device,
) -> Result<tch::Tensor, EvalError> {
    let input = crate::figure::frame_input(frame, network.input_convention()).to_device(device);
    Ok(crate::evaluate::logits(network, &input)?
        .get(0)
        .f_to_kind(Kind::Float)?
        .f_to_device(tch::Device::Cpu)?)
}

/// The class of each pixel of `logits` [classes, H, W] (row-major): output indices.
pub fn class_ids(logits: &tch::Tensor) -> Result<Vec<u8>, PredictError> {
    Ok(Vec::<u8>::try_from(
        logits
            .f_argmax(0, false)?
            .f_to_kind(Kind::Uint8)?
            .flatten(0, -1),
    )?)
}

/// Runs the network on one frame and writes its outputs, each whole (temp + rename).
fn predict_frame(
    network: &dyn Network,
    frame: &Frame,
    plan: &Planned,
    classes: &ClassSet,
    device: tch::Device,
) -> Result<(), PredictError> {
    let source = plan.source.display().to_string();
    if let Some(folder) = plan.ids.parent() {
        std::fs::create_dir_all(folder)
            .map_err(|e| Refusal::because(format!("cannot create {}", folder.display()), e))?;
    }
    let logits = frame_logits(network, frame, device).map_err(|e| Refusal::because(source, e))?;
    let ids = class_ids(&logits)?;
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
            .map_err(|e| Refusal::because(format!("writing {}", npy.display()), e))?;
    }
    Ok(())
}

/// Writes an 8-bit PNG tagged as rtf's output (what a later run may replace without
/// --overwrite: rtf-cli's output guard).
fn save_png(
    path: &Path,
    width: u32,
    height: u32,
    channels: usize,
    samples: &[u8],
) -> Result<(), PredictError> {
    let bytes =
        rtf_data::pngio::encode_png_u8_tagged(width as usize, height as usize, channels, samples)
            .map_err(Refusal::Refused)?;
    rtf_core::write_bytes_atomic(path, &bytes)
        .map_err(|e| Refusal::because(format!("writing {}", path.display()), e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thermal_rules() {
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
