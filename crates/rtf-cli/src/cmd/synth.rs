use anyhow::Result;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Number of frames.
    #[arg(long, default_value_t = 48)]
    pub count: usize,
    /// Random seed; the same seed writes the same dataset.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

pub fn run(_args: Args) -> Result<()> {
    anyhow::bail!("not yet implemented")
}
