//! `rtf`: train, evaluate, run and calibrate RGB-thermal segmentation networks.

mod cmd;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "rtf", version, about = "RGB-thermal semantic segmentation toolkit")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Write a synthetic dataset (MF or Freiburg layout) or calibration rig.
    Synth(cmd::synth::Args),
    /// List every network with its parameter count and size.
    Models(cmd::models::Args),
    /// Benchmarks (`rtf bench model --model NAME`).
    #[command(subcommand)]
    Bench(cmd::bench_model::Bench),
    /// Targetless RGB-thermal calibration of a rig (rig.yaml → calib.yaml).
    Calibrate(cmd::calibrate::Args),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Synth(args) => cmd::synth::run(args),
        Command::Models(args) => cmd::models::run(args),
        Command::Bench(bench) => cmd::bench_model::run_bench(bench),
        Command::Calibrate(args) => cmd::calibrate::run(args),
    };
    if let Err(err) = result {
        eprintln!("error: {err:#}");
        std::process::exit(1);
    }
}
