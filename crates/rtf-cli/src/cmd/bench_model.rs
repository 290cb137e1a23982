//! `rtf bench model --model NAME [--batch B] [--precision fp32|bf16] [--json]`: inference speed
//! at 480×640 (warm-up, then median, 95th-percentile and minimum ms per frame, FPS), the
//! process's peak resident memory, and the CPU (identity and kernel-deciding flags).

use anyhow::Result;
use rtf_eval::speed::{bench_model, BenchOptions, ForwardPath};
use rtf_models::fast::{Layout, Precision};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Network name (see `rtf models`).
    #[arg(long)]
    pub model: String,
    /// Outputs of the network (a dataset's class count). Default: the count recorded in
    /// --weights, else the network's usual count (see `rtf models`).
    #[arg(long)]
    pub classes: Option<i64>,
    /// Frames per forward pass.
    #[arg(long, default_value_t = 1)]
    pub batch: i64,
    /// fp32, bf16 or fp16 (CUDA only); bf16 and fp16 need the fast path.
    #[arg(long, default_value = "fp32", value_parser = Precision::parse_inference)]
    pub precision: Precision,
    /// Time the plain eval forward (NCHW, unfolded BatchNorm) instead of the fast path.
    #[arg(long)]
    pub plain: bool,
    /// Fast-path activation layout: nhwc (channels-last) or nchw.
    #[arg(long, default_value = "nhwc")]
    pub layout: Layout,
    /// Input size as WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480", value_parser = rtf_core::parse_size)]
    pub size: (usize, usize),
    /// Untimed passes first.
    #[arg(long, default_value_t = 3)]
    pub warmup: usize,
    /// Timed passes.
    #[arg(long, default_value_t = 10)]
    pub iterations: usize,
    /// libtorch threads (default: libtorch's choice, one per core).
    #[arg(long)]
    pub threads: Option<i32>,
    /// Load these weights (random initialisation otherwise).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// cpu, cuda or cuda:N.
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// Skip the arg-max comparison with the plain fp32 path after the timing (its second
    /// network and fp32 pass then stay out of the process's peak memory).
    #[arg(long)]
    pub no_agreement: bool,
    /// Print {model, batch, precision, median_ms, p95_ms, min_ms, fps, samples_ms, peak_rss_mb,
    /// cpu, ...} as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> Result<()> {
    if let Some(threads) = args.threads {
        anyhow::ensure!(threads >= 1, "--threads must be ≥ 1");
        tch::set_num_threads(threads);
    }
    let device = rtf_train::config::available_device(&args.device).map_err(anyhow::Error::msg)?;
    let kernels = super::prepare_inference(Some(args.precision), device)?;
    let bf16_convolutions = crate::bf16_probe::policy()?.inference_convolutions();
    let num_classes = match (args.classes, &args.weights) {
        (Some(n), _) => Some(n),
        (None, Some(weights)) => super::weights_config(weights)?.map(|c| c.num_classes()),
        (None, None) => None,
    };
    let opts = BenchOptions {
        model: args.model,
        num_classes,
        batch: args.batch,
        precision: args.precision,
        path: if args.plain {
            ForwardPath::Plain
        } else {
            ForwardPath::Fast
        },
        layout: args.layout,
        kernels,
        width: args.size.0 as i64,
        height: args.size.1 as i64,
        warmup: args.warmup,
        iterations: args.iterations,
        weights: args.weights,
        device,
        agreement: !args.no_agreement,
        bf16_convolutions,
    };
    let report = bench_model(&opts)?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_report(&report);
    }
    Ok(())
}

/// The report as text: the timings, the peak memory, the CPU, the agreement.
fn print_report(report: &rtf_eval::speed::BenchReport) {
    println!(
        "{} ({} classes) batch {} {} on {} ({:?} path, {:?}, {}x{}, {} threads): median {:.2} ms/frame, p95 {:.2}, min {:.2}, {:.2} FPS; peak RSS {}",
        report.model,
        report.num_classes,
        report.batch,
        report.precision,
        report.device,
        report.path,
        report.layout,
        report.width,
        report.height,
        report.threads,
        report.median_ms,
        report.p95_ms,
        report.min_ms,
        report.fps,
        report
            .peak_rss_mb
            .map_or("unknown".to_string(), |m| format!("{m:.0} MiB"))
    );
    println!("CPU: {}", report.cpu.label());
    if let Some(convolutions) = report.bf16_convolutions {
        let how = match convolutions {
            rtf_amp::Bf16Convolutions::Emulated => "emulated (fp32 kernels over bf16 maps)",
            _ => "native (oneDNN's bf16 kernels)",
        };
        println!("bf16 convolutions: {how}");
    }
    if let Some(kernels) = &report.bf16_3x3 {
        let how = match kernels.as_str() {
            "winograd" => "Winograd forms, fp32 arithmetic over bf16 maps",
            _ => "oneDNN's bf16 kernels",
        };
        println!("bf16 3x3 convolutions of 128+ channels: {how}");
    }
    if let Some(released) = report.plain_weights_released_mb {
        println!("plain weights released once folded: {released:.0} MiB");
    }
    if let Some(agreement) = report.agreement_with_plain {
        println!(
            "arg-max agreement with the plain fp32 path: {:.4} % of pixels",
            100.0 * agreement
        );
    }
}

/// `rtf bench …` subcommands.
#[derive(clap::Subcommand)]
pub enum Bench {
    /// Inference speed of a network at 480×640: median/p95/min ms per frame, FPS, peak memory.
    Model(Args),
    /// Input-pipeline throughput: decode + flip + crop + tensor of MF frames, frames/s.
    Data(super::bench_data::Args),
    /// Training-step throughput (forward, loss, backward, optimiser): images/s, peak RSS.
    Train(super::bench_train::Args),
    /// The bf16-against-fp32 probe (`--precision bf16` runs it in a child process of its own,
    /// so the command's memory, allocator and random state are untouched): prints its JSON.
    #[command(hide = true)]
    Bf16Probe {
        #[arg(long, value_enum)]
        work: crate::bf16_probe::Work,
    },
}

pub fn run_bench(bench: Bench) -> Result<()> {
    match bench {
        Bench::Model(args) => run(args),
        Bench::Data(args) => super::bench_data::run(args),
        Bench::Train(args) => super::bench_train::run(args),
        Bench::Bf16Probe { work } => {
            println!(
                "{}",
                serde_json::to_string(&crate::bf16_probe::measure(work)?)?
            );
            Ok(())
        }
    }
}
