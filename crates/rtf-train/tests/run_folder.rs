//! Run folders of every format rtf has written read back the same through the one reader
//! (rtf-run's `RunFolder` with rtf-train's typed configuration): the flat `config.json` and
//! first log schema of the early builds, today's sections and log, and a multi-stage recipe
//! folder of both; the recorded class set of a run.

use std::path::Path;

use rtf_train::config::{DatasetConfig, RunConfig};
use rtf_train::folder::{class_set, RunFolder, TrainedRun};
use rtf_train::EpochRecord;

mod common;

const FLAT_SINGLE: &str = include_str!("../../rtf-config/tests/fixtures/flat_single_config.json");
const FLAT_RECIPE: &str = include_str!("../../rtf-config/tests/fixtures/flat_recipe_config.json");
const FLAT_STAGE: &str =
    include_str!("../../rtf-config/tests/fixtures/flat_recipe_stage_config.json");

/// A log line of the first builds (flat fields only) of `epoch`.
fn first_schema_line(epoch: usize) -> String {
    format!(
        r#"{{"epoch":{epoch},"lr":0.01,"train_loss":{},"images":4,"seconds":1.5,"images_per_s":2.5,"data_wait_fraction":0.1,"val_miou":0.25,"val_macc":0.5}}"#,
        2.0 / (epoch + 1) as f64
    )
}

/// The same epoch as today's trainer writes it (loss terms, learning rates, nested scores).
fn todays_line(epoch: usize) -> String {
    let record: EpochRecord = serde_json::from_str(&first_schema_line(epoch)).unwrap();
    let mut line = serde_json::to_value(&record).unwrap();
    line["losses"] = serde_json::json!({"ce": record.train_loss});
    line["lrs"] = serde_json::json!({"student": 0.01});
    line["val"] = serde_json::json!({"miou": 0.25, "macc": 0.5, "miou_day": 0.3,
        "miou_night": null, "per_class_iou": {"car": 0.5, "person": null},
        "selected_by": "miou", "selected": 0.25});
    line.to_string()
}

fn write_run(dir: &Path, config: &str, log: &[String]) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("config.json"), config).unwrap();
    std::fs::write(dir.join("log.jsonl"), log.join("\n") + "\n").unwrap();
}

/// A configuration written in today's sections (what `rtf train` writes now).
fn in_sections(flat: &str) -> String {
    let cfg = RunConfig::parse(flat, false).unwrap();
    let text = serde_json::to_string_pretty(&cfg).unwrap();
    assert_ne!(text, flat);
    text
}

/// (epoch, lr, training loss, validation mIoU) of every epoch: what both schemas record.
fn epochs(folder: &RunFolder) -> Vec<(usize, f64, f64, Option<f64>)> {
    let log = folder.epochs().unwrap();
    log.iter()
        .map(|r| (r.epoch, r.lr, r.train_loss, r.val_miou))
        .collect()
}

#[test]
fn a_flat_run_of_the_first_builds_reads_as_today_s() {
    let tmp = tempfile::tempdir().unwrap();
    let (old, new) = (tmp.path().join("old"), tmp.path().join("new"));
    write_run(
        &old,
        FLAT_SINGLE,
        &(0..3).map(first_schema_line).collect::<Vec<_>>(),
    );
    write_run(
        &new,
        &in_sections(FLAT_SINGLE),
        &(0..3).map(todays_line).collect::<Vec<_>>(),
    );
    std::fs::write(new.join("final.safetensors"), b"w").unwrap();
    let (a, b) = (
        TrainedRun::open(&old).unwrap(),
        TrainedRun::open(&new).unwrap(),
    );
    assert_eq!(a.config(), b.config());
    assert!(matches!(a.config(), RunConfig::Single(_)));
    assert_eq!(a.last_training().schedule.batch_size, 6);
    assert_eq!(epochs(a.folder()), epochs(b.folder()));
    assert_eq!(epochs(a.folder()).len(), 3);
    // Only today's log has the nested scores and loss terms.
    let last = b.folder().last_epoch().unwrap().unwrap();
    assert_eq!(last.val.unwrap().per_class_iou["car"], Some(0.5));
    assert!(a.folder().epochs().unwrap()[2].val.is_none());
    // The settings are each file's own, in its own layout.
    let keys = |run: &TrainedRun| -> Vec<String> {
        run.folder()
            .settings()
            .into_iter()
            .map(|(k, _)| k)
            .collect()
    };
    assert!(keys(&a).contains(&"batch_size".to_string()));
    assert!(keys(&b).contains(&"schedule.batch_size".to_string()));
    assert_eq!(a.folder().weights().selected(), None);
    assert_eq!(
        b.folder().weights().selected(),
        Some(&*new.join("final.safetensors"))
    );
}

