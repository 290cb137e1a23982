//! Project tasks: `cargo xtask <task>`. A plain binary without libtorch, so it builds on a
//! fresh machine and can install libtorch itself.

mod setup;

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

const USAGE: &str = "usage: cargo xtask <task>

tasks:
  setup    install libtorch (PyPI torch==2.13.0) into .venv and link .libtorch (idempotent)
  test     setup, then run the whole test suite (release build)
  demo     setup, build, synthesise a small RGB-T dataset, train MFNet, evaluate, draw predictions
";

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let root = project_root();
    match args.first().map(String::as_str) {
        Some("setup") => setup::ensure_libtorch(&root).map(|_| ()),
        Some("test") => test(&root, &args[1..]),
        Some("demo") => demo(&root, &args[1..]),
        Some("-h" | "--help" | "help") | None => {
            print!("{USAGE}");
            Ok(())
        }
        Some(other) => bail!("unknown task `{other}`\n\n{USAGE}"),
    }
}

/// The repository root (xtask lives one level below it).
fn project_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("xtask has a parent").to_path_buf()
}

/// Runs a command in the project root, failing with the command line if it fails.
fn run(root: &Path, program: &str, args: &[&str]) -> Result<()> {
    let status = Command::new(program)
        .args(args)
        .current_dir(root)
        .status()
        .with_context(|| format!("cannot start `{program}`"))?;
    if !status.success() {
        bail!("`{program} {}` failed ({status})", args.join(" "));
    }
    Ok(())
}

fn test(root: &Path, extra: &[String]) -> Result<()> {
    setup::ensure_libtorch(root)?;
    let mut args = vec!["test", "--workspace", "--release"];
    args.extend(extra.iter().map(String::as_str));
    run(root, "cargo", &args)
}

fn demo(root: &Path, extra: &[String]) -> Result<()> {
    setup::ensure_libtorch(root)?;
    run(root, "cargo", &["build", "--release", "-p", "rtf-cli"])?;
    let rtf = root.join("target/release/rtf");
    let rtf = rtf.to_str().context("non-UTF-8 path")?;
    let mut args = vec!["demo", "--out", "demo"];
    args.extend(extra.iter().map(String::as_str));
    run(root, rtf, &args)
}
