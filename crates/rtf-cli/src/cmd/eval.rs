use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result};
use rtf_data::inspect::DatasetFormat;
use rtf_data::FrameSource;
use rtf_eval::scores_file::{single_modality_note, DroppedScores, HeatnetScores, ScoresFile};
use rtf_eval::{ClassMap, ClassMapScores, ClassMapping, EvalOptions, Scores};

use super::{load_network, parse_size};
use crate::output_guard::OutputGuard;

#[derive(clap::Args)]
pub struct Args {
    /// Network name (see `rtf models`).
    #[arg(long, default_value = "mfnet")]
    pub model: String,
    /// Weights (safetensors, reference names), e.g. RUN/final.safetensors.
    #[arg(long)]
    pub weights: PathBuf,
    /// Dataset root: MF, Freiburg Thermal, MSRS, PST900, FMB (recognised by its folders), or
    /// a dataset.yaml or the folder holding it. Its class set must be the one the weights
    /// record, if they do.
    #[arg(long, value_parser = rtf_data::dataset::parse_root)]
    pub data: PathBuf,
    /// Split to evaluate; its day and night frames are also scored separately. Freiburg:
    /// `test` (the test layout) or `train` (labelled frames of the training tree), both with
    /// the reference test preprocessing (320×704).
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Also write the scores as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a PNG grid (RGB | thermal | ground truth | prediction) of the first frames, with
    /// column titles and a class legend.
    #[arg(long, conflicts_with = "class_map")]
    pub figure: Option<PathBuf>,
    /// Score a network on data with another class set through a class map: a built-in one
    /// (`mf-to-freiburg`, `freiburg-to-mf`: HeatNet Tab. I's person, car, bicycle) or a YAML
    /// file naming the scored classes and, for each, the network's and the data's classes
    /// that count as it (docs: training.md, "Another dataset's classes").
    #[arg(long, value_name = "MAP")]
    pub class_map: Option<String>,
    /// Replace an existing --json or --figure file that rtf did not write, or a file of the
    /// dataset evaluated (without it such a path stops the run before anything is computed).
    #[arg(long)]
    pub overwrite: bool,
    /// Frames in the --figure grid (half day, half night where the split has both).
    #[arg(long, default_value_t = 4)]
    pub figure_frames: usize,
    /// Resize frames to WxH (labels nearest) before the network.
    #[arg(long, value_parser = parse_size)]
    pub resize: Option<(usize, usize)>,
    #[arg(long, default_value_t = 4)]
    pub batch_size: usize,
    #[command(flatten)]
    pub run: super::RunFlags,
    /// Also score with this modality missing (repeatable: `--drop rgb --drop thermal`); the
    /// JSON gains a `dropped` list beside the normal scores, each with all / day / night.
    #[arg(long, value_enum)]
    pub drop: Vec<DropArg>,
    /// What replaces a dropped modality: pixel value 0, or the split's per-channel mean.
    #[arg(long, value_enum, default_value = "zero")]
    pub drop_fill: FillArg,
    /// Run the network by sliding windows (--crop, --stride-rate) as the official CMX
    /// evaluator does, instead of on the whole image.
    #[arg(long)]
    pub sliding: bool,
    /// Window of --sliding, HxW (height first, as the official `eval_crop_size`).
    #[arg(long, value_parser = parse_crop, default_value = "480x640", requires = "sliding")]
    pub crop: (usize, usize),
    /// Window stride of --sliding as a fraction of the crop (`2/3` or `0.5`):
    /// stride = ceil(crop · rate).
    #[arg(long, value_parser = parse_rate, default_value = "2/3", requires = "sliding")]
    pub stride_rate: f64,
    /// Resize factors the input is scored at, summed (e.g. `0.75,1,1.25`); default 1.
    #[arg(long, value_parser = parse_scale, value_delimiter = ',', default_value = "1")]
    pub scales: Vec<f64>,
    /// Also score the horizontally flipped input (its logits flipped back and added).
    #[arg(long)]
    pub flip: bool,
}

