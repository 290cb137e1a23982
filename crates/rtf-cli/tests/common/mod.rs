//! Helpers shared by the CLI tests: run the `rtf` binary, check its outcome, and the two
//! invocations most tests start from (a synthetic MF dataset, a short training run).
// Each test file uses a different subset.
#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

pub fn rtf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args(args)
        .output()
        .expect("rtf runs")
}

/// Runs `rtf`, requires success, returns stdout.
pub fn ok(args: &[&str]) -> String {
    let out = rtf(args);
    assert!(
        out.status.success(),
        "rtf {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Runs `rtf`, requires failure, returns stderr.
pub fn fails(args: &[&str]) -> String {
    let out = rtf(args);
    assert!(!out.status.success(), "rtf {args:?} should fail");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// stdout then stderr.
pub fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Runs `rtf`, requires success, parses stdout as JSON.
pub fn json_out(args: &[&str]) -> serde_json::Value {
    serde_json::from_str(&ok(args)).expect("JSON on stdout")
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

pub fn json_file(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// `rtf synth` of an MF-layout dataset: `count` frames of `size` (WxH) from `seed`.
pub fn synth_mf(data: &Path, count: &str, seed: &str, size: &str) {
    ok(&[
        "synth",
        "--out",
        s(data),
        "--count",
        count,
        "--seed",
        seed,
        "--size",
        size,
    ]);
}

/// Arguments of `rtf train` for one short epoch (batch 2, `max_steps` steps), then `extra`.
pub fn short_train<'a>(
    data: &'a Path,
    run: &'a Path,
    max_steps: &'a str,
    extra: &[&'a str],
) -> Vec<&'a str> {
    let mut args = vec![
        "train",
        "--data",
        s(data),
        "--out",
        s(run),
        "--epochs",
        "1",
        "--batch-size",
        "2",
        "--max-steps",
        max_steps,
    ];
    args.extend_from_slice(extra);
    args
}

/// Starts a long `rtf train` on `data` into `run`, waits until it has written its config
/// (signal handlers are installed by then), lets it take a step, sends `signal`, and returns
/// its output.
pub fn train_then_signal(data: &Path, run: &Path, signal: i32) -> Output {
    let child = Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args([
            "train",
            "--data",
            s(data),
            "--out",
            s(run),
            "--epochs",
            "500",
            "--batch-size",
            "2",
            "--val-split",
            "none",
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    while !run.join("config.json").exists() {
        assert!(started.elapsed().as_secs() < 60, "training did not start");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    // SAFETY: sends a signal to our own child process.
    assert_eq!(unsafe { libc::kill(child.id() as i32, signal) }, 0);
    child.wait_with_output().unwrap()
}

/// Every file below `root` with its bytes, sorted by path: compared before and after a
/// command, it says that the command changed no file there.
pub fn files_of(root: &Path) -> Vec<(std::path::PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let path = entry.path();
            match path.is_dir() {
                true => stack.push(path),
                false => out.push((path.clone(), std::fs::read(&path).unwrap())),
            }
        }
    }
    out.sort();
    out
}

/// The bf16 arithmetic the `rtf` these tests start gets: this CPU's flags under the oneDNN ISA
/// cap of the test's environment (which the binary inherits and reads alike).
pub fn bf16_arithmetic() -> rtf_amp::Bf16Arithmetic {
    rtf_amp::Bf16Arithmetic::from_vars(|var| std::env::var(var).ok())
}
