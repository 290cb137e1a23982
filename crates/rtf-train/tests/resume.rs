//! A run stopped after one epoch, or inside one, or finished and extended by more epochs
//! (single or multi-stage), and resumed ends bit-identical to an uninterrupted run.

mod common;

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::sync::Mutex;

use rtf_train::config::{LrSchedule, PipelineConfig, StageConfig, WeightsRef};
use rtf_train::resume;
use rtf_train::{DatasetConfig, OptimizerConfig, RunConfig, TrainConfig};

/// A tiny MF-layout dataset: random RGBA frames whose label is "hot pixel = person".
/// libtorch's random generator is process-global: tests that compare runs must not interleave.
static TORCH_RNG: Mutex<()> = Mutex::new(());

fn config(root: &Path, epochs: usize) -> TrainConfig {
    let mut cfg = TrainConfig::mfnet_paper(root.to_path_buf());
    cfg.data.dataset = DatasetConfig::Mf {
        root: root.to_path_buf(),
        train_split: "train".into(),
        val_split: Some("val".into()),
    };
    cfg.schedule.epochs = epochs;
    cfg.schedule.batch_size = 2;
    cfg.schedule.seed = 7;
    cfg.data.workers = 1;
    cfg
}

#[test]
fn resumed_run_equals_uninterrupted_run() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 6, 12345, 4);
    // SGD's momentum buffers, and RMSprop's square averages plus momentum, must all resume.
    let optimizers = [
        ("sgd", OptimizerConfig::mfnet_paper()),
        (
            "rmsprop",
            OptimizerConfig {
                momentum: 0.5,
                ..OptimizerConfig::heatnet_paper()
            },
        ),
    ];
    for (label, optimizer) in optimizers {
        let config = |epochs| {
            config(&data, epochs).with(|c| {
                c.learning.optimizer = optimizer.clone();
            })
        };
        let straight = tmp.path().join(format!("{label}-straight"));
        let outcome = rtf_train::train(&config(2), &straight, false, &mut |_| {}).unwrap();
        assert_eq!(outcome.records.len(), 2);
        assert!(outcome
            .records
            .iter()
            .all(|r| r.train_loss.is_finite() && r.val_miou.is_some()));

        let split = tmp.path().join(format!("{label}-split"));
        rtf_train::train(&config(1), &split, false, &mut |_| {}).unwrap();
        let resumed = rtf_train::train(&config(2), &split, true, &mut |_| {}).unwrap();
        assert_eq!(resumed.records.len(), 1, "only the missing epoch runs");
        assert_eq!(resumed.state.epochs_done, 2);
        assert_eq!(resumed.state.steps_done, outcome.state.steps_done);

        let a = common::weights(&straight.join("final.safetensors"));
        let b = common::weights(&split.join("final.safetensors"));
        assert_eq!(a.len(), b.len());
        for ((na, da), (nb, db)) in a.iter().zip(&b) {
            assert_eq!(na, nb);
            assert!(
                da == db,
                "{label}: `{na}` differs between the resumed and the uninterrupted run"
            );
        }
        let log = std::fs::read_to_string(split.join("log.jsonl")).unwrap();
        assert_eq!(log.lines().count(), 2);
    }
}

#[test]
fn run_stopped_inside_an_epoch_resumes_exactly() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 6, 12345, 4);
    // HeatNet's optimiser with momentum, and CMX's AdamW (moments and step counts per tensor,
    // a per-step warm-up-then-poly rate, decay on weights only): their state must survive a
    // mid-epoch stop too.
    let optimizers = [
        (
            "rmsprop",
            OptimizerConfig {
                momentum: 0.5,
                ..OptimizerConfig::heatnet_paper()
            },
        ),
        (
            "adamw",
            OptimizerConfig {
                schedule: LrSchedule::WarmupPoly {
                    power: 0.9,
                    warmup_epochs: 1,
                },
                ..OptimizerConfig::cmx_code()
            },
        ),
    ];
    for (label, optimizer) in optimizers {
        let cfg = config(&data, 2).with(|c| c.learning.optimizer = optimizer);
        stopped_inside_an_epoch_resumes(&cfg, &tmp.path().join(label));
    }
}

