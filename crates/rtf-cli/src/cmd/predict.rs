use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use rtf_core::ClassSet;
use rtf_data::pngio::{read_png, PngImage, Samples};
use rtf_data::thermal::ThermalNormalisation;
use rtf_data::{Frame, TrainedOn};
use rtf_train::config::available_device;
use tch::Kind;

use super::load_network;

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
    /// RGB image of a pair given as separate files (with --thermal).
    #[arg(long, requires = "thermal")]
    pub rgb: Option<PathBuf>,
    /// Thermal image (8- or 16-bit grey PNG) of a pair given as separate files (with --rgb).
    #[arg(long, requires = "rgb")]
    pub thermal: Option<PathBuf>,
    /// 16-bit thermal: raw counts LO:HI mapped to [0, 1] (clipped). Default: the thermal rule
    /// the weights record (a dataset.yaml's `thermal:`), else HeatNet models use the Freiburg
    /// reference 21800:25000 and others each frame's own min:max.
    #[arg(long, value_parser = parse_range)]
    pub thermal_range: Option<(u16, u16)>,
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// Run the fast inference path (BatchNorm folded, channels-last) in fp32 or bf16; default:
    /// the plain path.
    #[arg(long)]
    pub precision: Option<rtf_models::fast::Precision>,
    /// Channels the network sees (rgb_t, rgb, thermal; the others zeroed). Default: what the
    /// weights file records (rtf writes it), else all four; needed only for files without it.
    #[arg(long, value_parser = rtf_models::Modality::parse)]
    pub inputs: Option<rtf_models::Modality>,
    /// Load weights whose metadata names another network (e.g. renamed or converted files);
    /// names and shapes must still match.
    #[arg(long)]
    pub foreign_weights: bool,
    /// RGBA PNGs, thermal in the alpha channel (MF layout).
    #[arg(required_unless_present = "rgb")]
    pub images: Vec<PathBuf>,
}

/// The class set of a dataset root in a described layout (dataset.yaml, MSRS, PST900, FMB) or
/// of a dataset.yaml file.
fn described_class_set(path: &Path) -> Result<ClassSet> {
    let description = if path.is_file() {
        rtf_data::description::read_description(path)?
    } else if let Some(description) = rtf_data::layouts::describe(path) {
        description?
    } else {
        bail!(
            "--classes {}: not mf, freiburg, a dataset.yaml or a dataset root with one \
             (or an MSRS, PST900 or FMB root)",
            path.display()
        );
    };
    eprintln!(
        "classes: {} ({}): {}",
        description.class_set.name,
        description.layout.name(),
        description.class_set.names().join(", ")
    );
    Ok(description.class_set)
}

