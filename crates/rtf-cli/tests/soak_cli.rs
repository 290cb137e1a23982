//! The soak script (`scripts/soak.py`, issue 30) in small: 320 training steps (40 epochs, each
//! validated and checkpointed), then eval and predict over 80 frames, sampled from `/proc`.
//! What it keeps fixed at this size: no descriptor or thread growth in any phase, the run's
//! files growing linearly with what they record, and the checkpoint's size not growing with
//! the epochs (it carried every epoch's log record before). Memory at length is the full
//! soak's (docs/src/reliability.md) and `memory_cli`'s. Linux only (elsewhere it says so).

mod common;

use std::path::Path;
use std::process::Command;

use common::*;

const STEPS: &str = "320";
const EVERY: &str = "40";
const WARM_UP: &str = "80";

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
        .arg(root.join("scripts/soak.py"))
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
        .expect("python3 runs scripts/soak.py");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{}", text(&out));
    let phases = summaries(&stdout);
    let train = &phases["train"];
    assert!(train["to"].as_u64().unwrap() >= 300, "{stdout}");
    let (fds, threads) = (range(train, "fds"), range(train, "threads"));
    // One more descriptor while a checkpoint or log line is being written.
    assert!(fds.1 - fds.0 <= 1 && threads.0 == threads.1, "{stdout}");
    for phase in ["eval", "predict"] {
        let (fds, threads) = (
            range(&phases[phase], "fds"),
            range(&phases[phase], "threads"),
        );
        assert!(fds.1 - fds.0 <= 1, "{phase}: {stdout}");
        assert!(threads.1 <= 8, "{phase}: {stdout}");
    }
    // log.jsonl grows by the same amount per 1,000 steps in both halves (a line per epoch).
    let log = &train["log_kib_per_1000_steps"];
    let (first, second) = (log[0].as_f64().unwrap(), log[1].as_f64().unwrap());
    assert!(
        first > 0.0 && (second / first - 1.0).abs() < 0.25,
        "{stdout}"
    );
    // The checkpoint's size: that of the last epoch, against a fresh 2-epoch run of the same
    // data, within a quarter of one log record (numbers change length by a few bytes).
    let run = out_dir.path().join("run");
    let last_record = std::fs::read_to_string(run.join("log.jsonl")).unwrap();
    let record_bytes = last_record.lines().last().unwrap().len() as i64;
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
        "checkpoint after 40 epochs {} bytes, after 2 {} (a record is {record_bytes})",
        size(&run),
        size(&short)
    );
}