fn stopped_inside_an_epoch_resumes(cfg: &TrainConfig, dir: &Path) {
    let straight = dir.join("straight");
    let expected = rtf_train::train(cfg, &straight, false, &mut |_| {}).unwrap();

    // A stop requested before the first step ends the run after it: batch 1 of epoch 1's 2.
    let stopped = dir.join("stopped");
    let stop = AtomicBool::new(true);
    let outcome =
        rtf_train::trainer::train_until(cfg, &stopped, false, &mut |_| {}, &stop).unwrap();
    assert!(outcome.final_weights.is_none() && outcome.records.is_empty());
    assert_eq!(outcome.state.partial.as_ref().map(|p| p.batches), Some(1));
    assert!(!stopped.join("final.safetensors").exists());

    // Checkpointing every step must not change the result either.
    let resumed_cfg = cfg.clone().with(|c| {
        c.schedule.checkpoint_every = Some(1);
    });
    let resumed = rtf_train::train(&resumed_cfg, &stopped, true, &mut |_| {}).unwrap();
    assert_eq!(
        resumed.records.len(),
        2,
        "the stopped epoch is finished and logged"
    );
    assert_eq!(resumed.state.steps_done, expected.state.steps_done);
    for (a, b) in expected.records.iter().zip(&resumed.records) {
        assert_eq!((a.epoch, a.images), (b.epoch, b.images));
        assert_eq!(
            a.train_loss, b.train_loss,
            "epoch {}: loss sums carried over",
            a.epoch
        );
    }
    let (a, b) = (
        common::weights(&straight.join("final.safetensors")),
        common::weights(&stopped.join("final.safetensors")),
    );
    assert_eq!(a, b, "stopped and resumed inside an epoch = uninterrupted");
}

#[test]
fn training_lowers_the_loss() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 6, 12345, 4);
    let mut cfg = config(&data, 20);
    cfg.learning.optimizer.lr = 0.05;
    cfg.data.dataset = DatasetConfig::Mf {
        root: data.clone(),
        train_split: "train".into(),
        val_split: None,
    };
    let outcome = rtf_train::train(&cfg, &tmp.path().join("run"), false, &mut |_| {}).unwrap();
    let first = outcome.records.first().unwrap().train_loss;
    let last = outcome.records.last().unwrap().train_loss;
    // The figures, for audits across CPU kinds (issue 44): the line is half the first loss.
    eprintln!(
        "training_lowers_the_loss: loss {first:.4} -> {last:.4} (line {:.4})",
        0.5 * first
    );
    assert!(last < 0.5 * first, "loss {first} -> {last}");
}

#[test]
fn backbone_weights_are_loaded_before_the_first_step() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 6, 12345, 4);
    // A torchvision-named ResNet-18 (tch's own resnet uses torchvision's names).
    let imagenet = tch::nn::VarStore::new(tch::Device::Cpu);
    let _ = tch::vision::resnet::resnet18_no_final_layer(&imagenet.root());
    let backbone = tmp.path().join("resnet18.safetensors");
    imagenet.save(&backbone).unwrap();

    let mut cfg = config(&data, 1);
    cfg.network.model = rtf_models::ModelConfig::from_name("rtfnet18", 9).unwrap();
    cfg.data.dataset = DatasetConfig::Mf {
        root: data.clone(),
        train_split: "train".into(),
        val_split: None,
    };
    cfg.network.backbone_weights = Some(backbone.clone());
    // No visible update (a rate of 0 is refused as a configuration error): 1e-30 × any
    // gradient is far below one ulp of these weights, so the written weights are the initial ones.
    cfg.learning.optimizer.lr = 1e-30;
    cfg.learning.optimizer.weight_decay = 0.0;
    cfg.schedule.max_steps_per_epoch = Some(1);
    let run = tmp.path().join("run");
    rtf_train::train(&cfg, &run, false, &mut |_| {}).unwrap();
    let written = common::weights(&run.join("final.safetensors"));
    let get = |name: &str| {
        written
            .iter()
            .find(|(n, _)| n == name)
            .unwrap_or_else(|| panic!("{name}"))
            .1
            .clone()
    };
    let source = imagenet.variables();
    let bytes = |t: &tch::Tensor| {
        let v = Vec::<f32>::try_from(t.flatten(0, -1)).unwrap();
        v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>()
    };
    assert_eq!(
        get("encoder_rgb_layer1.0.conv1.weight"),
        bytes(&source["layer1.0.conv1.weight"])
    );
    assert_eq!(
        get("encoder_thermal_layer4.1.conv2.weight"),
        bytes(&source["layer4.1.conv2.weight"])
    );
    // Thermal stem: mean of the RGB stem over its input channels.
    assert_eq!(
        get("encoder_thermal_conv1.weight"),
        bytes(&source["conv1.weight"].mean_dim(1, true, tch::Kind::Float))
    );

    let mut missing = cfg.clone();
    missing.network.backbone_weights = Some(tmp.path().join("nope.safetensors"));
    let err = rtf_train::train(&missing, &tmp.path().join("run2"), false, &mut |_| {}).unwrap_err();
    assert!(err.to_string().contains("nope.safetensors"), "{err}");
}

