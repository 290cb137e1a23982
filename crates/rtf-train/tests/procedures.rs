//! HeatNet's procedures on the training core: each runs end to end, resumes bit-identically
//! (both networks and both optimisers of the adversarial procedure; a two-stage run stopped in
//! stage 2), each step updates only its own network, label-free procedures never open a night
//! label, and bad teachers or configs are refused before anything is written.

mod common;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

use rtf_models::ModelConfig;
use rtf_train::config::{
    CriticOptions, PipelineConfig, StageConfig, StepAt, TargetOptions, TeacherRef, WeightsRef,
};
use rtf_train::{DatasetConfig, Modality, OptimizerConfig, Procedure, RunConfig, TrainConfig};

/// libtorch's random generator is process-global: tests that compare runs must not interleave.
static TORCH_RNG: Mutex<()> = Mutex::new(());

/// A tiny MF-layout dataset, 32×32, day and night frames ("hot pixel = person"); night label
/// files are garbage, so any attempt to decode one fails the run.
fn write_dataset(root: &Path) {
    let names = common::write_frames(root, 10, 777, true);
    std::fs::write(root.join("train.txt"), names[..8].join("\n")).unwrap();
    // Validation keeps real labels for both day and night.
    std::fs::write(root.join("val.txt"), "00008D").unwrap();
}

fn base(root: &Path, epochs: usize) -> TrainConfig {
    let mut cfg = TrainConfig::mfnet_paper(root.to_path_buf());
    cfg.data.dataset = DatasetConfig::Mf {
        root: root.to_path_buf(),
        train_split: "train".into(),
        val_split: Some("val".into()),
    };
    cfg.schedule.epochs = epochs;
    cfg.schedule.batch_size = 2;
    cfg.schedule.seed = 3;
    cfg.data.workers = 1;
    cfg.learning.optimizer = OptimizerConfig {
        lr: 1e-3,
        momentum: 0.5,
        ..OptimizerConfig::heatnet_paper()
    };
    cfg
}

fn adversarial(root: &Path, epochs: usize, day: TeacherRef) -> TrainConfig {
    base(root, epochs).with(|c| {
        c.learning.procedure = Procedure::Adversarial {
            day_teacher: day,
            night_teacher: None,
            targets: TargetOptions::default(),
            critic: CriticOptions {
                optimizer: OptimizerConfig {
                    lr: 1e-3,
                    momentum: 0.5,
                    ..OptimizerConfig::heatnet_paper()
                },
                ..CriticOptions::default()
            },
        };
    })
}

/// Every tensor of a safetensors file, sorted by name.
fn tensors(path: &Path) -> Vec<(String, Vec<u8>)> {
    let bytes = std::fs::read(path).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut named: Vec<_> = st
        .tensors()
        .into_iter()
        .map(|(n, v)| (n, v.data().to_vec()))
        .collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    named
}

fn setup() -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    write_dataset(&data);
    (tmp, data)
}

