//! `rtf bench train --model NAME --batch B --size WxH --precision P [--device D] [--json]`:
//! steady-state images/s of full training steps (forward, loss, backward, SGD update) and peak
//! resident memory; `lab/bench/bench_torch_train.py` runs the PyTorch peer side by side.

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
    /// After the timed steps, count the operators of one more step, part by part (libtorch's
    /// profiler events: on a GPU, kernel launches); `lab/bench/profile_train_torch.py --counts`
    /// counts PyTorch's step alike.
    #[arg(long)]
    pub count_ops: bool,
}

pub fn run(args: Args) -> Result<()> {
    if let Some(threads) = args.threads {
        anyhow::ensure!(threads >= 1, "--threads must be ≥ 1");
        tch::set_num_threads(threads);
    }
    let optimizer = OptimizerConfig::paper_default(args.optimizer);
    let device = rtf_train::config::available_device(&args.device).map_err(anyhow::Error::msg)?;
    // The choice `rtf train` would make for a new run.
    let policy = crate::bf16_probe::policy()?;
    let mut convolutions = policy.bf16.in_force(None);
    if args.precision == Precision::Bf16 && device == tch::Device::Cpu {
        let (choice, line) = rtf_train::kernels::measured_or_in_force(&policy.bf16, || {
            crate::bf16_probe::training_choice(&policy)
        });
        convolutions = choice;
        if let Some(line) = line {
            eprintln!("{line}");
        }
    }
    let measured = || crate::bf16_probe::measured_training(convolutions);
    let warning = rtf_train::kernels::training_warning(
        &policy.bf16,
        convolutions,
        args.precision,
        device,
        measured,
    );
    if let Some(warning) = warning {
        eprintln!("warning: {warning}");
    }
    let layout = super::train::layout_asked()?;
    let in_force = layout.unwrap_or_else(|| rtf_train::config::fp32_layout_faster_on(device));
    crate::allocator::set_purge_delay_for_training(args.precision, device, in_force);
    let report = bench_train(&TrainBenchOptions {
        model: args.model,
        batch: args.batch,
        size: args.size,
        precision: args.precision,
        device,
        warmup: args.warmup,
        steps: args.steps,
        optimizer,
        count_ops: args.count_ops,
        fp32_layout: layout,
        bf16_convolutions: Some(convolutions),
        winograd: policy.winograd,
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
        if let Some(counts) = &report.op_counts {
            print_op_counts(counts);
        }
    }
    Ok(())
}

/// Per part: operators at the outermost level and in all, and the most frequent outermost.
fn print_op_counts(counts: &rtf_train::bench::StepOpCounts) {
    let parts = [
        ("forward+loss", &counts.forward),
        ("zero_grad+backward", &counts.backward),
        ("optimiser", &counts.optimizer),
    ];
    for (part, ops) in parts {
        let outermost: u64 = ops.values().map(|c| c.1).sum();
        let all: u64 = ops.values().map(|c| c.0).sum();
        let mut top: Vec<(&String, u64)> = ops.iter().map(|(n, c)| (n, c.1)).collect();
        top.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
        let top: Vec<String> = top
            .iter()
            .take(8)
            .map(|(n, c)| format!("{n} {c}"))
            .collect();
        println!(
            "{part}: {outermost} operators outermost, {all} in all; {}",
            top.join(", ")
        );
    }
}
