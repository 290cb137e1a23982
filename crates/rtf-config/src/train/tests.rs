use super::*;

/// A config.json written before `shuffle` existed loads as shuffled; `false` is written
/// and read back (rtf train --no-shuffle).
#[test]
fn shuffle_defaults_to_on_and_is_recorded_when_off() {
    let mut cfg = TrainConfig::mfnet_paper(PathBuf::from("/data"));
    let old = serde_json::to_value(&cfg).unwrap();
    assert!(old["data"].get("shuffle").is_none(), "{old}");
    let back: TrainConfig = serde_json::from_value(old).unwrap();
    assert!(back.data.shuffle);
    cfg.data.shuffle = false;
    let text = serde_json::to_string(&cfg).unwrap();
    assert!(text.contains("\"shuffle\":false"), "{text}");
    assert!(
        !serde_json::from_str::<TrainConfig>(&text)
            .unwrap()
            .data
            .shuffle
    );
}

/// A config.json written by `rtf train` before the sections (tests/fixtures/README.md)
/// reads into them, and is written back in sections that read to the same config.
#[test]
fn a_flat_config_json_from_before_the_sections_reads_into_them() {
    let text = include_str!("../../tests/fixtures/flat_single_config.json");
    let RunConfig::Single(cfg) = RunConfig::parse(text, false).unwrap() else {
        panic!("a single run")
    };
    assert_eq!(cfg.network.model.name(), "mfnet");
    assert_eq!(
        cfg.data.dataset,
        DatasetConfig::Mf {
            root: "/tmp/house/fx/mf".into(),
            train_split: "train".into(),
            val_split: Some("val".into()),
        }
    );
    assert!(cfg.data.shuffle && cfg.data.augment.hflip);
    assert_eq!(cfg.data.workers, 2);
    assert_eq!(cfg.data.fingerprint.as_ref().unwrap().splits.len(), 5);
    assert_eq!(cfg.learning.optimizer, OptimizerConfig::mfnet_paper());
    assert_eq!(cfg.learning.precision, Precision::Fp32);
    assert_eq!((cfg.schedule.epochs, cfg.schedule.batch_size), (1, 6));
    assert_eq!(cfg.schedule.tb_images_every, Some(5));
    assert_eq!(cfg.compute.device, "cpu");
    let nested = serde_json::to_value(&*cfg).unwrap();
    let keys: Vec<&String> = nested.as_object().unwrap().keys().collect();
    assert_eq!(keys.len(), SECTIONS.len());
    assert!(SECTIONS.iter().all(|s| nested.get(s).is_some()), "{nested}");
    assert_eq!(serde_json::from_value::<TrainConfig>(nested).unwrap(), *cfg);
}

/// A multi-stage recipe's config.json and a stage's own (teachers by weights file) of
/// the flat layout read too.
#[test]
fn a_flat_recipe_config_and_its_stage_config_read_into_sections() {
    let text = include_str!("../../tests/fixtures/flat_recipe_config.json");
    let RunConfig::Pipeline(p) = RunConfig::parse(text, false).unwrap() else {
        panic!("a pipeline")
    };
    assert_eq!(p.recipe.as_deref(), Some("heatnet-v3"));
    let names: Vec<&str> = p.stages.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["teacher-rgb", "v3"]);
    assert!(matches!(
        &p.stages[1].config.learning.procedure,
        Procedure::TeacherStudent { day_teacher: TeacherRef::Stage(s), .. } if s == "teacher-rgb"
    ));
    assert_eq!(p.stages[0].config.network.inputs, Modality::Rgb);
    RunConfig::Pipeline(p).validate().unwrap();
    let text = include_str!("../../tests/fixtures/flat_recipe_stage_config.json");
    let RunConfig::Single(stage) = RunConfig::parse(text, false).unwrap() else {
        panic!("a stage is a single run")
    };
    assert!(matches!(
        &stage.learning.procedure,
        Procedure::TeacherStudent { day_teacher: TeacherRef::Weights { path, .. }, .. }
            if path.ends_with("teacher-rgb/best.safetensors")
    ));
}

/// Unknown keys are refused in both layouts, by name: a flat config's misspelt setting, a
/// setting left at the top of a sectioned one, a misspelt key inside a section.
#[test]
fn unknown_keys_are_refused_in_both_layouts() {
    let flat = r#"{"model": {"network": "mfnet", "num_classes": 9}, "epochz": 3}"#;
    let err = RunConfig::parse(flat, false).unwrap_err();
    assert!(err.contains("epochz"), "{err}");
    let cfg = TrainConfig::mfnet_paper("data".into());
    let mut nested = serde_json::to_value(&cfg).unwrap();
    nested["epochs"] = 3.into();
    let err = RunConfig::parse(&nested.to_string(), false).unwrap_err();
    assert!(err.contains("unknown field `epochs`"), "{err}");
    let mut nested = serde_json::to_value(&cfg).unwrap();
    nested["schedule"]["epochz"] = 3.into();
    let err = RunConfig::parse(&nested.to_string(), false).unwrap_err();
    assert!(err.contains("unknown field `epochz`"), "{err}");
    let yaml = "network: {model: {network: mfnet, num_classes: 9}}\nschedul: {}\n";
    let err = RunConfig::parse(yaml, true).unwrap_err();
    assert!(err.contains("schedul"), "{err}");
}

