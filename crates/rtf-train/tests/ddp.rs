//! Data-parallel training on 2 processes over gloo on loopback, launched by the venv's
//! torchrun as users launch it (`torchrun --nproc-per-node 2 --no-python <this test binary>
//! <test> --exact`): each test is the launcher when no `WORLD_SIZE` is set and a rank under
//! torchrun. Without the venv they say so and skip (CI has it: `cargo xtask setup`).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use rtf_dist::{Backend, DistEnv, ProcessGroup};
use rtf_train::config::StepAt;
use rtf_train::ddp::Ddp;
use rtf_train::procedure::Trained;
use rtf_train::{DatasetConfig, OptimizerConfig, RunConfig, TrainConfig};
use tch::nn::{self, Module};
use tch::{Device, Kind, Tensor};

#[path = "../../rtf-dist/tests/launcher/mod.rs"]
mod launcher;
use launcher::{free_port, torchrun};

/// Runs `test` of this binary on 2 ranks with `RTF_DDP_DIR=dir` and `RTF_DDP_PHASE=phase`;
/// false (with a message) when there is no torchrun.
fn launch(test: &str, dir: &Path, phase: &str) -> bool {
    let Some(torchrun) = torchrun() else {
        eprintln!(
            "SKIP {test}: no .venv/bin/torchrun (run `cargo xtask setup`, or set RTF_TORCHRUN)"
        );
        return false;
    };
    let output = Command::new(torchrun)
        .args(["--nproc-per-node", "2", "--master-addr", "127.0.0.1"])
        .args(["--master-port", &free_port().to_string()])
        .arg("--no-python")
        .arg(std::env::current_exe().unwrap())
        .args([test, "--exact", "--nocapture", "--test-threads", "1"])
        .env("RTF_DDP_DIR", dir)
        .env("RTF_DDP_PHASE", phase)
        .env("OMP_NUM_THREADS", "1")
        .env("GLOO_SOCKET_IFNAME", "lo")
        .output()
        .expect("torchrun runs");
    assert!(
        output.status.success(),
        "torchrun ({phase}) failed ({:?}):\n{}\n{}",
        output.status,
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    true
}

/// Under torchrun: this rank's DDP handle, the test folder and phase.
fn rank() -> Option<(std::sync::Arc<Ddp>, PathBuf, String)> {
    let env = DistEnv::from_vars(|name| std::env::var(name).ok()).unwrap()?;
    let group =
        ProcessGroup::new(&env, Backend::Gloo, Device::Cpu, Duration::from_secs(120)).unwrap();
    let dir = PathBuf::from(std::env::var_os("RTF_DDP_DIR").expect("launched by a test"));
    let phase = std::env::var("RTF_DDP_PHASE").unwrap_or_default();
    Some((Ddp::new(group), dir, phase))
}

/// `Trained::minimise` on 2 ranks, each on half of a batch, takes the step a single process
/// takes on the whole batch: same gradients and same updated weights (tolerance 1e-5), for a
/// network without train-mode BatchNorm.
#[test]
fn a_step_on_two_ranks_equals_the_single_process_step_on_the_whole_batch() {
    let test = "a_step_on_two_ranks_equals_the_single_process_step_on_the_whole_batch";
    let Some((ddp, dir, _)) = rank() else {
        let dir = tempfile::tempdir().unwrap();
        if !launch(test, dir.path(), "") {
            return;
        }
        for r in 0..2 {
            let text = std::fs::read_to_string(dir.path().join(format!("rank{r}")))
                .expect("each rank reports");
            let diff: f64 = text.trim().parse().unwrap();
            eprintln!("rank {r}: max |difference| to the single process {diff:e}");
            assert!(diff < 1e-5, "rank {r}: {diff}");
        }
        return;
    };
    let (r, world) = (ddp.rank() as i64, ddp.world_size() as i64);
    tch::manual_seed(3);
    let x = Tensor::randn([8, 4, 16, 16], (Kind::Float, Device::Cpu));
    let y = Tensor::randint(3, [8, 16, 16], (Kind::Int64, Device::Cpu));
    let schedule = OptimizerConfig::mfnet_paper();
    let build = || {
        tch::manual_seed(11);
        let trained = Trained::new("student", Device::Cpu, &schedule);
        let root = trained.vs.root();
        let net = nn::seq()
            .add(nn::conv2d(&root / "c1", 4, 8, 3, padding(1)))
            .add_fn(|t| t.relu())
            .add(nn::conv2d(&root / "c2", 8, 3, 3, padding(1)));
        (trained, net)
    };
    // Two ranks, each a half.
    let (mut trained, net) = build();
    trained.ddp = Some(ddp.clone());
    let share = 8 / world;
    let loss = net
        .forward(&x.narrow(0, r * share, share))
        .cross_entropy_loss::<Tensor>(
            &y.narrow(0, r * share, share),
            None,
            tch::Reduction::Mean,
            -100,
            0.0,
        );
    trained.minimise(&loss, StepAt::start_of(0));
    ddp.check().unwrap();
    // One process, the whole batch.
    let (mut single, net1) = build();
    let loss1 =
        net1.forward(&x)
            .cross_entropy_loss::<Tensor>(&y, None, tch::Reduction::Mean, -100, 0.0);
    single.minimise(&loss1, StepAt::start_of(0));
    let mut max = 0f64;
    let (a, b) = (trained.vs.variables(), single.vs.variables());
    assert!(!a.is_empty());
    for (name, t) in &a {
        let u = &b[name];
        max = max.max((t - u).abs().max().double_value(&[]));
        max = max.max((t.grad() - u.grad()).abs().max().double_value(&[]));
    }
    std::fs::write(dir.join(format!("rank{r}")), format!("{max:e}")).unwrap();
}

/// Synchronised BatchNorm (`--sync-bn`): MFNet, whose BatchNorm layers are in training mode,
/// on 2 ranks each a half of the batch takes the step one process takes on the whole batch —
/// gradients, updated weights and BatchNorm running statistics (tolerance 1e-5). Without the
/// synchronisation the ranks normalise with their own halves' statistics and differ.
#[test]
fn synchronised_batch_norm_makes_two_ranks_step_like_one_process() {
    let test = "synchronised_batch_norm_makes_two_ranks_step_like_one_process";
    let Some((ddp, dir, _)) = rank() else {
        let dir = tempfile::tempdir().unwrap();
        if !launch(test, dir.path(), "") {
            return;
        }
        for r in 0..2 {
            let read = |name: &str| {
                let text = std::fs::read_to_string(dir.path().join(format!("{name}{r}")))
                    .expect("each rank reports");
                text.trim().parse::<f64>().unwrap()
            };
            let (synced, per_rank) = (read("synced"), read("per_rank"));
            eprintln!(
                "rank {r}: max |difference| to the single process: synchronised {synced:e}, \
                 per-rank statistics {per_rank:e}"
            );
            assert!(synced < 1e-5, "rank {r}: {synced}");
            assert!(
                per_rank > 1e-3,
                "rank {r}: per-rank BatchNorm should differ: {per_rank}"
            );
        }
        return;
    };
    let (r, world) = (ddp.rank() as i64, ddp.world_size() as i64);
    tch::manual_seed(3);
    let x = Tensor::randn([4, 4, 32, 48], (Kind::Float, Device::Cpu));
    let y = Tensor::randint(9, [4, 32, 48], (Kind::Int64, Device::Cpu));
    let schedule = OptimizerConfig::mfnet_paper();
    let model = rtf_models::ModelConfig::from_name("mfnet", 9).unwrap();
    // With `sync`, the network's BatchNorms sum their statistics over the ranks.
    let build = |sync: bool| {
        tch::manual_seed(11);
        let kernels = rtf_models::UnitKernels {
            sync: sync.then(|| ddp.clone() as std::sync::Arc<dyn rtf_models::StatsAllReduce>),
            ..Default::default()
        };
        let trained = Trained::new("student", Device::Cpu, &schedule).computing(kernels);
        let net =
            rtf_models::build_with(&trained.vs.root(), &model, &trained.build_options()).unwrap();
        (trained, net)
    };
    let ce = |logits: Tensor, y: &Tensor| {
        logits.cross_entropy_loss::<Tensor>(y, None, tch::Reduction::Mean, -100, 0.0)
    };
    // One process, the whole batch.
    let (mut single, net1) = build(false);
    single.minimise(&ce(net1.forward_t(&x, true), &y), StepAt::start_of(0));
    // Two ranks, each a half, with and without synchronised statistics.
    let share = 4 / world;
    let (xr, yr) = (x.narrow(0, r * share, share), y.narrow(0, r * share, share));
    let difference = |sync: bool| {
        let (mut trained, net) = build(sync);
        trained.ddp = Some(ddp.clone());
        trained.minimise(&ce(net.forward_t(&xr, true), &yr), StepAt::start_of(0));
        ddp.check().unwrap();
        let (a, b) = (trained.vs.variables(), single.vs.variables());
        let mut max = 0f64;
        for (name, t) in &a {
            let u = &b[name];
            max = max.max((t - u).abs().max().double_value(&[]));
            if t.requires_grad() {
                max = max.max((t.grad() - u.grad()).abs().max().double_value(&[]));
            }
        }
        max
    };
    let synced = difference(true);
    let per_rank = difference(false);
    std::fs::write(dir.join(format!("synced{r}")), format!("{synced:e}")).unwrap();
    std::fs::write(dir.join(format!("per_rank{r}")), format!("{per_rank:e}")).unwrap();
}

fn padding(p: i64) -> nn::ConvConfig {
    nn::ConvConfig {
        padding: p,
        ..Default::default()
    }
}

/// MFNet (train-mode BatchNorm, per rank) on the tiny dataset, 2 epochs.
fn mfnet(root: &Path) -> TrainConfig {
    let mut cfg = TrainConfig::mfnet_paper(root.to_path_buf());
    cfg.data.dataset = DatasetConfig::Mf {
        root: root.to_path_buf(),
        train_split: "train".into(),
        val_split: Some("val".into()),
    };
    cfg.schedule.epochs = 2;
    cfg.schedule.batch_size = 2;
    cfg.schedule.seed = 5;
    cfg.data.workers = 1;
    cfg
}

/// A 2-process MFNet run ends with identical weights on both ranks (checked bit for bit by the
/// trainer, and by their digests here); a Ctrl-C on rank 1 alone stops both ranks after the
/// same step with a checkpoint from rank 0; resumed on 2 processes, the run ends bit-identical
/// to the uninterrupted one. Only rank 0 writes the run folder, whose config.json records
/// `compute.world_size`; a resume on another number of processes is refused.
#[test]
fn two_rank_mfnet_run_is_identical_on_both_ranks_and_resumes_exactly() {
    let test = "two_rank_mfnet_run_is_identical_on_both_ranks_and_resumes_exactly";
    let Some((ddp, dir, phase)) = rank() else {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        common::write_split_dataset(&dir.join("data"), 10, 4242, 8);
        if !launch(test, dir, "straight") {
            return;
        }
        let read = |name: &str| std::fs::read_to_string(dir.join(name)).expect(name);
        assert_eq!(read("straight.rank0"), read("straight.rank1"));
        let run = rtf_train::TrainedRun::open(&dir.join("straight")).unwrap();
        assert_eq!(run.last_training().compute.world_size, Some(2));
        assert_eq!(read("straight/log.jsonl").lines().count(), 2);
        // Rank 1 is asked to stop before its first step: both ranks stop after it.
        launch(test, dir, "stop");
        assert_eq!(read("stop.rank0"), "stopped at batch 1");
        assert_eq!(read("stop.rank1"), "stopped at batch 1");
        assert!(dir.join("stopped/checkpoint.safetensors").exists());
        assert!(!dir.join("stopped/final.safetensors").exists());
        // One process cannot continue a 2-process run exactly: refused.
        let RunConfig::Single(cfg) = rtf_train::trainer::read_config(&dir.join("stopped")).unwrap()
        else {
            panic!("a single run")
        };
        let err = rtf_train::trainer::train_until(
            &cfg,
            &dir.join("stopped"),
            true,
            &mut |_| {},
            &AtomicBool::new(false),
        )
        .expect_err("refused");
        assert!(err.to_string().contains("trained by 2 process"), "{err}");
        launch(test, dir, "resume");
        assert_eq!(read("resume.rank0"), read("resume.rank1"));
        assert_eq!(read("resume.rank0"), read("straight.rank0"));
        assert!(
            common::weights(&dir.join("straight/final.safetensors"))
                == common::weights(&dir.join("stopped/final.safetensors")),
            "stopped and resumed on 2 ranks = uninterrupted"
        );
        return;
    };
    let r = ddp.rank();
    let cfg = mfnet(&dir.join("data"));
    let write = |name: String, text: String| std::fs::write(dir.join(name), text).unwrap();
    match phase.as_str() {
        "straight" => {
            let out = rtf_train::trainer::train_distributed(
                &cfg,
                &dir.join("straight"),
                false,
                &mut |_| {},
                &AtomicBool::new(false),
                Some(ddp),
            )
            .unwrap();
            assert!(out.final_weights.is_some());
            write(
                format!("straight.rank{r}"),
                format!("{:?}", out.weights_digest),
            );
        }
        "stop" => {
            let out = rtf_train::trainer::train_distributed(
                &cfg,
                &dir.join("stopped"),
                false,
                &mut |_| {},
                &AtomicBool::new(r == 1),
                Some(ddp),
            )
            .unwrap();
            assert!(out.final_weights.is_none());
            let batches = out.state.partial.as_ref().map_or(0, |p| p.batches);
            write(
                format!("stop.rank{r}"),
                format!("stopped at batch {batches}"),
            );
        }
        "resume" => {
            let run = dir.join("stopped");
            let RunConfig::Single(cfg) = rtf_train::trainer::read_config(&run).unwrap() else {
                panic!("a single run")
            };
            let out = rtf_train::trainer::train_distributed(
                &cfg,
                &run,
                true,
                &mut |_| {},
                &AtomicBool::new(false),
                Some(ddp),
            )
            .unwrap();
            write(
                format!("resume.rank{r}"),
                format!("{:?}", out.weights_digest),
            );
        }
        other => panic!("unknown phase {other:?}"),
    }
}

/// A multi-stage run (a teacher stage, then a student learning from it) on 2 ranks: every
/// stage is data-parallel, rank 0 alone writes the run folder and the other rank reads the
/// teacher's weights from it; a stop in the second stage stops both ranks, a 1-process resume is
/// refused (the stage's config.json records 2 processes), and the 2-process resume skips the
/// finished stage and ends bit-identical to the uninterrupted run.
#[test]
fn two_rank_pipeline_trains_every_stage_data_parallel_and_resumes_exactly() {
    let test = "two_rank_pipeline_trains_every_stage_data_parallel_and_resumes_exactly";
    let Some((ddp, dir, phase)) = rank() else {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        common::write_split_dataset(&dir.join("data"), 10, 4242, 8);
        if !launch(test, dir, "straight") {
            return;
        }
        let read = |name: &str| std::fs::read_to_string(dir.join(name)).expect(name);
        assert_eq!(read("straight.rank0"), "trained [\"teacher\", \"student\"]");
        assert_eq!(read("straight.rank1"), read("straight.rank0"));
        for stage in ["teacher", "student"] {
            let run = rtf_train::TrainedRun::open(&dir.join("straight").join(stage)).unwrap();
            assert_eq!(run.last_training().compute.world_size, Some(2), "{stage}");
        }
        assert!(dir.join("straight/final.safetensors").is_file());
        launch(test, dir, "stop");
        // The student's epoch is one step per rank here: the stop lands on the end of epoch 1.
        assert_eq!(read("stop.rank0"), "stopped in student at epoch 2 batch 0");
        assert_eq!(read("stop.rank1"), read("stop.rank0"));
        assert!(dir.join("stopped/teacher/final.safetensors").is_file());
        assert!(dir.join("stopped/student/checkpoint.safetensors").is_file());
        assert!(!dir.join("stopped/final.safetensors").exists());
        let err = rtf_train::pipeline::run_pipeline(
            &pipeline(&dir.join("data")),
            &dir.join("stopped"),
            true,
            &mut |_, _| {},
            &AtomicBool::new(false),
        )
        .expect_err("refused");
        assert!(err.to_string().contains("trained by 2 process"), "{err}");
        launch(test, dir, "resume");
        assert_eq!(read("resume.rank0"), "trained [\"student\"]");
        assert_eq!(read("resume.rank1"), read("resume.rank0"));
        assert!(
            common::weights(&dir.join("straight/final.safetensors"))
                == common::weights(&dir.join("stopped/final.safetensors")),
            "stopped and resumed on 2 ranks = uninterrupted"
        );
        return;
    };
    let r = ddp.rank();
    let stop = AtomicBool::new(false);
    let (out, resume) = match phase.as_str() {
        "straight" => ("straight", false),
        "stop" => ("stopped", false),
        "resume" => ("stopped", true),
        other => panic!("unknown phase {other:?}"),
    };
    let outcome = rtf_train::pipeline::run_pipeline_distributed(
        &pipeline(&dir.join("data")),
        &dir.join(out),
        resume,
        // Only rank 0 sees the epochs; its stop flag stops both ranks at the same step.
        &mut |stage, _| {
            if phase == "stop" && stage == "teacher" {
                stop.store(true, std::sync::atomic::Ordering::SeqCst)
            }
        },
        &stop,
        Some(ddp),
    )
    .unwrap();
    let report = match &outcome.interrupted {
        Some((stage, o)) => format!(
            "stopped in {stage} at epoch {} batch {}",
            o.state.epochs_done + 1,
            o.state.partial.as_ref().map_or(0, |p| p.batches)
        ),
        None => format!("trained {:?}", outcome.trained),
    };
    std::fs::write(dir.join(format!("{phase}.rank{r}")), report).unwrap();
}

/// MFNet teacher (RGB only, 1 epoch), then an MFNet student labelled by it (2 epochs).
fn pipeline(data: &Path) -> rtf_train::PipelineConfig {
    use rtf_train::config::{StageConfig, TeacherRef};
    let teacher = mfnet(data).with(|c| {
        c.schedule.epochs = 1;
        c.network.inputs = rtf_train::Modality::Rgb;
    });
    let student = mfnet(data).with(|c| {
        c.learning.procedure = rtf_train::Procedure::TeacherStudent {
            day_teacher: TeacherRef::Stage("teacher".into()),
            night_teacher: None,
            targets: Default::default(),
        };
    });
    rtf_train::PipelineConfig {
        recipe: None,
        stages: vec![
            StageConfig {
                name: "teacher".into(),
                config: teacher,
            },
            StageConfig {
                name: "student".into(),
                config: student,
            },
        ],
    }
}

/// HeatNet's adversarial procedure on 2 ranks (teacher labels cached, so rank 1 labels into a
/// scratch folder of its own): both the segmentation network's and the critic's gradients are
/// averaged, so both networks end identical on both ranks (the trainer compares every trained
/// network bit for bit and fails the run otherwise; the ranks see different frames).
#[test]
fn two_rank_adversarial_run_keeps_both_networks_identical() {
    let test = "two_rank_adversarial_run_keeps_both_networks_identical";
    let Some((ddp, dir, _)) = rank() else {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let names = common::write_frames(&dir.join("data"), 10, 99, false);
        std::fs::write(dir.join("data/train.txt"), names[..8].join("\n")).unwrap();
        std::fs::write(dir.join("data/val.txt"), names[8..].join("\n")).unwrap();
        tch::manual_seed(21);
        let vs = nn::VarStore::new(Device::Cpu);
        let model = rtf_models::ModelConfig::from_name("mfnet", 9).unwrap();
        rtf_models::build(&vs.root(), &model).unwrap();
        rtf_models::io::weights::save_safetensors(
            &vs,
            &model,
            rtf_train::Modality::Rgb,
            &dir.join("teacher.safetensors"),
        )
        .unwrap();
        if !launch(test, dir, "") {
            return;
        }
        let read = |name: &str| std::fs::read_to_string(dir.join(name)).expect(name);
        assert_eq!(read("adv.rank0"), read("adv.rank1"));
        let log = read("run/log.jsonl");
        assert_eq!(log.lines().count(), 2);
        assert!(log.contains("critic_acc"), "the critic trained: {log}");
        assert!(dir.join("run/labels").exists(), "rank 0 cached the labels");
        return;
    };
    let mut cfg = mfnet(&dir.join("data"));
    cfg.learning.procedure = rtf_train::Procedure::Adversarial {
        day_teacher: rtf_train::config::TeacherRef::Weights {
            path: dir.join("teacher.safetensors"),
            model: rtf_models::ModelConfig::from_name("mfnet", 9).unwrap(),
            inputs: rtf_train::Modality::Rgb,
        },
        night_teacher: None,
        targets: rtf_train::config::TargetOptions {
            cache: true,
            ..Default::default()
        },
        critic: Default::default(),
    };
    let r = ddp.rank();
    let out = rtf_train::trainer::train_distributed(
        &cfg,
        &dir.join("run"),
        false,
        &mut |_| {},
        &AtomicBool::new(false),
        Some(ddp),
    )
    .unwrap();
    std::fs::write(
        dir.join(format!("adv.rank{r}")),
        format!("{:?}", out.weights_digest.expect("a data-parallel run")),
    )
    .unwrap();
}
