//! Two processes over gloo on loopback, launched by the venv's torchrun exactly as PyTorch
//! users launch jobs (`torchrun --nproc-per-node 2 --no-python <this test binary> ...`): each
//! test is both the launcher (when no `WORLD_SIZE` is set) and the worker (under torchrun).

use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use rtf_dist::{Backend, DistEnv, ProcessGroup};
use tch::nn::{self, Module, OptimizerConfig};
use tch::{Device, Kind, Tensor};

mod launcher;
use launcher::{free_port, torchrun};

/// Runs `test` of this binary on 2 ranks; returns the folder the ranks wrote to, or None (with
/// a message) when the venv is missing.
fn launch(test: &str) -> Option<tempfile::TempDir> {
    let Some(torchrun) = torchrun() else {
        eprintln!(
            "SKIP {test}: no .venv/bin/torchrun (run `cargo xtask setup`, or set RTF_TORCHRUN)"
        );
        return None;
    };
    let out = tempfile::tempdir().unwrap();
    let exe = std::env::current_exe().unwrap();
    let started = Instant::now();
    let output = Command::new(torchrun)
        .args(["--nproc-per-node", "2", "--master-addr", "127.0.0.1"])
        .args(["--master-port", &free_port().to_string()])
        .arg("--no-python")
        .arg(exe)
        .args([test, "--exact", "--nocapture", "--test-threads", "1"])
        .env("RTF_DIST_TEST_OUT", out.path())
        .env("OMP_NUM_THREADS", "1")
        .env("GLOO_SOCKET_IFNAME", "lo")
        .output()
        .expect("torchrun runs");
    assert!(
        output.status.success(),
        "torchrun failed ({:?}) after {:?}:\n{}\n{}",
        output.status,
        started.elapsed(),
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    Some(out)
}

/// Under torchrun: this rank's group and output folder.
fn worker(timeout: Duration) -> Option<(ProcessGroup, PathBuf)> {
    let env = DistEnv::from_vars(|name| std::env::var(name).ok()).unwrap()?;
    let out = PathBuf::from(std::env::var_os("RTF_DIST_TEST_OUT").expect("launched by a test"));
    let pg = ProcessGroup::new(&env, Backend::Gloo, Device::Cpu, timeout).unwrap();
    Some((pg, out))
}

/// A small conv net without BatchNorm, built the same way on every rank.
fn net(vs: &nn::Path) -> impl Module {
    nn::seq()
        .add(nn::conv2d(vs / "c1", 3, 8, 3, Default::default()))
        .add_fn(|x| x.relu())
        .add(nn::conv2d(vs / "c2", 8, 4, 3, Default::default()))
        .add_fn(|x| x.mean_dim(&[2i64, 3][..], false, Kind::Float))
}

fn gradients(vs: &nn::VarStore) -> Vec<(String, Tensor)> {
    let mut v: Vec<_> = vs
        .variables()
        .into_iter()
        .map(|(n, t)| (n, t.grad().copy()))
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

fn sorted_vars(vs: &nn::VarStore) -> Vec<Tensor> {
    let mut v: Vec<_> = vs.variables().into_iter().collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v.into_iter().map(|(_, t)| t).collect()
}

/// DDP semantics: a step's gradients averaged over 2 ranks, each on half of the batch, equal
/// the single-process gradients of the whole batch (tolerance 1e-5), and so do the weights
/// after an SGD step.
#[test]
fn averaged_gradients_equal_single_process_gradients() {
    let Some((pg, out)) = worker(Duration::from_secs(60)) else {
        let Some(out) = launch("averaged_gradients_equal_single_process_gradients") else {
            return;
        };
        for rank in 0..2 {
            let path = out.path().join(format!("rank{rank}.txt"));
            let text = std::fs::read_to_string(&path).expect("each rank reports");
            let diff: f64 = text.trim().parse().unwrap();
            eprintln!("rank {rank}: max |gradient or weight difference| {diff:e}");
            assert!(diff < 1e-5, "rank {rank}: max |grad diff| {diff}");
        }
        return;
    };
    let (rank, world) = (pg.rank() as i64, pg.world_size() as i64);
    // The same batch of 8 on every rank; rank r trains on rows [4r, 4r + 4).
    tch::manual_seed(7);
    let x = Tensor::randn([8, 3, 12, 12], (Kind::Float, Device::Cpu));
    let y = Tensor::randint(4, [8], (Kind::Int64, Device::Cpu));
    let build = || {
        tch::manual_seed(1);
        let vs = nn::VarStore::new(Device::Cpu);
        let m = net(&vs.root());
        (vs, m)
    };
    // Distributed: own shard, gradients averaged by the bucketed all-reduce (tiny buckets, so
    // several are used), one SGD step.
    let (vs, m) = build();
    pg.broadcast_from_rank0(&sorted_vars(&vs)).unwrap();
    let mut opt = nn::Sgd::default().build(&vs, 0.1).unwrap();
    let share = 8 / world;
    let loss = m
        .forward(&x.narrow(0, rank * share, share))
        .cross_entropy_for_logits(&y.narrow(0, rank * share, share));
    opt.zero_grad();
    loss.backward();
    pg.average_gradients(&sorted_vars(&vs), 512).unwrap();
    let dist = gradients(&vs);
    opt.step();
    // Single process, whole batch.
    let (vs1, m1) = build();
    let mut opt1 = nn::Sgd::default().build(&vs1, 0.1).unwrap();
    let loss1 = m1.forward(&x).cross_entropy_for_logits(&y);
    opt1.zero_grad();
    loss1.backward();
    let single = gradients(&vs1);
    opt1.step();
    let mut max = 0f64;
    for ((n, a), (_, b)) in dist.iter().zip(&single) {
        let d = (a - b).abs().max().double_value(&[]);
        eprintln!("rank {rank} {n}: max |diff| {d:e}");
        max = max.max(d);
    }
    for (a, b) in sorted_vars(&vs).iter().zip(sorted_vars(&vs1)) {
        max = max.max((a - b).abs().max().double_value(&[]));
    }
    std::fs::write(out.join(format!("rank{rank}.txt")), format!("{max:e}")).unwrap();
}

/// A rank that dies makes the next collective of the others fail with an error, well before
/// the timeout would stop a hang.
#[test]
fn dead_rank_gives_an_error_not_a_hang() {
    let Some((pg, out)) = worker(Duration::from_secs(20)) else {
        let Some(out) = launch("dead_rank_gives_an_error_not_a_hang") else {
            return;
        };
        let text = std::fs::read_to_string(out.path().join("rank0.txt")).expect("rank 0 reports");
        let (seconds, message) = text.split_once('\n').unwrap();
        assert!(
            message.contains("all_reduce failed on rank 0 of 2"),
            "{message}"
        );
        let seconds: f64 = seconds.parse().unwrap();
        eprintln!("rank 0 noticed the dead rank after {seconds:.2} s: {message}");
        assert!(seconds < 25.0, "noticed after {seconds} s");
        return;
    };
    pg.barrier().unwrap();
    if pg.rank() == 1 {
        // Dies without a word (exit code 0, so torchrun lets rank 0 finish).
        std::process::exit(0);
    }
    let started = Instant::now();
    let mut t = Tensor::ones([1000], (Kind::Float, Device::Cpu));
    let mut error = None;
    for _ in 0..100 {
        if let Err(e) = pg.all_reduce_sum(&mut t) {
            error = Some(e);
            break;
        }
    }
    let error = error.expect("a collective with a dead peer fails");
    std::fs::write(
        out.join("rank0.txt"),
        format!("{}\n{error}", started.elapsed().as_secs_f64()),
    )
    .unwrap();
}