#[test]
fn a_log_line_lost_to_a_kill_comes_back_on_resume() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 6, 12345, 4);
    let run = tmp.path().join("run");
    rtf_train::train(&config(&data, 1), &run, false, &mut |_| {}).unwrap();
    // A kill between the checkpoint's rename and the log's append: the line is missing.
    std::fs::write(run.join("log.jsonl"), "").unwrap();
    rtf_train::train(&config(&data, 2), &run, true, &mut |_| {}).unwrap();
    let log = rtf_run::log::read(&run.join("log.jsonl")).unwrap();
    let epochs: Vec<usize> = log.iter().map(|r| r.epoch).collect();
    assert_eq!(epochs, [0, 1]);
}

/// Issue 30: the checkpoint carried every epoch's log record, so it (and the run's memory)
/// grew with each epoch. It carries the last one only: its size after 2 epochs and after 8
/// differs by no more than a record's numbers can change length (a few bytes each).
#[test]
fn the_checkpoint_does_not_grow_with_the_epochs() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 6, 12345, 4);
    let run = tmp.path().join("run");
    let checkpoint = run.join("checkpoint.safetensors");
    let size = || std::fs::metadata(&checkpoint).unwrap().len() as i64;
    rtf_train::train(&config(&data, 2), &run, false, &mut |_| {}).unwrap();
    let after_2 = size();
    let extended = rtf_train::train(&config(&data, 8), &run, true, &mut |_| {}).unwrap();
    assert_eq!(
        extended.records.len(),
        6,
        "the outcome holds the 6 epochs this call trained"
    );
    let record_bytes = std::fs::read_to_string(run.join("log.jsonl"))
        .unwrap()
        .lines()
        .last()
        .unwrap()
        .len() as i64;
    assert!(
        (size() - after_2).abs() < record_bytes / 4,
        "checkpoint {after_2} → {} bytes over 6 epochs (a record is {record_bytes})",
        size()
    );
}

#[test]
fn a_diverging_run_stops_and_never_writes_non_finite_weights() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 6, 12345, 4);
    let mut cfg = config(&data, 3);
    cfg.learning.optimizer.lr = 1e12;
    let run = tmp.path().join("run");
    let err = rtf_train::train(&cfg, &run, false, &mut |_| {}).unwrap_err();
    assert!(err.to_string().contains("diverged"), "{err}");
    for file in [
        "checkpoint.safetensors",
        "best.safetensors",
        "final.safetensors",
    ] {
        let path = run.join(file);
        if !path.exists() {
            continue;
        }
        let bytes = std::fs::read(&path).unwrap();
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        for (name, view) in st.tensors() {
            let finite = view
                .data()
                .chunks_exact(4)
                .all(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite());
            assert!(finite, "{file}: `{name}` holds a non-finite value");
        }
    }
}

