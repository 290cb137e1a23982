//! `rtf`: train, evaluate, run and calibrate RGB-thermal segmentation networks.

mod allocator;
mod bf16_probe;
mod cmd;
mod output_guard;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "rtf",
    version,
    about = "RGB-thermal semantic segmentation toolkit"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

// One command is parsed per process: the size of the largest one's flags costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum Command {
    /// Write a synthetic dataset (MF or Freiburg layout) or calibration rig.
    Synth(cmd::synth::Args),
    /// Check a dataset (every problem, exit 1) or print its statistics.
    Data(cmd::data::Args),
    /// List every network with its parameter count and size.
    Models(cmd::models::Args),
    /// Benchmarks (`rtf bench model --model NAME`).
    #[command(subcommand)]
    Bench(cmd::bench_model::Bench),
    /// Train a network (writes a run folder; --resume continues one); --recipe runs a paper's
    /// procedure (HeatNet's teacher–student, adversarial, two-stage, distillation).
    Train(cmd::train::Args),
    /// List the papers' training recipes (`rtf train --recipe NAME`).
    Recipes(cmd::recipes::Args),
    /// Evaluate weights on a split: per-class Acc/IoU, mAcc/mIoU, day and night.
    Eval(cmd::eval::Args),
    /// Export a network with its weights for deployment (TorchScript or ONNX).
    Export(cmd::export::Args),
    /// One self-contained HTML page of runs: curves, per-class IoU, confusion, predictions.
    Report(cmd::report::Args),
    /// Segment RGB-T images: class-id PNG, colour PNG, optional logits .npy.
    Predict(cmd::predict::Args),
    /// Targetless RGB-thermal calibration of a rig (rig.yaml → calib.yaml).
    Calibrate(cmd::calibrate::Args),
}

fn main() {
    // `rtf models | head` should end quietly, as Unix tools do, not panic on the closed pipe
    // (Rust ignores SIGPIPE, so printing would fail with EPIPE).
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of one signal before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    // Every command repeats the same tensor work; keeping freed memory a while avoids
    // page-faulting activations in again on every pass, and mimalloc keeps it without
    // fragmenting (allocator).
    allocator::set_purge_delay();
    // cuDNN's autotuner, a libtorch setting of the process: on unless RTF_CUDNN_BENCHMARK=0.
    tch::Cuda::cudnn_set_benchmark(rtf_train::config::cudnn_benchmark(|v| {
        std::env::var(v).ok()
    }));
    // The kernel policy is read where each command needs it (its folds' kernels, a run's
    // recorded choices), once per command; a bad variable stops here, naming it.
    let result = bf16_probe::policy().and_then(|_| run(cli.command));
    if let Err(err) = result {
        eprintln!("error: {err:#}");
        std::process::exit(1);
    }
}

fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Synth(args) => cmd::synth::run(args),
        Command::Data(args) => cmd::data::run(args),
        Command::Models(args) => cmd::models::run(args),
        Command::Bench(bench) => cmd::bench_model::run_bench(bench),
        Command::Train(args) => cmd::train::run(args),
        Command::Recipes(args) => cmd::recipes::run(args),
        Command::Eval(args) => cmd::eval::run(args),
        Command::Export(args) => cmd::export::run(args),
        Command::Report(args) => cmd::report::run(args),
        Command::Predict(args) => cmd::predict::run(args),
        Command::Calibrate(args) => cmd::calibrate::run(args),
    }
}
