//! Mixed-precision training (`precision: bf16`) on the CPU: every procedure trains in bf16
//! autocast, the choice is recorded in config.json, a run stopped after an epoch or inside one
//! resumes bit-identically, bf16 really changes the arithmetic (weights differ from fp32's), and
//! fp16 on a CPU is refused before anything is written.

mod common;

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::sync::Mutex;

use rtf_train::config::{CriticOptions, Precision, TargetOptions};
use rtf_train::{DatasetConfig, Modality, OptimizerConfig, Procedure, TrainConfig};

/// libtorch's random generator is process-global: tests that compare runs must not interleave.
static TORCH_RNG: Mutex<()> = Mutex::new(());

fn config(root: &Path, epochs: usize, precision: Precision) -> TrainConfig {
    let mut cfg = TrainConfig::mfnet_paper(root.to_path_buf());
    cfg.data.dataset = DatasetConfig::Mf {
        root: root.to_path_buf(),
        train_split: "train".into(),
        val_split: Some("val".into()),
    };
    cfg.schedule.epochs = epochs;
    cfg.schedule.batch_size = 2;
    cfg.schedule.seed = 11;
    cfg.data.workers = 1;
    cfg.schedule.max_steps_per_epoch = Some(2);
    cfg.learning.precision = precision;
    // The choice this process is asked for (xtask's passes), as `rtf train` records it.
    if precision == Precision::Bf16 {
        cfg.compute.bf16_convolutions = Some(common::bf16_convolutions());
    }
    cfg
}

/// `cfg` without its validation pass (the procedure tests check training, not scores).
fn no_validation(mut cfg: TrainConfig) -> TrainConfig {
    if let DatasetConfig::Mf { val_split, .. } = &mut cfg.data.dataset {
        *val_split = None;
    }
    cfg
}

fn tensors(path: &Path) -> Vec<(String, safetensors::Dtype, Vec<u8>)> {
    let bytes = std::fs::read(path).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut named: Vec<_> = st
        .tensors()
        .into_iter()
        .map(|(n, v)| (n, v.dtype(), v.data().to_vec()))
        .collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    named
}

/// Trains `cfg` straight, then stopped after its first epoch and resumed, then stopped after
/// its first step and resumed; both continuations must end with the straight run's checkpoint
/// (every network's weights and optimiser state) and losses.
fn assert_resumes_exactly(cfg: &TrainConfig, dir: &Path) -> rtf_train::TrainOutcome {
    let straight = dir.join("straight");
    let expected = rtf_train::train(cfg, &straight, false, &mut |_| {}).unwrap();
    assert!(expected.records.iter().all(|r| r.train_loss.is_finite()));
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(straight.join("config.json")).unwrap())
            .unwrap();
    assert_eq!(
        written["learning"]["precision"],
        cfg.learning.precision.name(),
        "recorded in config.json"
    );
    if cfg.learning.precision == Precision::Bf16 {
        let asked = common::bf16_convolutions();
        eprintln!("bf16 convolutions: {}", asked.name());
        assert_eq!(
            written["compute"]["bf16_convolutions"],
            asked.name(),
            "the choice asked for is the run's, recorded"
        );
    }

    let split = dir.join("split");
    let first = cfg.clone().with(|c| {
        c.schedule.epochs = 1;
    });
    rtf_train::train(&first, &split, false, &mut |_| {}).unwrap();
    let resumed_cfg = rtf_train::trainer::read_config(&split).unwrap();
    let resumed_cfg = match resumed_cfg {
        rtf_train::RunConfig::Single(c) => (*c).with(|c| {
            c.schedule.epochs = cfg.schedule.epochs;
        }),
        other => panic!("a single run was written, got {other:?}"),
    };
    assert_eq!(
        resumed_cfg.learning.precision, cfg.learning.precision,
        "read back from config.json"
    );
    rtf_train::train(&resumed_cfg, &split, true, &mut |_| {}).unwrap();

    let inside = dir.join("inside");
    let stop = AtomicBool::new(true);
    let stopped = rtf_train::trainer::train_until(cfg, &inside, false, &mut |_| {}, &stop).unwrap();
    assert_eq!(stopped.state.partial.as_ref().map(|p| p.batches), Some(1));
    let resumed = rtf_train::train(cfg, &inside, true, &mut |_| {}).unwrap();
    assert_eq!(resumed.records[0].losses, expected.records[0].losses);

    let checkpoint = tensors(&straight.join("checkpoint.safetensors"));
    for run in [&split, &inside] {
        assert!(
            tensors(&run.join("checkpoint.safetensors")) == checkpoint,
            "{}: weights and optimiser state equal the uninterrupted run",
            run.display()
        );
    }
    expected
}

