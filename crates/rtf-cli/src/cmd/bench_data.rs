//! `rtf bench data`: input-pipeline throughput (decode + flip + RTFNet crop + tensor) at
//! batch 8 on MF frames or a described root (dataset.yaml, MSRS, PST900, FMB: RGB, thermal
//! (8- or 16-bit, normalised by its rule) and labels in separate files), the work
//! `lab/bench/bench_data.py` does with PIL + NumPy.

use anyhow::{bail, Context, Result};
use rtf_data::{AugmentConfig, FrameSource, Loader, LoaderConfig};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

#[derive(clap::Args)]
pub struct Args {
    /// Dataset root: MF layout, or a described one (dataset.yaml or its folder, MSRS, PST900,
    /// FMB).
    #[arg(long, value_parser = rtf_data::dataset::parse_root)]
    pub data: PathBuf,
    /// Split to read (default: MF's first split file, e.g. `test`; a described root's first
    /// split).
    #[arg(long)]
    pub split: Option<String>,
    #[arg(long, default_value_t = 8)]
    pub batch: usize,
    /// Decode/augment threads (0 = inline on the consumer thread).
    #[arg(long, default_value_t = 2)]
    pub workers: usize,
    /// Frames to time at least (whole epochs are repeated until reached).
    #[arg(long, default_value_t = 96)]
    pub frames: usize,
    /// Print `{frames_per_s, …}` as JSON.
    #[arg(long)]
    pub json: bool,
}

/// The split to time and its name (the first split unless named), the root opened once.
fn open(args: &Args) -> Result<(Arc<dyn FrameSource>, String)> {
    let dataset = super::open_dataset(&args.data, "a benchmark")?;
    let name = match &args.split {
        Some(s) => s.clone(),
        None => dataset
            .split_names()?
            .first()
            .cloned()
            .context("no splits")?,
    };
    Ok((dataset.split(&name, true)?, name))
}

pub fn run(args: Args) -> Result<()> {
    let (source, split_name) = open(&args)?;
    let (w, h) = {
        let f = source.load(0)?;
        (f.width, f.height)
    };
    let cfg = LoaderConfig {
        batch_size: args.batch,
        shuffle: true,
        drop_last: false,
        seed: 0,
        workers: args.workers,
        prefetch: 2,
        augment: AugmentConfig {
            hflip: true,
            crop: Some(0.1),
            ..AugmentConfig::default()
        },
        resize: None,
    };
    let loader = Loader::new(source.clone(), cfg, rtf_core::InputConvention::UnitRange);
    // Warm-up batch (page cache, thread start), not timed.
    if let Some(b) = loader.epoch(u64::MAX).next() {
        b?;
    }
    let (mut frames, mut waited, mut epoch) = (0usize, Duration::ZERO, 0u64);
    let start = Instant::now();
    while frames < args.frames {
        for batch in loader.epoch(epoch) {
            let batch = batch?;
            waited += batch.wait;
            frames += batch.names.len();
            // Touch the data like a consumer would.
            std::hint::black_box(batch.input.size());
            if frames >= args.frames {
                break;
            }
        }
        epoch += 1;
        if source.is_empty() {
            bail!("empty split");
        }
    }
    let secs = start.elapsed().as_secs_f64();
    let fps = frames as f64 / secs;
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "frames_per_s": fps,
                "frames": frames,
                "seconds": secs,
                "batch": args.batch,
                "workers": args.workers,
                "width": w,
                "height": h,
                "split": split_name,
            })
        );
    } else {
        println!(
            "{frames} frames ({w}x{h}, batch {}, {} workers, decode + flip + crop + tensor) in {secs:.2} s: {fps:.1} frames/s",
            args.batch, args.workers
        );
        let _ = waited;
    }
    Ok(())
}