#[test]
fn adversarial_runs_and_resumes_exactly_after_an_epoch_and_inside_one() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, data) = setup();
    let cfg = adversarial(&data, 2, common::teacher(tmp.path(), 1));
    let straight = tmp.path().join("straight");
    let expected = rtf_train::train(&cfg, &straight, false, &mut |_| {}).unwrap();
    let record = &expected.records[1];
    for term in ["ce_day", "adv", "critic"] {
        assert!(
            record.losses[term].is_finite(),
            "{term} in {:?}",
            record.losses
        );
    }
    for metric in ["critic_acc_day", "critic_acc_night"] {
        assert!((0.0..=1.0).contains(&record.metrics[metric]), "{metric}");
    }
    assert_eq!(record.lrs.keys().collect::<Vec<_>>(), ["critic", "student"]);
    let checkpoint = tensors(&straight.join("checkpoint.safetensors"));
    for prefix in ["student/w/", "student/opt/", "critic/w/", "critic/opt/"] {
        assert!(
            checkpoint.iter().any(|(n, _)| n.starts_with(prefix)),
            "{prefix}"
        );
    }

    // Stopped after epoch 1, then resumed.
    let split = tmp.path().join("split");
    rtf_train::train(
        &cfg.clone().with(|c| {
            c.schedule.epochs = 1;
        }),
        &split,
        false,
        &mut |_| {},
    )
    .unwrap();
    rtf_train::train(&cfg, &split, true, &mut |_| {}).unwrap();
    // Stopped after the first step (inside epoch 1), then resumed.
    let inside = tmp.path().join("inside");
    let stop = AtomicBool::new(true);
    let stopped =
        rtf_train::trainer::train_until(&cfg, &inside, false, &mut |_| {}, &stop).unwrap();
    assert_eq!(stopped.state.partial.as_ref().map(|p| p.batches), Some(1));
    let resumed = rtf_train::train(&cfg, &inside, true, &mut |_| {}).unwrap();
    assert_eq!(resumed.records[0].losses, expected.records[0].losses);
    for run in [&split, &inside] {
        assert_eq!(
            tensors(&run.join("checkpoint.safetensors")),
            checkpoint,
            "{}: both networks and both optimisers equal the uninterrupted run",
            run.display()
        );
        let log = std::fs::read_to_string(run.join("log.jsonl")).unwrap();
        assert_eq!(log.lines().count(), 2);
    }
}

/// The published code's procedure (`--critic-code`): critic and segmentation steps alternate,
/// critic first, each on its own batches; a run stopped after its first (critic) step resumes
/// with a segmentation step and ends bit-identical to the uninterrupted run. The critic starts
/// from `critic.init`.
#[test]
fn the_codes_alternation_resumes_exactly_and_the_critic_starts_from_its_init() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, data) = setup();
    let mut cfg = adversarial(&data, 2, common::teacher(tmp.path(), 1));
    // A critic file: the critic a build makes, halved (not what a fresh build gives).
    let fresh = rtf_train::procedure::build_adversarial(&cfg, None, tch::Device::Cpu).unwrap();
    let halved: Vec<(String, tch::Tensor)> = rtf_models::io::weights::state_dict(&fresh.critic.vs)
        .into_iter()
        .map(|(n, t)| (n, t * 0.5))
        .collect();
    let critic_file = tmp.path().join("critic.safetensors");
    rtf_models::io::weights::save_named(&halved, &critic_file).unwrap();
    let Procedure::Adversarial { critic, .. } = &mut cfg.learning.procedure else {
        unreachable!()
    };
    critic.init = Some(critic_file);
    (critic.flip_targets, critic.day_term, critic.alternate) = (true, true, true);
    critic.input = rtf_train::config::CriticInput::Logits;
    let started = rtf_train::procedure::build_adversarial(&cfg, None, tch::Device::Cpu).unwrap();
    let vars = started.critic.vs.variables();
    assert!(halved.iter().all(|(n, t)| t.equal(&vars[n])));

    let straight = tmp.path().join("straight");
    let expected = rtf_train::train(&cfg, &straight, false, &mut |_| {}).unwrap();
    let steps = rtf_train::step_log::read(&straight).unwrap();
    assert_eq!(steps.len(), 2 * 2, "2 day batches per epoch");
    for (i, step) in steps.iter().enumerate() {
        let critic_step = i % 2 == 0;
        let term = |name: &str| step.terms.get(name).copied();
        assert_eq!(term("ce_day").is_none(), critic_step, "step {i}: {step:?}");
        assert!(
            term("critic").is_none() != critic_step,
            "step {i}: {step:?}"
        );
        assert!(
            critic_step || term("adv_day").unwrap() > 0.0,
            "the day term"
        );
    }
    let inside = tmp.path().join("inside");
    let stop = AtomicBool::new(true);
    rtf_train::trainer::train_until(&cfg, &inside, false, &mut |_| {}, &stop).unwrap();
    let resumed = rtf_train::train(&cfg, &inside, true, &mut |_| {}).unwrap();
    // The epoch's term sums come back through the checkpoint's JSON, whose parser (serde_json
    // without `float_roundtrip`) may round the last bit.
    let (a, b) = (&resumed.records[0].losses, &expected.records[0].losses);
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    assert!(
        a.iter()
            .all(|(k, v)| (v - b[k]).abs() <= 1e-12 * b[k].abs()),
        "{a:?} vs {b:?}"
    );
    assert_eq!(
        tensors(&inside.join("checkpoint.safetensors")),
        tensors(&straight.join("checkpoint.safetensors")),
        "both networks and both optimisers equal the uninterrupted run"
    );
}

