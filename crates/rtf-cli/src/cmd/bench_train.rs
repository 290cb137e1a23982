//! `rtf bench train --model NAME --batch B --size WxH --precision P [--device D] [--json]`:
//! steady-state images/s of full training steps (forward, loss, backward, SGD update) and peak
//! resident memory; `scripts/bench_torch_train.py` runs the PyTorch peer side by side.

use anyhow::Result;
use rtf_train::bench::{bench_train, TrainBenchOptions};
use rtf_train::config::{OptimizerKind, Precision};
use rtf_train::OptimizerConfig;

use super::parse_size;

#[derive(clap::Args)]
pub struct Args {
    /// Network name (see `rtf models`).
    #[arg(long)]
    pub model: String,
    /// Frames per step.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Frame size as WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub size: (usize, usize),
    /// fp32, bf16 or fp16 (CUDA only): the arithmetic of `rtf train --precision`.
    #[arg(long, default_value = "fp32", value_parser = Precision::parse)]
    pub precision: Precision,
    /// cpu, cuda or cuda:N.
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// sgd (MFNet paper), rmsprop (HeatNet paper) or adamw (CMX's training).
    #[arg(long, default_value = "sgd", value_parser = OptimizerKind::parse)]
    pub optimizer: OptimizerKind,
    /// Untimed steps first.
    #[arg(long, default_value_t = 2)]
    pub warmup: usize,
    /// Timed steps.
    #[arg(long, default_value_t = 5)]
    pub steps: usize,
    /// libtorch threads (default: libtorch's choice, one per core).
    #[arg(long)]
    pub threads: Option<i32>,
    /// Print {model, batch, size, precision, images_per_s, peak_rss_mb, cpu, ...} as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> Result<()> {
    if let Some(threads) = args.threads {
        anyhow::ensure!(threads >= 1, "--threads must be ≥ 1");
        tch::set_num_threads(threads);
    }
    let optimizer = OptimizerConfig::paper_default(args.optimizer);
    let device = rtf_train::config::available_device(&args.device).map_err(anyhow::Error::msg)?;
    if let Some(line) = crate::bf16_kernels::settle_for_bench(args.precision, device)? {
        eprintln!("{line}");
    }
    if let Some(warning) = crate::bf16_warning::training(args.precision, device) {
        eprintln!("warning: {warning}");
    }
    crate::allocator::set_purge_delay_for_training(args.precision, device);
    let report = bench_train(&TrainBenchOptions {
        model: args.model,
        batch: args.batch,
        size: args.size,
        precision: args.precision,
        device,
        warmup: args.warmup,
        steps: args.steps,
        optimizer,
    })?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "{} batch {} {} {} on {} ({} threads): {:.2} images/s; step {:.3} s (forward+loss {:.3}, backward {:.3}, optimiser {:.3}); peak RSS {}",
            report.model,
            report.batch,
            report.size,
            report.precision,
            report.device,
            report.threads,
            report.images_per_s,
            report.step_s,
            report.forward_s,
            report.backward_s,
            report.optimizer_s,
            report
                .peak_rss_mb
                .map_or("unknown".to_string(), |m| format!("{m:.0} MiB"))
        );
        println!("CPU: {}", report.cpu.label());
    }
    Ok(())
}
