//! `rtf report RUN… [--eval SCORES.json…] --out report.html`: one self-contained HTML page
//! summarising training runs and evaluations. The page is rtf-report's ([`rtf_report`]); this
//! command takes its flags, writes it and says where.

use std::path::PathBuf;

use anyhow::Result;

#[derive(clap::Args)]
pub struct Args {
    /// Run folders (written by `rtf train`).
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// Score files written by `rtf eval --json` (repeatable).
    #[arg(long = "eval")]
    pub evals: Vec<PathBuf>,
    /// The HTML page to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Dataset root for the prediction grid (default: the first run's dataset, if present).
    #[arg(long, value_parser = rtf_data::dataset::parse_root)]
    pub data: Option<PathBuf>,
    /// Split of --data for the prediction grid.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Frames in the prediction grid (0: no grid).
    #[arg(long, default_value_t = 4)]
    pub frames: usize,
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

pub fn run(args: Args) -> Result<()> {
    let options = rtf_report::ReportOptions {
        runs: args.runs,
        evals: args.evals,
        data: args.data,
        split: args.split,
        frames: args.frames,
        device: args.device,
    };
    for note in rtf_report::write(&options, &args.out)? {
        eprintln!("{note}");
    }
    println!("report: {}", args.out.display());
    Ok(())
}