#[test]
fn each_adversarial_step_updates_only_its_own_network() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, data) = setup();
    let cfg = adversarial(&data, 1, common::teacher(tmp.path(), 1));
    let mut procedure = rtf_train::procedure::build(&cfg, None, tch::Device::Cpu).unwrap();
    let student_of = |p: &dyn rtf_train::procedure::Procedure, i: usize| {
        p.trained()[i]
            .vs
            .variables()
            .into_iter()
            .map(|(n, t)| (n, t.copy()))
            .collect::<std::collections::BTreeMap<_, _>>()
    };
    let batch = |daytime: char| {
        let input = tch::Tensor::rand([2, 4, 32, 32], (tch::Kind::Float, tch::Device::Cpu));
        rtf_data::Batch {
            input,
            target: tch::Tensor::zeros([2, 32, 32], (tch::Kind::Int64, tch::Device::Cpu)),
            names: vec![format!("a{daytime}"), format!("b{daytime}")],
            daytimes: vec![None, None],
            wait: std::time::Duration::ZERO,
        }
    };
    let batches = rtf_train::procedure::StepBatches {
        main: batch('D'),
        night: Some(batch('N')),
    };
    // Reach into the adversarial step halves through the concrete type.
    let adv = rtf_train::procedure::build(&cfg, None, tch::Device::Cpu).unwrap();
    drop(adv);
    let before_student = student_of(procedure.as_ref(), 0);
    let before_critic = student_of(procedure.as_ref(), 1);
    procedure.step(&batches, StepAt::start_of(0)).unwrap();
    let after_student = student_of(procedure.as_ref(), 0);
    let after_critic = student_of(procedure.as_ref(), 1);
    assert!(
        before_student
            .iter()
            .any(|(n, t)| !t.equal(&after_student[n])),
        "the student learnt"
    );
    assert!(
        before_critic
            .iter()
            .any(|(n, t)| !t.equal(&after_critic[n])),
        "the critic learnt"
    );

    // The halves alone: the segmentation step leaves the critic untouched, the critic step the
    // student.
    let mut halves = rtf_train::procedure::build_adversarial(&cfg, None, tch::Device::Cpu).unwrap();
    let critic0 = halves
        .critic
        .vs
        .variables()
        .into_iter()
        .map(|(n, t)| (n, t.copy()))
        .collect::<Vec<_>>();
    let student0 = halves
        .student
        .trained
        .vs
        .variables()
        .into_iter()
        .map(|(n, t)| (n, t.copy()))
        .collect::<Vec<_>>();
    let (_, _, night_logits, day_logits) = halves
        .segmentation_step(&batches, StepAt::start_of(0))
        .unwrap();
    let critic1 = halves.critic.vs.variables();
    assert!(
        critic0.iter().all(|(n, t)| t.equal(&critic1[n])),
        "segmentation step froze the critic"
    );
    let student1 = halves
        .student
        .trained
        .vs
        .variables()
        .into_iter()
        .map(|(n, t)| (n, t.copy()))
        .collect::<Vec<_>>();
    assert!(student0
        .iter()
        .any(|(n, t)| !t.equal(&student1.iter().find(|(m, _)| m == n).unwrap().1)));
    halves.critic_step(&day_logits, &night_logits, StepAt::start_of(0));
    let student2 = halves.student.trained.vs.variables();
    assert!(
        student1.iter().all(|(n, t)| t.equal(&student2[n])),
        "critic step froze the student"
    );
    let critic2 = halves.critic.vs.variables();
    assert!(
        critic0.iter().any(|(n, t)| !t.equal(&critic2[n])),
        "the critic learnt"
    );
}

