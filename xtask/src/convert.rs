//! `cargo xtask convert-pth IN.pth OUT.safetensors [--allow-pickle]`: converts a PyTorch
//! checkpoint (plain state_dict, or nested under `state_dict` / `model`, `module.` prefixes
//! stripped, legacy non-zip pickles too) into a safetensors state_dict that rtf loads, using
//! the `.venv` Python (scripts/convert_pth.py). xtask itself stays free of libtorch.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

pub const USAGE: &str = "usage: cargo xtask convert-pth IN.pth OUT.safetensors [--allow-pickle]";

pub fn convert_pth(root: &Path, args: &[String]) -> Result<()> {
    let allow_pickle = args.iter().any(|a| a == "--allow-pickle");
    let paths: Vec<&String> = args.iter().filter(|a| *a != "--allow-pickle").collect();
    if paths.len() != 2 || paths.iter().any(|p| p.starts_with('-')) {
        bail!("{USAGE}");
    }
    let cwd = std::env::current_dir().context("cannot read the current directory")?;
    let absolute = |p: &str| -> PathBuf { cwd.join(p) };
    let (input, output) = (absolute(paths[0]), absolute(paths[1]));
    if !input.is_file() {
        bail!("{}: no such file", input.display());
    }
    let python = crate::setup::ensure_libtorch(root)?;
    let status = Command::new(&python)
        .arg(root.join("scripts/convert_pth.py"))
        .arg(&input)
        .arg(&output)
        .args(allow_pickle.then_some("--allow-pickle"))
        .status()
        .with_context(|| format!("cannot run {}", python.display()))?;
    if !status.success() {
        bail!("converting {} failed", input.display());
    }
    Ok(())
}