/// A multi-stage recipe folder: the stages its config lists, each an ordinary run folder
/// with its own config and log, read the same from the flat layout and from sections.
#[test]
fn a_multi_stage_recipe_folder_reads_the_same_in_both_layouts() {
    let tmp = tempfile::tempdir().unwrap();
    let mut read = Vec::new();
    for (name, top, stage) in [
        ("flat", FLAT_RECIPE.to_string(), FLAT_STAGE.to_string()),
        (
            "sections",
            in_sections(FLAT_RECIPE),
            in_sections(FLAT_STAGE),
        ),
    ] {
        let dir = tmp.path().join(name);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("config.json"), &top).unwrap();
        let RunConfig::Pipeline(p) = RunConfig::parse(&top, false).unwrap() else {
            panic!("a pipeline")
        };
        let teacher = serde_json::to_string(&p.stages[0].config).unwrap();
        write_run(&dir.join("teacher-rgb"), &teacher, &[first_schema_line(0)]);
        write_run(&dir.join("v3"), &stage, &[todays_line(0), todays_line(1)]);
        std::fs::write(dir.join("final.safetensors"), b"w").unwrap();
        let run = TrainedRun::open(&dir).unwrap();
        let folder = run.folder();
        assert_eq!(folder.stage_names(), ["teacher-rgb", "v3"]);
        assert!(!folder.has_log() && folder.weights().last.is_some());
        let stages: Vec<(RunConfig, Vec<_>)> = folder
            .stage_names()
            .iter()
            .map(|s| {
                let stage = folder.stage(s).unwrap();
                (stage.config().unwrap(), epochs(&stage))
            })
            .collect();
        assert_eq!(stages[1].1.len(), 2);
        read.push((run.config().clone(), run.last_training().clone(), stages));
    }
    assert!(read[0] == read[1], "the two layouts read differently");
}

/// The class set a run trained on: recorded in its configuration (described datasets), else
/// its dataset's; none when neither can be read.
#[test]
fn a_run_s_class_set_is_its_record_else_its_dataset_s() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::write_split_dataset(&data, 4, 1, 2);
    let mut cfg = rtf_train::TrainConfig::mfnet_paper(data.clone());
    let run = tmp.path().join("run");
    write_run(&run, &serde_json::to_string(&cfg).unwrap(), &[]);
    let owned = |set: rtf_core::ClassSet| -> Vec<String> {
        set.names().iter().map(|n| n.to_string()).collect()
    };
    let names = |dir: &Path| class_set(&TrainedRun::open(dir).unwrap()).map(owned);
    assert_eq!(names(&run), Some(owned(rtf_core::ClassSet::mf())));
    let mut recorded = rtf_data::TrainedOn::mf();
    recorded.classes.name = "recorded".into();
    recorded.classes.classes.truncate(3);
    cfg.data.dataset = DatasetConfig::Described {
        root: tmp.path().join("gone"),
        train_split: "train".into(),
        val_split: None,
        trained_on: Some(recorded),
    };
    cfg.network.model = cfg.network.model.with_num_classes(3);
    write_run(&run, &serde_json::to_string(&cfg).unwrap(), &[]);
    let set = class_set(&TrainedRun::open(&run).unwrap()).unwrap();
    assert_eq!((set.name.as_str(), set.len()), ("recorded", 3));
    // A described root of a config written before the record, gone since.
    cfg.data.dataset = DatasetConfig::Described {
        root: tmp.path().join("gone"),
        train_split: "train".into(),
        val_split: None,
        trained_on: None,
    };
    write_run(&run, &serde_json::to_string(&cfg).unwrap(), &[]);
    assert_eq!(names(&run), None);
}