#[test]
fn two_stage_run_stopped_in_stage_two_resumes_exactly() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, data) = setup();
    let day = common::teacher(tmp.path(), 1);
    let night = common::teacher(tmp.path(), 2);
    let stage1 = base(&data, 1).with(|c| {
        c.learning.procedure = Procedure::TeacherStudent {
            day_teacher: day.clone(),
            night_teacher: Some(night),
            targets: TargetOptions::default(),
        };
    });
    let stage2 = adversarial(&data, 2, day).with(|c| {
        c.network.init_from = Some(WeightsRef::Stage("stage1".into()));
    });
    let pipeline = PipelineConfig {
        recipe: None,
        stages: vec![
            StageConfig {
                name: "stage1".into(),
                config: stage1,
            },
            StageConfig {
                name: "stage2".into(),
                config: stage2,
            },
        ],
    };
    let straight = tmp.path().join("straight");
    let never = AtomicBool::new(false);
    let done =
        rtf_train::pipeline::run_pipeline(&pipeline, &straight, false, &mut |_, _| {}, &never)
            .unwrap();
    assert_eq!(done.trained, ["stage1", "stage2"]);
    assert!(straight.join("final.safetensors").is_file());
    // The stage config on disk names the stage-1 weights it started from.
    let s2 = rtf_train::trainer::read_config(&straight.join("stage2")).unwrap();
    let RunConfig::Single(s2) = s2 else {
        panic!("a stage is a single run")
    };
    assert_eq!(
        s2.network.init_from,
        Some(WeightsRef::File(straight.join("stage1/final.safetensors")))
    );

    // Stop once stage 1 has finished: stage 2 stops after its first step.
    let stopped = tmp.path().join("stopped");
    let stop = AtomicBool::new(false);
    let outcome = rtf_train::pipeline::run_pipeline(
        &pipeline,
        &stopped,
        false,
        &mut |stage, _| {
            if stage == "stage1" {
                stop.store(true, Ordering::SeqCst)
            }
        },
        &stop,
    )
    .unwrap();
    let (stage, inner) = outcome.interrupted.expect("stopped in stage 2");
    assert_eq!(stage, "stage2");
    assert_eq!(inner.state.partial.as_ref().map(|p| p.batches), Some(1));
    // A fresh start on that folder is refused; --resume skips stage 1 and finishes stage 2.
    let err = rtf_train::pipeline::run_pipeline(&pipeline, &stopped, false, &mut |_, _| {}, &never)
        .unwrap_err();
    assert!(err.to_string().contains("--resume"), "{err}");
    let resumed =
        rtf_train::pipeline::run_pipeline(&pipeline, &stopped, true, &mut |_, _| {}, &never)
            .unwrap();
    assert_eq!(resumed.trained, ["stage2"]);
    assert_eq!(
        tensors(&stopped.join("stage2/checkpoint.safetensors")),
        tensors(&straight.join("stage2/checkpoint.safetensors"))
    );
    assert_eq!(
        tensors(&stopped.join("final.safetensors")),
        tensors(&straight.join("final.safetensors"))
    );
}

#[test]
fn label_free_procedures_train_without_night_labels_and_supervised_needs_them() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, data) = setup();
    let cfg = base(&data, 1).with(|c| {
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
    });
    let run = rtf_train::train(&cfg, &tmp.path().join("ts"), false, &mut |_| {}).unwrap();
    assert!(run.records[0].losses.contains_key("ce_night"));
    // Supervised training reads every label of the split: the garbage night labels fail it,
    // which is what makes the run above a proof.
    let err = rtf_train::train(&base(&data, 1), &tmp.path().join("sup"), false, &mut |_| {})
        .unwrap_err()
        .to_string();
    assert!(err.contains("labels") && err.contains("N.png"), "{err}");
}