/// `HxW` (height first) → (height, width).
fn parse_crop(text: &str) -> Result<(usize, usize), String> {
    // parse_size's (first, second) numbers are here (height, width).
    super::parse_size(text)
        .map_err(|_| format!("`{text}` is not HxW with positive integers (e.g. 480x640)"))
}

/// `2/3` or a decimal, in (0, 1].
fn parse_rate(text: &str) -> Result<f64, String> {
    let value = match text.split_once('/') {
        Some((n, d)) => n
            .trim()
            .parse::<f64>()
            .ok()
            .zip(d.trim().parse::<f64>().ok())
            .map(|(n, d)| n / d),
        None => text.trim().parse::<f64>().ok(),
    };
    value
        .filter(|r| *r > 0.0 && *r <= 1.0)
        .ok_or_else(|| format!("`{text}` is not a stride rate in (0, 1] (e.g. 2/3)"))
}

/// A positive resize factor.
fn parse_scale(text: &str) -> Result<f64, String> {
    text.trim()
        .parse::<f64>()
        .ok()
        .filter(|s| s.is_finite() && *s > 0.0)
        .ok_or_else(|| format!("`{text}` is not a positive scale (e.g. 0.75)"))
}

impl Args {
    fn eval_options(&self) -> EvalOptions {
        EvalOptions {
            batch_size: self.batch_size,
            resize: self.resize,
            workers: 2,
            inference: self.inference(),
        }
    }

