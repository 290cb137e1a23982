//! `cargo xtask hostile`: replays the catalogue of bad inputs and interruptions
//! (crates/rtf-cli/tests/hostile/, one module per surface: predict/eval/data inputs, recipes,
//! report, export, `--drop`/`--precision`, DDP, dataset.yaml, rig.yaml's prior) against the
//! release `rtf` binary, huge frames under `ulimit -v` included, and prints each case's exit
//! code and verdict, the counts per group as a Markdown table and in all: cases tried, clear
//! outcomes, panics and silent wrong results (both must be 0; the run fails otherwise).
//! `RTF_HOSTILE_ONLY=recipes,report` runs those modules alone. docs/src/reliability.md.

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
        .env("RTF_HOSTILE_SLOW", "1")
        .current_dir(root)
        .status()?;
    if !status.success() {
        anyhow::bail!("hostile catalogue failed ({status}): see the cases above");
    }
    Ok(())
}