#[test]
fn bad_teachers_and_configs_are_refused_before_anything_is_written() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, data) = setup();
    let good = common::teacher(tmp.path(), 1);
    let TeacherRef::Weights { path, .. } = &good else {
        unreachable!()
    };
    let cases: Vec<(TeacherRef, &str)> = vec![
        (
            TeacherRef::Weights {
                path: tmp.path().join("missing.safetensors"),
                model: ModelConfig::from_name("mfnet", 9).unwrap(),
                inputs: Modality::RgbT,
            },
            "missing.safetensors",
        ),
        (
            TeacherRef::Weights {
                path: path.clone(),
                model: ModelConfig::from_name("mfnet", 13).unwrap(),
                inputs: Modality::RgbT,
            },
            "13 classes",
        ),
        (
            TeacherRef::Weights {
                path: path.clone(),
                model: ModelConfig::from_name("heatnet-rgb", 9).unwrap(),
                inputs: Modality::RgbT,
            },
            "input",
        ),
        // The file says its network saw RGB only; labelling with all four channels would be
        // silently wrong.
        (
            TeacherRef::Weights {
                path: path.clone(),
                model: ModelConfig::from_name("mfnet", 9).unwrap(),
                inputs: Modality::RgbT,
            },
            "trained on `rgb` inputs",
        ),
        (
            TeacherRef::Weights {
                path: path.clone(),
                model: ModelConfig::from_name("mfnet-f", 9).unwrap(),
                inputs: Modality::Rgb,
            },
            "holds a mfnet network",
        ),
    ];
    for (i, (bad, expected)) in cases.into_iter().enumerate() {
        let cfg = adversarial(&data, 1, bad);
        let run = tmp.path().join(format!("bad{i}"));
        let err = rtf_train::train(&cfg, &run, false, &mut |_| {})
            .unwrap_err()
            .to_string();
        assert!(err.contains(expected), "case {i}: {err}");
        assert!(!run.exists(), "case {i}: nothing written");
    }
    let unknown = r#"{"stages": [{"name": "a", "config": {"epochz": 3}}]}"#;
    let err = RunConfig::parse(unknown, false).unwrap_err();
    assert!(err.contains("epochz"), "{err}");
    let mut edited = serde_json::to_value(base(&data, 1)).unwrap();
    edited["learning"]["optimizer"]["lr"] = serde_json::json!(-1.0);
    let parsed = RunConfig::parse(&edited.to_string(), false).unwrap();
    let err = parsed.validate().unwrap_err().to_string();
    assert!(err.contains("optimizer.lr"), "{err}");
    // A stage may only name earlier stages.
    let forward = PipelineConfig {
        recipe: None,
        stages: vec![StageConfig {
            name: "only".into(),
            config: adversarial(&data, 1, TeacherRef::Stage("later".into())),
        }],
    };
    let err = RunConfig::Pipeline(forward)
        .validate()
        .unwrap_err()
        .to_string();
    assert!(err.contains("later"), "{err}");
}

#[test]
fn a_label_cache_trains_like_the_teacher_run_every_step() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, data) = setup();
    let day = common::teacher(tmp.path(), 1);
    let config = |cache: bool| {
        base(&data, 2).with(|c| {
            c.learning.procedure = Procedure::TeacherStudent {
                day_teacher: day.clone(),
                night_teacher: None,
                targets: TargetOptions {
                    cache,
                    ..TargetOptions::default()
                },
            }; // No augmentation: the teacher then sees the same frames either way.
            c.data.augment = Default::default();
        })
    };
    let live =
        rtf_train::train(&config(false), &tmp.path().join("live"), false, &mut |_| {}).unwrap();
    let cached_run = tmp.path().join("cached");
    let cached = rtf_train::train(&config(true), &cached_run, false, &mut |_| {}).unwrap();
    let labels = std::fs::read_dir(cached_run.join("labels/day"))
        .unwrap()
        .count();
    assert_eq!(labels, 4, "one label per day frame of the training split");
    for (a, b) in live.records.iter().zip(&cached.records) {
        let (a, b) = (a.losses["ce_day"], b.losses["ce_day"]);
        assert!(
            (a - b).abs() <= 1e-3 * a.abs().max(1e-6),
            "epoch loss {a} vs {b}"
        );
    }
    let soft_cache = base(&data, 1).with(|c| {
        c.learning.procedure = Procedure::TeacherStudent {
            day_teacher: day.clone(),
            night_teacher: None,
            targets: TargetOptions {
                cache: true,
                soft: true,
                threshold: None,
            },
        };
    });
    let err = soft_cache.validate().unwrap_err().to_string();
    assert!(err.contains("procedure.targets.cache"), "{err}");
}

