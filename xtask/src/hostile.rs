//! `cargo xtask hostile`: replays the catalogue of bad inputs (crates/rtf-cli/tests/hostile.rs)
//! against the release `rtf` binary, huge frames under `ulimit -v` included, and prints each
//! case's exit code and verdict with the counts: cases tried, clear errors, panics and silent
//! wrong results (both must be 0; the run fails otherwise). docs/src/reliability.md.

use anyhow::Result;
use std::path::Path;
use std::process::Command;

pub fn hostile(root: &Path, extra: &[String]) -> Result<()> {
    crate::setup::ensure_libtorch(root)?;
    let mut args = vec![
        "test",
        "--release",
        "-p",
        "rtf-cli",
        "--test",
        "hostile",
        "--",
        "--nocapture",
    ];
    args.extend(extra.iter().map(String::as_str));
    let status = Command::new("cargo")
        .args(&args)
        .env("RTF_HOSTILE_MEMORY", "1")
        .current_dir(root)
        .status()?;
    if !status.success() {
        anyhow::bail!("hostile catalogue failed ({status}): see the cases above");
    }
    Ok(())
}
