use anyhow::{Context, Result};
use rtf_data::synth::{self, Misalignment, SynthConfig, SynthFormat};
use std::path::PathBuf;

/// What `rtf synth` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// MF layout: images/ (RGBA, thermal in alpha), labels/, split files; 9 classes.
    Mf,
    /// Freiburg Thermal layout: 8-bit RGB, 16-bit IR, 13 classes.
    Freiburg,
    /// The plain layout (dataset.yaml; docs "Your own data"): 8-bit RGB, 16-bit radiometric
    /// thermal with its range, MF's 9 classes as ids.
    Plain,
    /// A calibration rig for `rtf calibrate`: rig.yaml, RGB stereo pairs, depth, thermal
    /// frames rendered through a known thermal camera, and ground_truth.yaml.
    CalibrationRig,
}

/// Depth source the frames of a synthetic calibration rig list in rig.yaml.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum RigDepth {
    /// 16-bit depth PNGs.
    Given,
    /// Only the right image of a stereo pair (depth from the built-in matcher).
    Stereo,
    /// Both (depth wins).
    Both,
}

#[derive(clap::Args)]
pub struct Args {
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Number of frames (datasets: half day, half night, at least 6; default 48. Calibration
    /// rig: default 12).
    #[arg(long)]
    pub count: Option<usize>,
    /// Random seed; the same seed writes the same dataset.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Image size as WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480", value_parser = super::parse_size)]
    pub size: (usize, usize),
    /// Dataset layout.
    #[arg(long, value_enum, default_value_t = Format::Mf)]
    pub format: Format,
    /// Misalign thermal against RGB by up to this many pixels (at 640 px width), ±1° and
    /// ±50 ms of object motion, as between the real MF cameras. Off by default.
    #[arg(long)]
    pub misalign: Option<f32>,
    /// Calibration rig: which depth source the frames list in rig.yaml.
    #[arg(long, value_enum, default_value_t = RigDepth::Both)]
    pub rig_depth: RigDepth,
}

pub fn run(args: Args) -> Result<()> {
    let format = match args.format {
        Format::Mf => SynthFormat::Mf,
        Format::Freiburg => SynthFormat::Freiburg,
        Format::Plain => SynthFormat::Plain,
        Format::CalibrationRig => return calibration_rig(&args),
    };
    let cfg = SynthConfig {
        count: args.count.unwrap_or(48),
        seed: args.seed,
        width: args.size.0,
        height: args.size.1,
        format,
        misalignment: args.misalign.map(|px| Misalignment {
            max_shift_px: px,
            ..Misalignment::default()
        }),
    };
    let summary = synth::generate(&args.out, &cfg)
        .with_context(|| format!("writing {}", args.out.display()))?;
    let splits: Vec<String> = summary
        .splits
        .iter()
        .map(|(n, c)| format!("{n} {c}"))
        .collect();
    println!(
        "wrote {} frames ({}x{}, {:?} layout) to {}: {}",
        summary.frames,
        cfg.width,
        cfg.height,
        format,
        args.out.display(),
        splits.join(", ")
    );
    Ok(())
}

fn calibration_rig(args: &Args) -> Result<()> {
    use rtf_calib::synth_rig::{write_rig, DepthSource, RigSynthConfig};
    let cfg = RigSynthConfig {
        seed: args.seed,
        width: args.size.0,
        height: args.size.1,
        frames: args.count.unwrap_or(RigSynthConfig::default().frames),
        depth: match args.rig_depth {
            RigDepth::Given => DepthSource::Given,
            RigDepth::Stereo => DepthSource::Stereo,
            RigDepth::Both => DepthSource::Both,
        },
        ..Default::default()
    };
    let rig = write_rig(&args.out, &cfg)
        .with_context(|| format!("writing a synthetic rig to {}", args.out.display()))?;
    println!(
        "wrote {} ({} frames) and {}",
        rig.rig_path.display(),
        cfg.frames,
        rig.ground_truth_path.display()
    );
    Ok(())
}
