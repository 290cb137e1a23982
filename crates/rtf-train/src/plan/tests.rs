use std::path::Path;
use std::sync::atomic::AtomicBool;

use rtf_data::synth::{generate, SynthConfig, SynthFormat};
use rtf_models::Modality;

use super::sources::OPENED;
use super::teachers::CHECKED;
use super::*;
use crate::config::{Procedure, TeacherRef};
use crate::progress::Epochs;
use crate::RunConfig;

/// A teacher-student run of one step on a synthetic MF set, its day teacher a weights file.
fn teacher_student(dir: &Path) -> TrainConfig {
    let data = dir.join("data");
    let synth = SynthConfig {
        count: 8,
        width: 32,
        height: 32,
        format: SynthFormat::Mf,
        ..SynthConfig::default()
    };
    generate(&data, &synth).unwrap();
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let model = rtf_models::ModelConfig::from_name("mfnet", 9).unwrap();
    rtf_models::build(&vs.root(), &model).unwrap();
    let path = dir.join("teacher.safetensors");
    rtf_models::io::weights::save_safetensors(&vs, &model, Modality::Rgb, &path).unwrap();
    TrainConfig::mfnet_paper(data).with(|c| {
        c.schedule.epochs = 1;
        c.schedule.batch_size = 2;
        c.schedule.max_steps_per_epoch = Some(1);
        c.data.workers = 1;
        c.learning.procedure = Procedure::TeacherStudent {
            day_teacher: TeacherRef::Weights {
                path,
                model,
                inputs: Modality::Rgb,
            },
            night_teacher: None,
            targets: Default::default(),
        };
    })
}

/// From the configuration to the end of training, the dataset root is opened once and the
/// teacher checked once; config.json records the fingerprint of that opened dataset.
#[test]
fn a_run_opens_its_dataset_once_and_checks_its_teachers_once() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = teacher_student(tmp.path());
    OPENED.with(|n| n.set(0));
    CHECKED.with(|n| n.set(0));
    let plan = RunPlan::resolve(&cfg).unwrap();
    let counts = || (OPENED.with(|n| n.get()), CHECKED.with(|n| n.get()));
    assert_eq!(counts(), (1, 1), "(datasets opened, teachers checked)");
    let fingerprint = rtf_data::fingerprint::fingerprint_opened(&plan.sources.dataset).unwrap();
    assert_eq!(plan.record.data.fingerprint.as_ref(), Some(&fingerprint));
    let day = plan.teachers.day.as_ref().map(|t| t.model.name());
    assert_eq!(day.as_deref(), Some("mfnet"));

    let run = tmp.path().join("run");
    let mut progress = Epochs(|_: &str, _: &rtf_run::EpochRecord| {});
    let stop = AtomicBool::new(false);
    crate::trainer::train_planned(plan, &run, false, &mut progress, &stop, None).unwrap();
    assert_eq!(counts(), (1, 1), "training opens and checks nothing again");
    let RunConfig::Single(recorded) = crate::folder::read_config(&run).unwrap() else {
        panic!("a single run")
    };
    assert_eq!(recorded.data.fingerprint, Some(fingerprint));
}

/// A teacher that cannot teach the student is refused by the plan, before a run folder exists.
#[test]
fn a_bad_teacher_is_refused_by_the_plan() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = teacher_student(tmp.path()).with(|c| {
        if let Procedure::TeacherStudent { day_teacher, .. } = &mut c.learning.procedure {
            *day_teacher = TeacherRef::Stage("teacher".into());
        }
    });
    let err = RunPlan::resolve(&cfg).err().unwrap().to_string();
    assert!(err.contains("teacher stage `teacher`"), "{err}");
}
