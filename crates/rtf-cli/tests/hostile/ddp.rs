//! Data-parallel training under the venv's torchrun (2 processes, gloo on loopback): a rank
//! killed mid-epoch must stop the survivor with a clear error within the timeout, and the run
//! must resume. Skipped (and said) without torchrun.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::common::*;
use crate::launcher::{free_port, torchrun};
use crate::verdict::*;
use crate::Fixture;

/// Seconds a collective waits for the other rank (`--dist-timeout`).
const TIMEOUT_S: u64 = 30;

fn launch(torchrun: &Path, args: &[String]) -> Child {
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

/// The worker of `parent` (torchrun) whose environment has `RANK=rank`.
fn worker_pid(parent: u32, rank: usize) -> Option<i32> {
    let wanted = format!("RANK={rank}");
    for task in std::fs::read_dir(format!("/proc/{parent}/task"))
        .ok()?
        .flatten()
    {
        let children = std::fs::read_to_string(task.path().join("children")).unwrap_or_default();
        for pid in children.split_whitespace() {
            let environ = std::fs::read(format!("/proc/{pid}/environ")).unwrap_or_default();
            if environ.split(|&b| b == 0).any(|v| v == wanted.as_bytes()) {
                return pid.parse().ok();
            }
        }
    }
    None
}

/// A 2-process run whose rank `victim` is killed after the first epoch; the survivor's
/// output, and how long it took to stop after the kill.
fn kill_rank(
    torchrun: &Path,
    data: &Path,
    run: &Path,
    victim: usize,
    took: &Mutex<Duration>,
) -> Output {
    let timeout = TIMEOUT_S.to_string();
    let args = long_train(data, run, &["--dist-timeout", &timeout]);
    let child = launch(torchrun, &args);
    let log = run.join("log.jsonl");
    wait_for(180, || lines(&log) >= 1);
    if let Some(pid) = worker_pid(child.id(), victim) {
        // SAFETY: kills a process this test started (through torchrun).
        unsafe { libc::kill(pid, libc::SIGKILL) };
    }
    let killed = Instant::now();
    let out = wait_at_most(child, Duration::from_secs(3 * TIMEOUT_S));
    *took.lock().unwrap() = killed.elapsed();
    out
}

fn rank_killed(torchrun: &Path, f: &Fixture, victim: usize) -> Vec<Case> {
    let run = f.t.join(format!("ddp_kill{victim}"));
    let took = Arc::new(Mutex::new(Duration::ZERO));
    let (tr, data, r, t) = (
        torchrun.to_path_buf(),
        f.data.clone(),
        run.clone(),
        took.clone(),
    );
    let (checkpoint, weights) = (
        run.join("checkpoint.safetensors"),
        run.join("final.safetensors"),
    );
    let stopped = case(
        &format!("ddp: rank {victim} killed mid-run (survivor stops)"),
        &[],
        &["rank"],
    )
    .runner(move || kill_rank(&tr, &data, &r, victim, &t))
    .intact(move || {
        checkpoint.exists()
            && !weights.exists()
            && *took.lock().unwrap() < Duration::from_secs(2 * TIMEOUT_S)
    });
    let (tr, r, log) = (torchrun.to_path_buf(), run.clone(), run.join("log.jsonl"));
    let check_log = log.clone();
    let resumed = recovers(
        &format!("ddp: resumed after rank {victim} was killed"),
        &[],
        &[],
        Box::new(move || epochs_in_order(&check_log).is_some_and(|n| n >= 2)),
    )
    .runner(move || {
        let epochs = (lines(&log) + 1).to_string();
        let args = strings(&["train", "--resume", s(&r), "--epochs", &epochs]);
        wait_at_most(launch(&tr, &args), Duration::from_secs(300))
    });
    vec![stopped, resumed]
}

pub fn cases(f: &Fixture) -> Vec<Case> {
    let Some(torchrun) = torchrun() else {
        eprintln!("hostile: SKIP the DDP cases: no .venv/bin/torchrun (run `cargo xtask setup`, or set RTF_TORCHRUN)");
        return Vec::new();
    };
    let mut cases = rank_killed(&torchrun, f, 1);
    cases.extend(rank_killed(&torchrun, f, 0));
    // The 2-process run continued by one process (no torchrun).
    let run: PathBuf = f.t.join("ddp_kill1");
    let log = run.join("log.jsonl");
    cases.push(
        case(
            "ddp: a 2-process run resumed by one process",
            &[],
            &["ddp_kill1", "2 process(es)", "torchrun"],
        )
        .runner(move || resume_one_more(&run, &log)),
    );
    cases
}