    /// The inference mode, scales and flip the flags ask for.
    fn inference(&self) -> rtf_eval::InferenceOptions {
        rtf_eval::InferenceOptions {
            mode: match self.sliding {
                true => rtf_eval::Inference::Sliding {
                    crop: self.crop,
                    stride_rate: self.stride_rate,
                },
                false => rtf_eval::Inference::Whole,
            },
            scales: self.scales.clone(),
            flip: self.flip,
        }
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum DropArg {
    Rgb,
    Thermal,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum FillArg {
    Zero,
    Mean,
}

/// Schema tag of the `--json` file (`rtf report` checks it).
pub use rtf_eval::EVAL_SCHEMA;
/// The labelled frames of `split` under `root`, the root opened once (its layout decides how;
/// Freiburg Thermal: `test` or `train`, with the reference test preprocessing).
pub(crate) fn open_split(
    root: &Path,
    split: &str,
) -> Result<(Arc<dyn FrameSource>, rtf_data::Dataset)> {
    let dataset = super::open_dataset(root, "an evaluation")?;
    Ok((dataset.split(split, true)?, dataset))
}

/// Refuses, before any work, a --json or --figure path that must not be written.
fn check_outputs(args: &Args) -> Result<()> {
    let guard = OutputGuard::new(args.overwrite)
        .reading([args.weights.as_path()])
        .dataset(&args.data);
    for (path, what) in [(&args.json, "eval --json"), (&args.figure, "eval --figure")] {
        if let Some(path) = path {
            guard.check(path, what)?;
        }
    }
    Ok(())
}

pub fn run(args: Args) -> Result<()> {
    check_outputs(&args)?;
    let device = args.run.device()?;
    let (split, dataset) = open_split(&args.data, &args.split)?;
    let classes = split.class_set().clone();
    let (network_classes, mapping) = class_mapping(&args, &classes)?;
    let loaded = load_network(&args.run.request(
        &args.model,
        &args.weights,
        network_classes.len() as i64,
        device,
    ))?;
    let network = loaded.net;
    rtf_eval::evaluate::install_quiet_panic_hook();
    let options = args.eval_options();
    // Hashed before the evaluation reads the frames, so the record is of what was read.
    let data_fingerprint = args
        .json
        .as_ref()
        .map(|_| rtf_data::fingerprint::fingerprint_opened(&dataset))
        .transpose()?;
    let (net, map) = (network.as_ref(), mapping.as_ref());
    let report = rtf_eval::evaluate_mapped(net, split.clone(), &options, None, map, device)?;
    let (heatnet, mapped) = match &mapping {
        None => (
            print_scores(&args, dataset.format(), &report, loaded.inputs),
            None,
        ),
        Some(m) => (None, Some(print_mapped(&args, m, &report, loaded.inputs))),
    };
    let (sees, options) = (loaded.inputs, &options);
    let dropped = scores_without_modalities(&args, net, sees, &split, options, map, device)?;
    if let (Some(path), Some(data_fingerprint)) = (&args.json, &data_fingerprint) {
        let file = ScoresFile {
            schema: EVAL_SCHEMA,
            class_names: mapping
                .as_ref()
                .map_or_else(|| classes.names(), |m| m.matrix_names()),
            class_map: mapped,
            confusion: report.confusion.rows(),
            dropped,
            model: &args.model,
            inputs: loaded.inputs,
            weights: &args.weights,
            data: &args.data,
            split: &args.split,
            inference: &options.inference,
            frames: report.frames,
            all: &report.all,
            day: report.day.as_ref(),
            night: report.night.as_ref(),
            heatnet,
            data_fingerprint,
        };
        let json = serde_json::to_string_pretty(&file)?;
        rtf_core::write_bytes_atomic(path, json.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.figure {
        write_figure(
            &args,
            path,
            network.as_ref(),
            split.as_ref(),
            &classes,
            device,
        )?;
    }
    Ok(())
}

/// Prints the scores: RTFNet's convention table, then HeatNet's (Freiburg Thermal) or the MFNet
/// paper's mIoU, then day and night. Returns HeatNet's scores for the JSON.
fn print_scores(
    args: &Args,
    format: DatasetFormat,
    report: &rtf_eval::EvalReport,
    inputs: rtf_models::Modality,
) -> Option<HeatnetScores> {
    print_header(args, report, inputs);
    println!("inference: {}", args.inference().describe());
    println!("{}", report.all.table());
    let heatnet = (format == DatasetFormat::Freiburg).then(|| HeatnetScores::of(report));
    let pct = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{:.1}", 100.0 * v));
    match &heatnet {
        Some(h) => println!(
            "HeatNet convention (classes 0–11, undefined skipped): mIoU {}  day {}  night {}  day/night {}",
            pct(h.miou),
            pct(h.day_miou),
            pct(h.night_miou),
            pct(h.day_night_miou)
        ),
        // Only for class sets whose class 0 is unlabelled (MF's): elsewhere class 0 is a class.
        None => {
            if let Some(m) = report.all.miou_mfnet {
                println!(
                    "MFNet paper (class 0 '{}' excluded from the sums): mIoU {:.1}",
                    report.all.per_class[0].name,
                    100.0 * m
                );
            }
        }
    }
    for (label, scores) in [("day", &report.day), ("night", &report.night)] {
        if let Some(s) = scores {
            let extra = match s.miou_mfnet {
                Some(m) => format!("  mIoU(MFNet) {:.1}", 100.0 * m),
                None => String::new(),
            };
            println!(
                "{label}: mAcc {:.1}  mIoU {:.1}{extra}",
                100.0 * s.macc,
                100.0 * s.miou
            );
        }
    }
    heatnet
}

/// The network's class set and the `--class-map` checked against it and the data's, before
/// anything runs. Without a map: the data's classes, which weights that record theirs must
/// have (by name). With one: the weights' record, else the map's `network_classes`, else
/// MF's (as for any weights without a record).
fn class_mapping(
    args: &Args,
    data: &rtf_core::ClassSet,
) -> Result<(rtf_core::ClassSet, Option<ClassMapping>)> {
    let Some(spec) = &args.class_map else {
        super::check_classes(&args.weights, &args.data, data)?;
        return Ok((data.clone(), None));
    };
    let map = ClassMap::load(spec)?;
    let network = match super::trained_on(&args.weights)? {
        Some(trained) => trained.classes,
        None => map
            .network_class_set()?
            .unwrap_or_else(rtf_core::ClassSet::mf),
    };
    let mapping = map.resolve(&network, data)?;
    Ok((network, Some(mapping)))
}

/// The first line of the scores: network, data, split, frames, inputs.
fn print_header(args: &Args, report: &rtf_eval::EvalReport, inputs: rtf_models::Modality) {
    println!(
        "{} on {} `{}` ({} frames, inputs {})",
        args.model,
        args.data.display(),
        args.split,
        report.frames,
        inputs
    );
}

/// The scores through a class map: the scored classes' table (then "other"), the mean IoU over
/// the scored classes, day and night. Returns them for the JSON.
fn print_mapped(
    args: &Args,
    mapping: &ClassMapping,
    report: &rtf_eval::EvalReport,
    inputs: rtf_models::Modality,
) -> ClassMapScores {
    let s = ClassMapScores::of(mapping, report);
    print_header(args, report, inputs);
    println!(
        "class map {} ({}): scored {}; other pixels {:?}",
        s.name,
        s.source,
        s.scored.join(", "),
        s.other_pixels
    );
    println!("inference: {}", args.inference().describe());
    println!("{}", report.all.table());
    let pct = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{:.1}", 100.0 * v));
    println!(
        "mIoU over the scored classes: {}  day {}  night {}  day/night {}",
        pct(s.miou),
        pct(s.day_miou),
        pct(s.night_miou),
        pct(s.day_night_miou)
    );
    s
}

/// `--drop`: the evaluation again with each named modality missing; prints and returns them.
fn scores_without_modalities(
    args: &Args,
    network: &dyn rtf_models::Network,
    sees: rtf_models::Modality,
    split: &Arc<dyn FrameSource>,
    options: &EvalOptions,
    mapping: Option<&ClassMapping>,
    device: tch::Device,
) -> Result<Vec<DroppedScores>> {
    let mut dropped = Vec::new();
    for modality in &args.drop {
        let drop = rtf_eval::ModalityDrop {
            modality: match modality {
                DropArg::Rgb => rtf_models::Modality::Rgb,
                DropArg::Thermal => rtf_models::Modality::Thermal,
            },
            fill: match args.drop_fill {
                FillArg::Zero => rtf_eval::DropFill::Zero,
                FillArg::Mean => rtf_eval::DropFill::Mean,
            },
        };
        if let Some(note) = single_modality_note(drop.modality, sees) {
            eprintln!("note: --drop {}: {note}", drop.modality.name());
        }
        let r = rtf_eval::evaluate_mapped(
            network,
            split.clone(),
            options,
            Some(drop),
            mapping,
            device,
        )?;
        let pct = |s: &Option<Scores>| {
            s.as_ref()
                .map_or("-".into(), |s| format!("{:.1}", 100.0 * s.miou))
        };
        println!(
            "{:?} missing ({:?} fill): mAcc {:.1}  mIoU {:.1}  day mIoU {}  night mIoU {}",
            drop.modality,
            drop.fill,
            100.0 * r.all.macc,
            100.0 * r.all.miou,
            pct(&r.day),
            pct(&r.night)
        );
        dropped.push(DroppedScores {
            drop,
            all: r.all,
            day: r.day,
            night: r.night,
        });
    }
    Ok(dropped)
}

/// `--figure`: a grid of `--figure-frames` frames (RGB, thermal, truth, prediction).
fn write_figure(
    args: &Args,
    path: &Path,
    network: &dyn rtf_models::Network,
    split: &dyn FrameSource,
    classes: &rtf_core::ClassSet,
    device: tch::Device,
) -> Result<()> {
    let rows = rtf_eval::figure::rows_for(network, split, args.figure_frames, args.resize, device)?;
    let column = rtf_eval::figure::PredictionColumn {
        title: args.model.clone(),
        ids: rows.iter().map(|r| r.prediction.clone()).collect(),
    };
    let grid = rtf_eval::figure::annotated_grid(&rows, &[column], classes);
    rtf_eval::figure::save_png(&grid, path)?;
    println!("figure: {}", path.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{parse_crop, parse_rate, parse_scale};

    #[test]
    fn inference_flags_parse() {
        assert_eq!(parse_crop("480x640"), Ok((480, 640)));
        assert!(parse_crop("480").is_err());
        assert_eq!(parse_rate("2/3"), Ok(2.0 / 3.0));
        assert_eq!(parse_rate("0.5"), Ok(0.5));
        assert!(parse_rate("3/2").is_err() && parse_rate("0").is_err());
        assert_eq!(parse_scale("0.75"), Ok(0.75));
        assert!(parse_scale("-1").is_err() && parse_scale("x").is_err());
    }
}
