//! The soak script (`lab/reliability/soak.py`, issue 30) in small: 640 training steps (80 epochs, each
//! validated and checkpointed), then eval and predict over 80 frames, sampled from `/proc`.
//! What it keeps fixed at this size: no descriptor or thread growth in any phase, and the
//! checkpoint's size not growing with the epochs (it carried every epoch's log record
//! before). Linear file growth and memory at length are the full soak's
//! (docs/src/reliability.md); memory across epochs is also `memory_cli`'s. Linux only
//! (elsewhere it says so).

mod common;

use std::path::Path;
use std::process::Command;

use common::*;

const STEPS: &str = "640";
/// 640 steps, 8 an epoch (16 training frames, batch 2).
const EPOCHS: usize = 80;
const EVERY: &str = "80";
const WARM_UP: &str = "160";

fn summaries(stdout: &str) -> std::collections::HashMap<String, serde_json::Value> {
    stdout
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .map(|v| (v["phase"].as_str().unwrap_or("").to_string(), v))
        .collect()
}

/// `[min, max]` of a summary's count field.
fn range(summary: &serde_json::Value, key: &str) -> (u64, u64) {
    let r = &summary[key];
    (r[0].as_u64().unwrap(), r[1].as_u64().unwrap())
}

#[test]
fn a_short_soak_keeps_descriptors_threads_and_the_checkpoint_flat() {
    if !Path::new("/proc/self/status").exists() {
        eprintln!("soak_cli: no /proc here; the soak samples it (Linux only)");
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let out_dir = tempfile::tempdir().unwrap();
    let out = Command::new("python3")
        .arg(root.join("lab/reliability/soak.py"))
        .args([
            "--rtf",
            env!("CARGO_BIN_EXE_rtf"),
            "--out",
            s(out_dir.path()),
        ])
        .args(["--steps", STEPS, "--every", EVERY, "--warm-up", WARM_UP])
        .args([
            "--frames",
            "80",
            "--count",
            "32",
            "--size",
            "32x32",
            "--batch-size",
            "2",
        ])
        .env("OMP_NUM_THREADS", "1")
        .output()
        .expect("python3 runs lab/reliability/soak.py");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{}", text(&out));
    let phases = summaries(&stdout);
    let train = &phases["train"];
    // Every epoch ran (the script samples once a second, so how many samples a fast machine
    // takes before training ends varies: the log, not the samples, says how far it got).
    let run = out_dir.path().join("run");
    let log = std::fs::read_to_string(run.join("log.jsonl")).unwrap();
    assert_eq!(log.lines().count(), EPOCHS, "{stdout}");
    let (fds, threads) = (range(train, "fds"), range(train, "threads"));
    // One more descriptor while a checkpoint or log line is being written.
    assert!(fds.1 - fds.0 <= 1 && threads.0 == threads.1, "{stdout}");
    // Eval and predict of 80 frames may end before the script's first sample on a fast
    // machine; where they were sampled, nothing grows.
    for phase in ["eval", "predict"] {
        let Some(summary) = phases.get(phase) else {
            continue;
        };
        let (fds, threads) = (range(summary, "fds"), range(summary, "threads"));
        assert!(fds.1 - fds.0 <= 1, "{phase}: {stdout}");
        assert!(threads.1 <= 8, "{phase}: {stdout}");
    }
    // The checkpoint's size: that of the last epoch, against a fresh 2-epoch run of the same
    // data, within a quarter of one log record (numbers change length by a few bytes).
    let record_bytes = log.lines().last().unwrap().len() as i64;
    let short = out_dir.path().join("short");
    let data = out_dir.path().join("data");
    ok(&[
        "train",
        "--model",
        "mfnet",
        "--data",
        s(&data),
        "--out",
        s(&short),
    ]
    .into_iter()
    .chain(["--batch-size", "2", "--epochs", "2"])
    .collect::<Vec<_>>());
    let size = |r: &Path| {
        std::fs::metadata(r.join("checkpoint.safetensors"))
            .unwrap()
            .len() as i64
    };
    assert!(
        (size(&run) - size(&short)).abs() < record_bytes / 4,
        "checkpoint after 80 epochs {} bytes, after 2 {} (a record is {record_bytes})",
        size(&run),
        size(&short)
    );
}
