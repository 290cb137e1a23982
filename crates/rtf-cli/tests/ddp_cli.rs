//! `rtf train` data-parallel under the venv's torchrun, as users launch it
//! (`torchrun --nproc-per-node 2 --no-python rtf train ...`), over gloo on loopback. Without
//! the venv the test says so and skips (CI has it: `cargo xtask setup`).

mod common;

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{json_file, s, synth_mf};

#[path = "../../rtf-dist/tests/launcher/mod.rs"]
mod launcher;
use launcher::{free_port, torchrun};

fn spawn(torchrun: &Path, args: &[&str]) -> Child {
    Command::new(torchrun)
        .args(["--nproc-per-node", "2", "--master-addr", "127.0.0.1"])
        .args(["--master-port", &free_port().to_string()])
        .arg("--no-python")
        .arg(env!("CARGO_BIN_EXE_rtf"))
        .args(args)
        .env("OMP_NUM_THREADS", "1")
        .env("GLOO_SOCKET_IFNAME", "lo")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("torchrun runs")
}

fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// The worker of `parent` (torchrun) whose environment has `RANK=rank`.
fn worker_pid(parent: u32, rank: usize) -> Option<i32> {
    let tasks = std::fs::read_dir(format!("/proc/{parent}/task")).ok()?;
    for task in tasks.flatten() {
        let children = std::fs::read_to_string(task.path().join("children")).unwrap_or_default();
        for pid in children.split_whitespace() {
            let environ = std::fs::read(format!("/proc/{pid}/environ")).unwrap_or_default();
            let wanted = format!("RANK={rank}");
            if environ.split(|&b| b == 0).any(|v| v == wanted.as_bytes()) {
                return pid.parse().ok();
            }
        }
    }
    None
}

/// A 2-process run whose rank 1 is killed mid-run stops rank 0 with an error and a checkpoint
/// (never a hang), also with synchronised BatchNorm's collectives inside every forward and
/// backward; the run folder is rank 0's alone and records `world_size` and `sync_batch_norm`;
/// resumed under torchrun it finishes.
#[test]
fn a_two_process_run_survives_a_killed_rank_and_resumes() {
    let Some(torchrun) = torchrun() else {
        eprintln!("SKIP: no .venv/bin/torchrun (run `cargo xtask setup`, or set RTF_TORCHRUN)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (data, run) = (dir.path().join("data"), dir.path().join("run"));
    synth_mf(&data, "12", "4", "32x32");
    let child = spawn(
        &torchrun,
        &[
            "train",
            "--data",
            s(&data),
            "--out",
            s(&run),
            "--epochs",
            "400",
            "--batch-size",
            "2",
            // BatchNorm's collectives in the forward and backward too must not hang.
            "--sync-bn",
        ],
    );
    let started = Instant::now();
    let log = run.join("log.jsonl");
    while std::fs::read_to_string(&log)
        .unwrap_or_default()
        .lines()
        .count()
        < 1
    {
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "training did not start"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let victim = worker_pid(child.id(), 1).expect("rank 1 is a child of torchrun");
    // SAFETY: kills a process this test started (through torchrun).
    assert_eq!(unsafe { libc::kill(victim, libc::SIGKILL) }, 0);
    let killed_at = Instant::now();
    let out = child.wait_with_output().unwrap();
    let all = text(&out);
    assert!(!out.status.success(), "{all}");
    assert!(
        killed_at.elapsed() < Duration::from_secs(60),
        "rank 0 noticed late"
    );
    assert!(all.contains("every rank stops"), "{all}");
    assert!(all.contains("rank 0 wrote a checkpoint"), "{all}");
    assert!(run.join("checkpoint.safetensors").exists());
    assert!(!run.join("final.safetensors").exists());
    let config = json_file(&run.join("config.json"));
    assert_eq!(config["compute"]["world_size"], 2);
    assert_eq!(config["network"]["sync_batch_norm"], true);
    let done = std::fs::read_to_string(&log).unwrap().lines().count();
    assert!(done < 400, "killed before the end");
    // Resumed by 2 processes, it runs to (a shortened) end.
    let epochs = (done + 1).to_string();
    let out = spawn(
        &torchrun,
        &["train", "--resume", s(&run), "--epochs", &epochs],
    )
    .wait_with_output()
    .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    assert!(run.join("final.safetensors").exists());
    assert_eq!(
        std::fs::read_to_string(&log).unwrap().lines().count(),
        done + 1
    );
    let names: Vec<String> = std::fs::read_dir(&run)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names.iter().all(|n| !n.contains("rank")),
        "only rank 0 writes the run folder: {names:?}"
    );
}