/// A finished run extended by a resume with more epochs (`rtf train --resume RUN --epochs 4`
/// after 2) ends with the weights and log of a 4-epoch run; a resume with nothing left says so;
/// a checkpoint inside an epoch cannot be declared final by asking for fewer epochs.
#[test]
fn a_finished_run_extended_equals_an_uninterrupted_run() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 6, 12345, 4);
    let straight = tmp.path().join("straight");
    let expected = rtf_train::train(&config(&data, 4), &straight, false, &mut |_| {}).unwrap();

    let extended = tmp.path().join("extended");
    let mut run = RunConfig::Single(Box::new(config(&data, 2)));
    rtf_train::train(&config(&data, 2), &extended, false, &mut |_| {}).unwrap();
    let finished = resume::finished(&run, &extended)
        .unwrap()
        .expect("finished");
    assert_eq!(
        finished.to_string(),
        "nothing to do: finished at epoch 2 of 2"
    );
    assert_eq!(finished.weights, extended.join("final.safetensors"));
    resume::extend(&mut run, &extended, 4).unwrap();
    assert_eq!(resume::finished(&run, &extended).unwrap(), None);
    let RunConfig::Single(cfg) = &run else {
        panic!("a single run stays single")
    };
    assert_eq!(cfg.schedule.epochs, 4);
    let resumed = rtf_train::train(cfg, &extended, true, &mut |_| {}).unwrap();
    assert_eq!(resumed.records.len(), 2, "epochs 3 and 4 train");
    assert_eq!(resumed.state.steps_done, expected.state.steps_done);
    assert_eq!(
        common::weights(&straight.join("final.safetensors")),
        common::weights(&extended.join("final.safetensors")),
        "2 epochs extended to 4 = 4 epochs"
    );
    let log = std::fs::read_to_string(extended.join("log.jsonl")).unwrap();
    assert_eq!(log.lines().count(), 4);
    assert!(resume::finished(&run, &extended).unwrap().is_some());
    // Fewer epochs than done: refused.
    let err = rtf_train::train(&config(&data, 3), &extended, true, &mut |_| {}).unwrap_err();
    assert!(err.to_string().contains("--epochs 3"), "{err}");

    // Stopped inside epoch 2 of 2: asking for 1 epoch would call mid-epoch weights final.
    let stopped = tmp.path().join("stopped");
    rtf_train::train(&config(&data, 1), &stopped, false, &mut |_| {}).unwrap();
    let stop = AtomicBool::new(true);
    rtf_train::trainer::train_until(&config(&data, 2), &stopped, true, &mut |_| {}, &stop).unwrap();
    assert!(resume::saved_state(&stopped)
        .unwrap()
        .unwrap()
        .partial
        .is_some());
    let stopped_run = RunConfig::Single(Box::new(config(&data, 1)));
    assert_eq!(resume::finished(&stopped_run, &stopped).unwrap(), None);
    let err = rtf_train::train(&config(&data, 1), &stopped, true, &mut |_| {}).unwrap_err();
    assert!(err.to_string().contains("part of epoch 2"), "{err}");
}

