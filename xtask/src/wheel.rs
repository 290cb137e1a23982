//! `cargo xtask wheel`: builds the Python package `rtf` (crates/rtf-py, maturin) into
//! `target/wheels/rtf-*.whl` for the project's `.venv` (or `--python PATH`), against that
//! interpreter's torch; and the pytest pass of `cargo xtask test`, which installs the wheel
//! into `.venv` and runs `crates/rtf-py/tests`.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::setup;

const USAGE: &str = "usage: cargo xtask wheel [--python PATH]

Builds target/wheels/rtf-<version>-<python>-linux_<arch>.whl with maturin for the project's
.venv (default) or the interpreter PATH, which needs torch==2.13.0 and maturin installed.
Install it with `pip install target/wheels/rtf-*.whl` into an environment with that torch.";

/// Parses `[--python PATH]`, builds the wheel and returns its path.
pub fn wheel(root: &Path, args: &[String]) -> Result<PathBuf> {
    let python = match args {
        [] => return build(root, &setup::ensure_libtorch(root)?, None),
        [flag, path] if flag == "--python" => PathBuf::from(path),
        [flag] if flag == "-h" || flag == "--help" => {
            println!("{USAGE}");
            return Ok(PathBuf::new());
        }
        _ => bail!("unexpected arguments {args:?}\n\n{USAGE}"),
    };
    let torch = setup::torch_package_dir(&python)?;
    build(root, &python, Some(&torch))
}

/// maturin, run by `python`: the extension linked against `torch` (LIBTORCH; None: the
/// project's `.libtorch`, as every other build, so that switching does not rebuild torch-sys),
/// torch-sys's include lookup and PyO3 pointed at the same interpreter. No auditwheel repair:
/// the wheel must not bundle libtorch (it takes torch/lib through the `$ORIGIN/../torch/lib`
/// rpath set by crates/rtf-py/build.rs).
fn build(root: &Path, python: &Path, torch: Option<&Path>) -> Result<PathBuf> {
    let bin = python.parent().context("the interpreter's folder")?;
    let path = std::env::join_paths(std::iter::once(bin.to_path_buf()).chain(
        std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default()),
    ))?;
    let out = root.join("target/wheels");
    let before = wheels_in(&out);
    let mut maturin = Command::new(python);
    if let Some(torch) = torch {
        maturin.env("LIBTORCH", torch);
    }
    let status = maturin
        .args([
            "-m",
            "maturin",
            "build",
            "--release",
            "--strip",
            "--auditwheel",
            "skip",
        ])
        .args(["--compatibility", "linux", "-m", "crates/rtf-py/Cargo.toml"])
        .arg("-i")
        .arg(python)
        .arg("--out")
        .arg(&out)
        .env("PYO3_PYTHON", python)
        .env("VIRTUAL_ENV", bin.parent().unwrap_or(bin))
        .env("PATH", path)
        .current_dir(root)
        .status()
        .context("cannot run maturin (cargo xtask setup installs it into .venv)")?;
    if !status.success() {
        bail!("maturin build failed ({status})");
    }
    newest_wheel(&out, &before)
}

fn wheels_in(dir: &Path) -> Vec<(PathBuf, std::time::SystemTime)> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "whl"))
        .filter_map(|p| Some((p.clone(), p.metadata().ok()?.modified().ok()?)))
        .collect()
}

/// The wheel maturin just wrote (the newest `.whl`, changed since `before`).
fn newest_wheel(dir: &Path, before: &[(PathBuf, std::time::SystemTime)]) -> Result<PathBuf> {
    let newest = wheels_in(dir)
        .into_iter()
        .filter(|w| !before.contains(w))
        .max_by_key(|(_, time)| *time);
    match newest {
        Some((path, _)) => {
            println!("wheel: {}", path.display());
            Ok(path)
        }
        None => bail!("maturin wrote no wheel into {}", dir.display()),
    }
}

/// `cargo xtask test`'s Python pass: the wheel built and installed into `.venv` (its torch
/// kept), then pytest over crates/rtf-py/tests (which run the release `rtf` for the CLI's side).
pub fn pytest(root: &Path) -> Result<()> {
    let python = setup::ensure_libtorch(root)?;
    let wheel = build(root, &python, None)?;
    let wheel = wheel.to_string_lossy();
    setup::pip_install(&python, &["--no-deps", "--force-reinstall", &wheel])?;
    let status = Command::new(&python)
        .args(["-m", "pytest", "-q", "crates/rtf-py/tests"])
        .env("RTF_BIN", root.join("target/release/rtf"))
        .current_dir(root)
        .status()
        .context("cannot run pytest in .venv")?;
    if !status.success() {
        bail!("the Python tests (crates/rtf-py/tests) failed ({status})");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    /// The torch version `rtf/__init__.py` demands is the one setup installs.
    #[test]
    fn the_package_checks_the_torch_setup_installs() {
        let init = include_str!("../../crates/rtf-py/python/rtf/__init__.py");
        let line = format!("TORCH_VERSION = \"{}\"", crate::setup::TORCH_VERSION);
        assert!(init.contains(&line), "__init__.py lacks `{line}`");
    }
}