#[test]
fn schedule_decays_per_epoch() {
    let sgd = OptimizerConfig::mfnet_paper();
    let epoch = |e, step| StepAt {
        epoch: e,
        step,
        steps_per_epoch: 7,
        epochs: 100,
    };
    assert_eq!(sgd.lr_at(epoch(0, 0)), 0.01);
    assert!((sgd.lr_at(epoch(2, 5)) - 0.01 * 0.94 * 0.94).abs() < 1e-15);
    let heatnet = OptimizerConfig::heatnet_paper();
    assert_eq!(heatnet.lr_at(StepAt::start_of(29)), 1e-4);
    assert_eq!(heatnet.lr_at(epoch(30, 6)), 0.5e-4);
    assert_eq!(heatnet.lr_at(StepAt::start_of(99)), 0.125e-4);
}

/// CMX's per-step schedule over the run's steps: 0 at the first step, half the rate half-way
/// through the warm-up, the poly decay after it.
#[test]
fn cmx_schedule_warms_up_then_decays_per_step() {
    let cmx = OptimizerConfig::cmx_code();
    let at = |epoch, step| StepAt {
        epoch,
        step,
        steps_per_epoch: 4,
        epochs: 20,
    };
    assert_eq!(cmx.lr_at(at(0, 0)), 0.0);
    assert!((cmx.lr_at(at(5, 0)) - 3e-5).abs() < 1e-18);
    let poly = 6e-5 * (1.0 - 41.0 / 80.0f64).powf(0.9);
    assert!((cmx.lr_at(at(10, 1)) - poly).abs() < 1e-18);
    assert!(cmx.lr_at(at(19, 3)) > 0.0);
}

/// CMX's optimiser section is written with its kind, scope and schedule and reads back; the
/// older sections (no such keys) read as before; bad betas and powers are refused by name.
#[test]
fn adamw_sections_round_trip_and_validate() {
    let cmx = OptimizerConfig::cmx_code();
    let json = serde_json::to_value(&cmx).unwrap();
    assert_eq!(json["kind"], "adamw");
    assert_eq!(json["decay_scope"], "conv_and_linear_weights");
    assert_eq!(json["schedule"]["kind"], "warmup_poly");
    assert!(
        json.get("betas").is_none(),
        "PyTorch's betas are not written"
    );
    assert_eq!(
        serde_json::from_value::<OptimizerConfig>(json).unwrap(),
        cmx
    );
    let sgd = serde_json::to_value(OptimizerConfig::mfnet_paper()).unwrap();
    assert!(sgd.get("schedule").is_none() && sgd.get("decay_scope").is_none());
    cmx.validate("o").unwrap();
    let bad_betas = OptimizerConfig {
        betas: (0.9, 1.0),
        ..cmx.clone()
    };
    assert_eq!(bad_betas.validate("o").unwrap_err().field, "o.betas");
    let bad_power = OptimizerConfig {
        schedule: LrSchedule::WarmupPoly {
            power: 0.0,
            warmup_epochs: 1,
        },
        ..cmx
    };
    assert_eq!(
        bad_power.validate("o").unwrap_err().field,
        "o.schedule.power"
    );
}

#[test]
fn optimizer_kinds_parse_to_their_papers_optimisers() {
    for (text, expected) in [
        ("sgd", OptimizerConfig::mfnet_paper()),
        ("rmsprop", OptimizerConfig::heatnet_paper()),
        ("adamw", OptimizerConfig::cmx_code()),
    ] {
        let kind = OptimizerKind::parse(text).unwrap();
        assert_eq!(OptimizerConfig::paper_default(kind), expected);
    }
    let err = OptimizerKind::parse("adam").unwrap_err();
    assert!(err.contains("adamw"), "{err}");
}

#[test]
fn optimizer_configs_written_before_rmsprop_still_read() {
    let old = r#"{"lr": 0.01, "momentum": 0.9, "weight_decay": 0.0005, "lr_decay": 0.94}"#;
    let cfg: OptimizerConfig = serde_json::from_str(old).unwrap();
    assert_eq!(cfg, OptimizerConfig::mfnet_paper());
}

#[test]
fn config_round_trips_through_json() {
    let cfg = TrainConfig::mfnet_paper("data/mf".into());
    let json = serde_json::to_string_pretty(&cfg).unwrap();
    assert_eq!(serde_json::from_str::<TrainConfig>(&json).unwrap(), cfg);
    assert!(json.contains("\"seed\""));
}

#[test]
fn a_described_dataset_round_trips_with_its_format_tag() {
    let cfg = DatasetConfig::Described {
        root: "data/pst900".into(),
        train_split: "train".into(),
        val_split: Some("holdout:10".into()),
        trained_on: Some(crate::data::TrainedOn {
            classes: rtf_core::ClassSet::mf(),
            thermal: Some(crate::data::ThermalNormalisation::Byte),
        }),
    };
    let json = serde_json::to_string(&cfg).unwrap();
    assert!(json.contains(r#""format":"described""#), "{json}");
    assert_eq!(serde_json::from_str::<DatasetConfig>(&json).unwrap(), cfg);
}

#[test]
fn freiburg_dataset_round_trips_and_defaults_to_the_reference_preprocessing() {
    let cfg = DatasetConfig::freiburg("data/freiburg".into(), true);
    let json = serde_json::to_string(&cfg).unwrap();
    assert_eq!(serde_json::from_str::<DatasetConfig>(&json).unwrap(), cfg);
    let short = r#"{"format": "freiburg", "root": "data/freiburg"}"#;
    assert_eq!(serde_json::from_str::<DatasetConfig>(short).unwrap(), cfg);
}