/// A finished two-stage run (stage 2 starts from stage 1's weights) extended by a resume with
/// more epochs trains its last stage only, and ends as the same run trained for those epochs
/// in one go; stage 1 is untouched.
#[test]
fn a_finished_multi_stage_run_extends_its_last_stage_exactly() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 6, 12345, 4);
    let pipeline = |last_epochs| {
        RunConfig::Pipeline(PipelineConfig {
            recipe: None,
            stages: vec![
                StageConfig {
                    name: "first".into(),
                    config: config(&data, 1),
                },
                StageConfig {
                    name: "second".into(),
                    config: config(&data, last_epochs).with(|c| {
                        c.network.init_from = Some(WeightsRef::Stage("first".into()));
                    }),
                },
            ],
        })
    };
    let never = AtomicBool::new(false);
    let train = |run: &RunConfig, dir: &Path, resume: bool| {
        let RunConfig::Pipeline(p) = run else {
            panic!("a pipeline")
        };
        rtf_train::pipeline::run_pipeline(p, dir, resume, &mut |_, _| {}, &never).unwrap()
    };
    let straight = tmp.path().join("straight");
    train(&pipeline(4), &straight, false);

    let extended = tmp.path().join("extended");
    let mut run = pipeline(2);
    train(&run, &extended, false);
    let finished = resume::finished(&run, &extended)
        .unwrap()
        .expect("finished");
    assert_eq!(
        finished.to_string(),
        "nothing to do: finished at epoch 2 of 2 (last stage second)"
    );
    let first_before = common::weights(&extended.join("first/final.safetensors"));
    resume::extend(&mut run, &extended, 4).unwrap();
    let RunConfig::Pipeline(p) = &run else {
        panic!("a pipeline")
    };
    assert_eq!(
        p.stages
            .iter()
            .map(|s| s.config.schedule.epochs)
            .collect::<Vec<_>>(),
        [1, 4],
        "only the last stage is extended"
    );
    let outcome = train(&run, &extended, true);
    assert_eq!(outcome.trained, ["second"]);
    assert_eq!(
        common::weights(&extended.join("first/final.safetensors")),
        first_before
    );
    for file in ["second/final.safetensors", "final.safetensors"] {
        assert_eq!(
            common::weights(&straight.join(file)),
            common::weights(&extended.join(file)),
            "{file}: stage 2 extended from 2 to 4 epochs = 4 epochs"
        );
    }
    let log = std::fs::read_to_string(extended.join("second/log.jsonl")).unwrap();
    assert_eq!(log.lines().count(), 4);
    // Fewer epochs than the last stage has done: refused before anything trains.
    let err = resume::extend(&mut run.clone(), &extended, 3).unwrap_err();
    assert!(err.to_string().contains("--epochs 3"), "{err}");
}

/// A run folder started before `config.json` had sections (its flat config.json written by
/// the `rtf` of that time, tests/fixtures/README.md) resumes, here extended from 1 to 2
/// epochs, and ends as the same run trained 2 epochs in one go; the resume writes its config
/// back in sections.
#[test]
fn a_run_folder_with_a_flat_config_json_from_before_the_sections_resumes_exactly() {
    let _rng = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 6, 12345, 4);
    let mut flat: serde_json::Value = serde_json::from_str(include_str!(
        "../../rtf-config/tests/fixtures/flat_single_config.json"
    ))
    .unwrap();
    flat["dataset"]["root"] = data.to_str().unwrap().into();
    flat["batch_size"] = 2.into();
    let flat = flat.to_string();
    let RunConfig::Single(old) = RunConfig::parse(&flat, false).unwrap() else {
        panic!("a single run")
    };
    assert_eq!(old.schedule.epochs, 1);

    let straight = tmp.path().join("straight");
    let two = old.clone().with(|c| c.schedule.epochs = 2);
    rtf_train::train(&two, &straight, false, &mut |_| {}).unwrap();

    // The folder as that build left it after one epoch: its checkpoint, its flat config.
    let folder = tmp.path().join("old");
    rtf_train::train(&old, &folder, false, &mut |_| {}).unwrap();
    std::fs::write(folder.join("config.json"), &flat).unwrap();
    // What `rtf train --resume old --epochs 2` does.
    let mut run = rtf_train::trainer::read_config(&folder).unwrap();
    assert!(resume::finished(&run, &folder).unwrap().is_some());
    resume::extend(&mut run, &folder, 2).unwrap();
    let RunConfig::Single(cfg) = &run else {
        panic!("a single run stays single")
    };
    let resumed = rtf_train::train(cfg, &folder, true, &mut |_| {}).unwrap();
    assert_eq!(resumed.records.len(), 1, "epoch 2 trains");
    assert_eq!(
        common::weights(&straight.join("final.safetensors")),
        common::weights(&folder.join("final.safetensors")),
        "1 epoch under the flat config, extended to 2 = 2 epochs"
    );
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(folder.join("config.json")).unwrap())
            .unwrap();
    assert_eq!(written["schedule"]["epochs"], 2, "{written}");
    assert!(written.get("epochs").is_none() && written.get("dataset").is_none());
}