#[test]
fn bf16_supervised_run_resumes_exactly_and_keeps_fp32_master_weights() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 10, 4242, 8);
    let bf16 = config(&data, 2, Precision::Bf16);
    let outcome = assert_resumes_exactly(&bf16, &tmp.path().join("bf16"));
    assert!(outcome.records.iter().all(|r| r.val_miou.is_some()));

    // Same seeds in fp32: the same schedule, other arithmetic, so other weights (not far off).
    let fp32_run = tmp.path().join("fp32");
    rtf_train::train(
        &config(&data, 2, Precision::Fp32),
        &fp32_run,
        false,
        &mut |_| {},
    )
    .unwrap();
    let a = tensors(&tmp.path().join("bf16/straight/final.safetensors"));
    let b = tensors(&fp32_run.join("final.safetensors"));
    assert_eq!(a.len(), b.len());
    let mut differing = 0;
    for ((na, ta, da), (nb, tb, db)) in a.iter().zip(&b) {
        assert_eq!(na, nb);
        // Master weights and BatchNorm statistics stay fp32.
        assert_eq!(
            (*ta, *tb),
            (safetensors::Dtype::F32, safetensors::Dtype::F32),
            "{na}"
        );
        differing += usize::from(da != db);
    }
    assert!(differing > 0, "bf16 training must not be fp32 training");
}

#[test]
fn bf16_teacher_student_and_adversarial_runs_resume_exactly() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 10, 4242, 8);
    let optimizer = OptimizerConfig {
        lr: 1e-3,
        momentum: 0.5,
        ..OptimizerConfig::heatnet_paper()
    };
    let distillation = no_validation(config(&data, 2, Precision::Bf16)).with(|c| {
        c.learning.procedure = Procedure::TeacherStudent {
            day_teacher: common::teacher(tmp.path(), 1),
            night_teacher: Some(common::teacher(tmp.path(), 2)),
            targets: TargetOptions {
                threshold: Some(0.05),
                soft: true,
                cache: false,
            },
        };
        c.network.inputs = Modality::Rgb;
        c.learning.optimizer = optimizer.clone();
    });
    let run = assert_resumes_exactly(&distillation, &tmp.path().join("ts"));
    assert!(run.records[0].losses["ce_night"].is_finite());

    let adversarial = no_validation(config(&data, 2, Precision::Bf16)).with(|c| {
        c.learning.procedure = Procedure::Adversarial {
            day_teacher: common::teacher(tmp.path(), 1),
            night_teacher: None,
            targets: TargetOptions::default(),
            critic: CriticOptions {
                optimizer: optimizer.clone(),
                ..CriticOptions::default()
            },
        };
        c.learning.optimizer = optimizer;
    });
    let run = assert_resumes_exactly(&adversarial, &tmp.path().join("adv"));
    for term in ["ce_day", "adv", "critic"] {
        assert!(run.records[1].losses[term].is_finite(), "{term}");
    }
}

#[test]
fn fp16_on_a_cpu_is_refused_before_anything_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 10, 4242, 8);
    let run = tmp.path().join("run");
    let err = rtf_train::train(&config(&data, 1, Precision::Fp16), &run, false, &mut |_| {})
        .unwrap_err()
        .to_string();
    assert!(err.contains("precision") && err.contains("CUDA"), "{err}");
    assert!(!run.exists());
}
