//! Installs libtorch from PyPI into the project's `.venv` and links `.libtorch` to it, which
//! `.cargo/config.toml` hands to torch-sys. Idempotent: does nothing when all is in place.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

/// tch 0.26 is built against exactly this libtorch.
pub const TORCH_VERSION: &str = "2.13.0";

/// Makes sure `.venv` holds torch==TORCH_VERSION and `.libtorch` points at it; returns the
/// venv's python. Prints each step it takes, or one line when nothing was needed.
pub fn ensure_libtorch(root: &Path) -> Result<PathBuf> {
    let venv = root.join(".venv");
    let python = venv.join("bin/python");
    if !python.exists() {
        println!("setup: creating {}", venv.display());
        let host_python = find_host_python()?;
        let status = Command::new(&host_python)
            .args(["-m", "venv"])
            .arg(&venv)
            .status()?;
        if !status.success() {
            bail!("`{host_python} -m venv {}` failed", venv.display());
        }
    }
    let installed = torch_version(&python);
    let up_to_date = installed
        .as_deref()
        .is_some_and(|v| v.split('+').next() == Some(TORCH_VERSION));
    if !up_to_date {
        match &installed {
            Some(v) => {
                println!("setup: torch {v} found, installing {TORCH_VERSION} (needed by tch 0.26)")
            }
            None => {
                println!("setup: installing torch=={TORCH_VERSION} into .venv (about 1 minute)")
            }
        }
        // A torch that pip knows but Python cannot import is broken: reinstall it.
        let repair = installed.is_none() && pip_knows_torch(&python);
        if repair {
            println!("setup: torch in .venv cannot be imported; reinstalling");
        }
        let torch = format!("torch=={TORCH_VERSION}");
        let mut packages = vec![torch.as_str()];
        if repair {
            packages.insert(0, "--force-reinstall");
        }
        pip_install(&python, &packages)?;
        if torch_version(&python).is_none() {
            bail!(
                "torch installed but `import torch` fails in {}",
                python.display()
            );
        }
    }
    let torch_dir = torch_package_dir(&python)?;
    let link = root.join(".libtorch");
    let target = torch_dir
        .strip_prefix(root)
        .map(Path::to_path_buf)
        .unwrap_or(torch_dir.clone());
    let current = std::fs::read_link(&link).ok();
    if current.as_deref() != Some(target.as_path()) {
        if link.symlink_metadata().is_ok() {
            std::fs::remove_file(&link)
                .with_context(|| format!("cannot replace {}", link.display()))?;
        }
        std::os::unix::fs::symlink(&target, &link)
            .with_context(|| format!("cannot link {} -> {}", link.display(), target.display()))?;
        println!("setup: linked .libtorch -> {}", target.display());
    }
    ensure_script_packages(&python)?;
    if up_to_date && current.is_some() {
        println!("setup: libtorch {TORCH_VERSION} ready (.venv)");
    }
    Ok(python)
}

/// Python packages the scripts and tests use, as (import name, PyPI name): the benchmark peers
/// (`lab/bench/bench_*.py`) need NumPy and Pillow; the TensorBoard test reads event files back
/// with TensorBoard's reader; `rtf export --format onnx` and its test use PyTorch's ONNX
/// exporter (`onnx`, `onnxscript`) and check the result with onnxruntime; `cargo xtask
/// wheel` builds the Python package with maturin, and `cargo xtask test` runs its tests with
/// pytest.
const SCRIPT_PACKAGES: [(&str, &str); 8] = [
    ("numpy", "numpy"),
    ("PIL", "pillow"),
    ("tensorboard", "tensorboard"),
    ("onnx", "onnx"),
    ("onnxscript", "onnxscript"),
    ("onnxruntime", "onnxruntime"),
    ("maturin", "maturin>=1.16,<2"),
    ("pytest", "pytest"),
];

fn ensure_script_packages(python: &Path) -> Result<()> {
    let missing: Vec<&str> = SCRIPT_PACKAGES
        .iter()
        .filter(|(module, _)| {
            !Command::new(python)
                .args(["-c", &format!("import {module}")])
                .output()
                .is_ok_and(|o| o.status.success())
        })
        .map(|&(_, package)| package)
        .collect();
    if !missing.is_empty() {
        println!(
            "setup: installing {} into .venv (scripts and tests)",
            missing.join(", ")
        );
        pip_install(python, &missing)?;
    }
    ensure_protoc()
}

/// The `tboard` crate (TensorBoard event files) compiles TensorBoard's protos at build time
/// with `protoc`: use `$PROTOC` or the one on PATH, else install Debian's `protobuf-compiler`.
fn ensure_protoc() -> Result<()> {
    let works = |cmd: &std::ffi::OsStr| {
        Command::new(cmd)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if let Some(protoc) = std::env::var_os("PROTOC") {
        if works(&protoc) {
            return Ok(());
        }
        bail!("PROTOC={} does not run", protoc.to_string_lossy());
    }
    if works("protoc".as_ref()) {
        return Ok(());
    }
    println!("setup: installing protobuf-compiler (protoc, needed to build the tboard crate)");
    let apt = |args: &[&str]| {
        Command::new("apt-get")
            .args(args)
            .status()
            .is_ok_and(|s| s.success())
    };
    if !(apt(&["update", "-qq"]) && apt(&["install", "-y", "-qq", "protobuf-compiler"])) {
        bail!(
            "protoc not found and `apt-get install protobuf-compiler` failed: install protoc \
             (Debian/Ubuntu: protobuf-compiler) or point PROTOC at one"
        );
    }
    Ok(())
}

/// `pip install --quiet <args>` with the venv's Python. No download cache: PyTorch's wheels
/// would leave gigabytes beside the `.venv` that holds them.
pub fn pip_install(python: &Path, args: &[&str]) -> Result<()> {
    let status = Command::new(python)
        .args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "--disable-pip-version-check",
            "--no-cache-dir",
        ])
        .args(args)
        .status()
        .context("cannot run pip in .venv")?;
    if !status.success() {
        bail!("pip install {} failed; is PyPI reachable?", args.join(" "));
    }
    Ok(())
}

fn find_host_python() -> Result<String> {
    for candidate in ["python3", "python"] {
        if Command::new(candidate)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
        {
            return Ok(candidate.to_string());
        }
    }
    bail!("no python3 found on PATH; it is needed once to create .venv with torch")
}

fn torch_version(python: &Path) -> Option<String> {
    let out = Command::new(python)
        .args(["-c", "import torch; print(torch.__version__)"])
        .output()
        .ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn pip_knows_torch(python: &Path) -> bool {
    Command::new(python)
        .args(["-m", "pip", "show", "--quiet", "torch"])
        .output()
        .is_ok_and(|o| o.status.success())
}

pub fn torch_package_dir(python: &Path) -> Result<PathBuf> {
    let out = Command::new(python)
        .args([
            "-c",
            "import os, torch; print(os.path.dirname(torch.__file__))",
        ])
        .output()
        .context("cannot ask torch for its location")?;
    if !out.status.success() {
        bail!(
            "cannot locate torch: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    Ok(PathBuf::from(String::from_utf8_lossy(&out.stdout).trim()))
}
