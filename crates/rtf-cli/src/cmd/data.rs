//! `rtf data check DIR`, `rtf data stats DIR [--json]` and `rtf data fingerprint DIR [--json]`.

use anyhow::{bail, Result};
use rtf_data::inspect;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: DataCommand,
}

#[derive(clap::Subcommand)]
pub enum DataCommand {
    /// Validate a dataset completely; lists every problem, exit code 1 if there is any.
    Check {
        /// Dataset root (dataset.yaml or its folder, MF, Freiburg Thermal, BDD100K-night, MSRS, PST900 or FMB layout).
        #[arg(value_parser = rtf_data::dataset::parse_root)]
        dir: PathBuf,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Frames per split and day/night, per-class pixel shares.
    Stats {
        /// Dataset root (dataset.yaml or its folder, MF, Freiburg Thermal, BDD100K-night, MSRS, PST900 or FMB layout).
        #[arg(value_parser = rtf_data::dataset::parse_root)]
        dir: PathBuf,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// SHA-256 of every file each split reads: one hash per split and one for the dataset
    /// (recorded by `rtf eval --json` and in a run's config.json).
    Fingerprint {
        /// Dataset root (MF, Freiburg Thermal, dataset.yaml or its folder, MSRS, PST900 or FMB layout).
        #[arg(value_parser = rtf_data::dataset::parse_root)]
        dir: PathBuf,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
}

pub fn run(args: Args) -> Result<()> {
    match args.command {
        DataCommand::Check { dir, json } => {
            let report = inspect::check(&dir);
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                println!("{}", recognised(&dir, &report));
                for p in &report.problems {
                    println!("{p}");
                }
                if let Some(skeleton) = &report.skeleton {
                    println!(
                        "a {} beside the data describes any tree (docs: bring-your-data.md); from what {} holds:\n{skeleton}",
                        rtf_data::description::DESCRIPTION_FILE,
                        dir.display()
                    );
                }
                let format = report.format.map_or("unknown", |f| f.name());
                println!(
                    "{}: {} layout, {} frames decoded, {} problem(s)",
                    dir.display(),
                    format,
                    report.frames,
                    report.problems.len()
                );
            }
            if !report.is_ok() {
                bail!("{} problem(s) in {}", report.problems.len(), dir.display());
            }
            Ok(())
        }
        DataCommand::Fingerprint { dir, json } => {
            let fp = rtf_data::fingerprint(&dir)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&fp)?);
                return Ok(());
            }
            println!(
                "{} ({} layout, {} files, {} bytes)",
                dir.display(),
                fp.format.name(),
                fp.files,
                fp.bytes
            );
            println!("{:<16} {:>7}  {}", "split", "frames", fp.algorithm);
            for s in &fp.splits {
                println!("{:<16} {:>7}  {}", s.name, s.frames, s.hash);
            }
            println!("{:<16} {:>7}  {}", "dataset", "", fp.hash);
            Ok(())
        }
        DataCommand::Stats { dir, json } => {
            let stats = inspect::stats(&dir)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&stats)?);
                return Ok(());
            }
            print_stats(&dir, &stats);
            Ok(())
        }
    }
}

/// The first line of `rtf data check`: which layout was recognised, which classes it reads and
/// how its thermal is normalised (nothing about a dataset is guessed silently).
fn recognised(dir: &std::path::Path, report: &inspect::CheckReport) -> String {
    let Some(format) = report.format else {
        return format!("{}: no known layout", dir.display());
    };
    let mut line = format!("{}: recognised the {} layout", dir.display(), format.name());
    if let Some(classes) = &report.class_set {
        let ignore = classes.values_note();
        line += &format!(
            "; {} classes ({}{ignore}): {}",
            classes.len(),
            classes.name,
            classes.names().join(", ")
        );
    }
    if let Some(thermal) = &report.thermal {
        line += &format!("; thermal {thermal}");
    }
    line
}

/// `rtf data stats` as a table: splits, then the class histogram by name.
fn print_stats(dir: &std::path::Path, stats: &inspect::Stats) {
    println!("{} ({} layout)", dir.display(), stats.format.name());
    println!(
        "{:<16} {:>7} {:>7} {:>7}",
        "split", "frames", "day", "night"
    );
    for s in &stats.splits {
        println!("{:<16} {:>7} {:>7} {:>7}", s.name, s.frames, s.day, s.night);
    }
    println!(
        "\nclass pixel share over {} labelled frames",
        stats.labelled_frames
    );
    let width = stats
        .classes
        .iter()
        .map(|c| c.name.len())
        .max()
        .unwrap_or(0)
        .max(12);
    for c in &stats.classes {
        println!(
            "{:>3} {:<width$} {:>8.4} %  {:>12} px",
            c.id,
            c.name,
            100.0 * c.share,
            c.pixels
        );
    }
    if stats.ignored_pixels > 0 {
        println!("ignored (ignore id): {} px", stats.ignored_pixels);
    }
}