fn parse_range(text: &str) -> Result<(u16, u16), String> {
    let parsed = text
        .split_once(':')
        .and_then(|(a, b)| Some((a.trim().parse().ok()?, b.trim().parse().ok()?)));
    match parsed {
        Some((lo, hi)) if lo < hi => Ok((lo, hi)),
        _ => Err(format!("`{text}` is not LO:HI with 0 <= LO < HI <= 65535")),
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
    Range(Option<(u16, u16)>),
    Trained(&'a ThermalNormalisation),
}

/// Reads an RGB PNG and a grey thermal PNG (8- or 16-bit) of the same size into a frame.
fn read_pair(rgb_path: &Path, thermal_path: &Path, rule: ThermalRule) -> Result<Frame> {
    let rgb_png = read_png(rgb_path)?;
    let rgb = match (&rgb_png.samples, rgb_png.channels, rgb_png.indexed) {
        (Samples::U8(v), 3, false) => v.clone(),
        (Samples::U8(v), 4, false) => v.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect(),
        _ => bail!(
            "{}: {}-bit with {} channel(s), expected 8-bit RGB",
            rgb_path.display(),
            rgb_png.bit_depth(),
            rgb_png.channels
        ),
    };
    let thermal_png = read_png(thermal_path)?;
    if (thermal_png.width, thermal_png.height) != (rgb_png.width, rgb_png.height) {
        bail!(
            "{} is {}x{} but {} is {}x{}: the pair must be registered at the same size",
            thermal_path.display(),
            thermal_png.width,
            thermal_png.height,
            rgb_path.display(),
            rgb_png.width,
            rgb_png.height
        );
    }
    let thermal = match rule {
        ThermalRule::Range(range) => thermal_unit(&thermal_png, thermal_path, range)?,
        ThermalRule::Trained(rule) => trained_thermal(&thermal_png, thermal_path, rule)?,
    };
    let name = stem(rgb_path);
    Ok(Frame {
        daytime: None,
        name,
        width: rgb_png.width,
        height: rgb_png.height,
        rgb,
        thermal,
        label: None,
    })
}

/// Thermal samples in [0, 1] by the rule the weights were trained with (as the dataset
/// loader applies it).
fn trained_thermal(png: &PngImage, path: &Path, rule: &ThermalNormalisation) -> Result<Vec<f32>> {
    check_grey(png, path)?;
    let (samples, bits): (Vec<u16>, u8) = match &png.samples {
        Samples::U8(v) => (v.iter().map(|&x| x as u16).collect(), 8),
        Samples::U16(v) => (v.clone(), 16),
    };
    Ok(rule.apply(&samples, bits, path)?)
}

fn check_grey(png: &PngImage, path: &Path) -> Result<()> {
    if png.channels != 1 || png.indexed {
        bail!(
            "{}: {} channel(s), expected a single grey thermal channel",
            path.display(),
            png.channels
        );
    }
    Ok(())
}

/// Thermal samples in [0, 1]: 8-bit / 255; 16-bit clipped to `range` (or the frame's min:max).
fn thermal_unit(png: &PngImage, path: &Path, range: Option<(u16, u16)>) -> Result<Vec<f32>> {
    check_grey(png, path)?;
    Ok(match &png.samples {
        Samples::U8(v) => v.iter().map(|&x| x as f32 / 255.0).collect(),
        Samples::U16(v) => {
            let (lo, hi) = range.unwrap_or_else(|| {
                (
                    v.iter().copied().min().unwrap_or(0),
                    v.iter().copied().max().unwrap_or(1),
                )
            });
            let span = (hi.saturating_sub(lo)).max(1) as f32;
            v.iter()
                .map(|&x| (x.clamp(lo, hi) - lo) as f32 / span)
                .collect()
        }
    })
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
) -> Result<Vec<PathBuf>> {
    if out.exists() && !out.is_dir() {
        bail!("--out {}: exists and is not a directory", out.display());
    }
    for input in inputs {
        if input.is_dir() {
            bail!(
                "{}: is a directory; predict takes image files (e.g. {}/*.png)",
                input.display(),
                input.display()
            );
        }
        if !input.exists() {
            bail!("{}: no such file", input.display());
        }
    }
    // Inputs by canonical path; an output folder that does not exist yet holds none of them.
    let canonical_inputs: Vec<(PathBuf, &Path)> = inputs
        .iter()
        .filter_map(|p| p.canonicalize().ok().map(|c| (c, *p)))
        .collect();
    let canonical_out = out.canonicalize().ok();
    let mut writer: std::collections::HashMap<PathBuf, &Path> = Default::default();
    let mut ids = Vec::with_capacity(sources.len());
    for source in sources {
        let stem = stem(source);
        if stem.is_empty() {
            bail!(
                "{}: no file name to name the outputs after",
                source.display()
            );
        }
        let mut names = vec![format!("{stem}.png"), format!("{stem}_color.png")];
        if logits {
            names.push(format!("{stem}.npy"));
        }
        for name in &names {
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
            if let Some(dir) = &canonical_out {
                let target = dir.join(name);
                if let Some((_, input)) = canonical_inputs.iter().find(|(c, _)| *c == target) {
                    bail!(
                        "{} would overwrite the input {}: choose another --out (nothing was \
                         written)",
                        path.display(),
                        input.display()
                    );
                }
            }
        }
        ids.push(out.join(&names[0]));
    }
    Ok(ids)
}

pub fn run(args: Args) -> Result<()> {
    let mut sources: Vec<PathBuf> = args.images.clone();
    if let Some(rgb) = &args.rgb {
        sources.push(rgb.clone());
    }
    let mut inputs: Vec<&Path> = args.images.iter().map(PathBuf::as_path).collect();
    inputs.extend(args.rgb.as_deref());
    inputs.extend(args.thermal.as_deref());
    inputs.push(&args.weights);
    let planned = plan_outputs(&args.out, &sources, &inputs, args.logits)?;
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
    // Read every input first: a bad file stops the run before anything is written.
    let mut frames = args
        .images
        .iter()
        .map(|p| rtf_data::mf::read_mf_image(p).map_err(anyhow::Error::from))
        .collect::<Result<Vec<_>>>()?;
    if let (Some(rgb), Some(thermal)) = (&args.rgb, &args.thermal) {
        frames.push(read_pair(
            rgb,
            thermal,
            thermal_rule(&args, trained.as_ref()),
        )?);
    }
    // Frames larger than memory allows are refused before anything is written.
    for (frame, path) in frames.iter().zip(&sources) {
        rtf_eval::evaluate::check_memory(network.as_ref(), 1, frame.height, frame.width, device)
            .with_context(|| path.display().to_string())?;
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let _guard = tch::no_grad_guard();
    for ((frame, path), ids_path) in frames.iter().zip(&sources).zip(&planned) {
        let input =
            rtf_eval::figure::frame_input(frame, network.input_convention()).to_device(device);
        let logits = rtf_eval::evaluate::logits(network.as_ref(), &input)
            .with_context(|| path.display().to_string())?
            .get(0)
            .to_kind(Kind::Float)
            .to_device(tch::Device::Cpu);
        let ids = Vec::<u8>::try_from(logits.argmax(0, false).to_kind(Kind::Uint8).flatten(0, -1))?;
        let (w, h) = (frame.width as u32, frame.height as u32);
        let stem = stem(path);
        let color_path = args.out.join(format!("{stem}_color.png"));
        save_png(
            ids_path,
            image::DynamicImage::ImageLuma8(
                image::GrayImage::from_raw(w, h, ids.clone()).expect("sized"),
            ),
        )?;
        save_png(
            &color_path,
            image::DynamicImage::ImageRgb8(
                image::RgbImage::from_raw(w, h, classes.colorize(&ids)).expect("sized"),
            ),
        )?;
        if args.logits {
            let shape: Vec<usize> = logits.size().iter().map(|&d| d as usize).collect();
            let values = Vec::<f32>::try_from(logits.flatten(0, -1))?;
            let npy = args.out.join(format!("{stem}.npy"));
            rtf_core::npy::write_f32(&npy, &shape, &values)
                .with_context(|| format!("writing {}", npy.display()))?;
        }
        println!("{} -> {}", path.display(), ids_path.display());
    }
    Ok(())
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
            range.or(args.model.starts_with("heatnet").then_some((21800, 25000))),
        ),
    }
}

fn save_png(path: &Path, image: image::DynamicImage) -> Result<()> {
    rtf_core::write_atomic(path, |tmp| {
        image.save_with_format(tmp, image::ImageFormat::Png)
    })
    .with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thermal_ranges() {
        assert_eq!(parse_range("21800:25000"), Ok((21800, 25000)));
        assert!(parse_range("5:5").is_err());
        let png = PngImage {
            width: 3,
            height: 1,
            channels: 1,
            indexed: false,
            samples: Samples::U16(vec![100, 200, 300]),
        };
        assert_eq!(
            thermal_unit(&png, Path::new("t.png"), None).unwrap(),
            vec![0.0, 0.5, 1.0]
        );
        assert_eq!(
            thermal_unit(&png, Path::new("t.png"), Some((200, 250))).unwrap(),
            vec![0.0, 0.0, 1.0]
        );
    }
}
