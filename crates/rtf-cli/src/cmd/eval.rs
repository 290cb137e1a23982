use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use rtf_data::{FrameSource, MfDataset};
use rtf_eval::{EvalOptions, Scores};
use rtf_train::config::available_device;
use serde::Serialize;

use super::{load_network, parse_size};

#[derive(clap::Args)]
pub struct Args {
    /// Network name (see `rtf models`).
    #[arg(long, default_value = "mfnet")]
    pub model: String,
    /// Weights (safetensors, reference names), e.g. RUN/final.safetensors.
    #[arg(long)]
    pub weights: PathBuf,
    /// Dataset root (MF layout).
    #[arg(long)]
    pub data: PathBuf,
    /// Split to evaluate; its day and night frames are also scored separately.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Also write the scores as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a PNG grid (RGB | thermal | ground truth | prediction) of the first frames.
    #[arg(long)]
    pub figure: Option<PathBuf>,
    /// Frames in the --figure grid (half day, half night where the split has both).
    #[arg(long, default_value_t = 4)]
    pub figure_frames: usize,
    /// Resize frames to WxH (labels nearest) before the network.
    #[arg(long, value_parser = parse_size)]
    pub resize: Option<(usize, usize)>,
    #[arg(long, default_value_t = 4)]
    pub batch_size: usize,
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// Run the fast inference path (BatchNorm folded, channels-last) in fp32 or bf16; default:
    /// the plain path.
    #[arg(long)]
    pub precision: Option<rtf_models::fast::Precision>,
}

/// `--json` contents: RTFNet convention at the top level (spec §2), MFNet paper's mIoU beside it.
#[derive(Serialize)]
struct Report<'a> {
    model: &'a str,
    weights: &'a PathBuf,
    data: &'a PathBuf,
    split: &'a str,
    frames: usize,
    #[serde(flatten)]
    all: &'a Scores,
    day: Option<&'a Scores>,
    night: Option<&'a Scores>,
}

pub fn run(args: Args) -> Result<()> {
    let device = available_device(&args.device).map_err(anyhow::Error::msg)?;
    let dataset = MfDataset::open(&args.data)?;
    let split: Arc<dyn FrameSource> = Arc::new(dataset.split(&args.split)?);
    let classes = split.class_set().clone();
    let (_vs, network) = load_network(
        &args.model,
        classes.len() as i64,
        &args.weights,
        device,
        args.precision,
    )?;
    let options = EvalOptions {
        batch_size: args.batch_size,
        resize: args.resize,
        workers: 2,
    };
    let report = rtf_eval::evaluate(network.as_ref(), split.clone(), &options, device)?;

    println!(
        "{} on {} `{}` ({} frames)",
        args.model,
        args.data.display(),
        args.split,
        report.frames
    );
    println!("{}", report.all.table());
    for (label, scores) in [("day", &report.day), ("night", &report.night)] {
        if let Some(s) = scores {
            println!(
                "{label}: mAcc {:.1}  mIoU {:.1}  mIoU(MFNet) {:.1}",
                100.0 * s.macc,
                100.0 * s.miou,
                100.0 * s.miou_mfnet
            );
        }
    }
    if let Some(path) = &args.json {
        let json = serde_json::to_string_pretty(&Report {
            model: &args.model,
            weights: &args.weights,
            data: &args.data,
            split: &args.split,
            frames: report.frames,
            all: &report.all,
            day: report.day.as_ref(),
            night: report.night.as_ref(),
        })?;
        rtf_core::write_bytes_atomic(path, json.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.figure {
        let rows = rtf_eval::figure::rows_for(
            network.as_ref(),
            split.as_ref(),
            args.figure_frames,
            args.resize,
            device,
        )?;
        let grid = rtf_eval::figure::prediction_grid(&rows, &classes);
        rtf_eval::figure::save_png(&grid, path)?;
        println!("figure: {}", path.display());
    }
    Ok(())
}