/// CMX (issue 39): a cmx-mit-b0 student trains by every procedure — supervised on labelled
/// days, teacher–student, adversarial (the critic on its outputs) and RGB-T → RGB distillation
/// (an RGB-T teacher, an RGB-only student) — and every run's loss is finite.
#[test]
fn a_cmx_student_trains_by_every_procedure() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, data) = setup();
    let days: Vec<String> = std::fs::read_to_string(data.join("train.txt"))
        .unwrap()
        .lines()
        .filter(|n| n.ends_with('D'))
        .map(str::to_string)
        .collect();
    std::fs::write(data.join("days.txt"), days.join("\n")).unwrap();
    let cmx = |procedure: Procedure, inputs: Modality, split: &str| {
        base(&data, 1).with(|c| {
            c.network.model = ModelConfig::from_name("cmx-mit-b0", 9).unwrap();
            c.network.inputs = inputs;
            c.learning.procedure = procedure;
            c.schedule.max_steps_per_epoch = Some(2);
            if let DatasetConfig::Mf {
                train_split,
                val_split,
                ..
            } = &mut c.data.dataset
            {
                *train_split = split.into();
                *val_split = None;
            }
        })
    };
    let rgbt_teacher = {
        tch::manual_seed(4);
        let vs = tch::nn::VarStore::new(tch::Device::Cpu);
        let model = ModelConfig::from_name("mfnet", 9).unwrap();
        rtf_models::build(&vs.root(), &model).unwrap();
        let path = tmp.path().join("rgbt_teacher.safetensors");
        rtf_models::io::weights::save_safetensors(&vs, &model, Modality::RgbT, &path).unwrap();
        TeacherRef::Weights {
            path,
            model,
            inputs: Modality::RgbT,
        }
    };
    let targets = TargetOptions::default();
    let runs = [
        (
            "supervised",
            cmx(Procedure::Supervised, Modality::RgbT, "days"),
        ),
        (
            "teacher-student",
            cmx(
                Procedure::TeacherStudent {
                    day_teacher: common::teacher(tmp.path(), 1),
                    night_teacher: Some(common::teacher(tmp.path(), 2)),
                    targets: targets.clone(),
                },
                Modality::RgbT,
                "train",
            ),
        ),
        ("adversarial", {
            let mut c = adversarial(&data, 1, common::teacher(tmp.path(), 1));
            c.network.model = ModelConfig::from_name("cmx-mit-b0", 9).unwrap();
            c.schedule.max_steps_per_epoch = Some(2);
            if let DatasetConfig::Mf { val_split, .. } = &mut c.data.dataset {
                *val_split = None;
            }
            c
        }),
        (
            "distillation",
            cmx(
                Procedure::TeacherStudent {
                    day_teacher: rgbt_teacher.clone(),
                    night_teacher: Some(rgbt_teacher),
                    targets,
                },
                Modality::Rgb,
                "train",
            ),
        ),
    ];
    for (name, cfg) in runs {
        let run = rtf_train::train(&cfg, &tmp.path().join(name), false, &mut |_| {})
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let loss = run.records[0].train_loss;
        assert!(loss.is_finite() && loss > 0.0, "{name}: loss {loss}");
    }
}
