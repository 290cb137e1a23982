//! Multi-stage recipes (heatnet-v3 with mfnet in every role, on 64×32 Freiburg frames, one
//! step per epoch): SIGTERM and kill -9 in each stage and as the first one ends, then the
//! resume; a finished run extended; stage folders deleted, corrupt or from another recipe.

use std::path::{Path, PathBuf};

use crate::common::*;
use crate::verdict::*;
use crate::Fixture;

const STAGES: [&str; 2] = ["teacher-rgb", "v3"];

fn recipe_args(data: &Path, run: &Path, recipe: &str, epochs: &str) -> Vec<String> {
    strings(&[
        "train",
        "--recipe",
        recipe,
        "--model",
        "mfnet",
        "--data",
        s(data),
        "--out",
        s(run),
        "--epochs",
        epochs,
        "--batch-size",
        "2",
        "--max-steps",
        "1",
        "--resize",
        "64x32",
        "--workers",
        "1",
        "--val-split",
        "none",
        "--tb-images-every",
        "0",
    ])
}

/// The Freiburg data and a finished heatnet-v3 run of one epoch per stage (made once).
fn base(f: &Fixture) -> (PathBuf, PathBuf) {
    let data = f.t.join("fr");
    let run = f.t.join("recipe_done");
    if !run.join("final.safetensors").exists() {
        ok(&[
            "synth",
            "--format",
            "freiburg",
            "--out",
            s(&data),
            "--count",
            "12",
            "--size",
            "64x32",
        ]);
        let args = recipe_args(&data, &run, "heatnet-v3", "1");
        ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    }
    (data, run)
}

/// A `--config` of the finished run with `epochs` per stage: a run whose second stage is
/// long, to interrupt it there.
fn config_with(f: &Fixture, done: &Path, epochs: [u64; 2]) -> PathBuf {
    let mut config = json_file(&done.join("config.json"));
    for (i, e) in epochs.iter().enumerate() {
        config["stages"][i]["config"]["schedule"]["epochs"] = (*e).into();
    }
    let path = f.t.join(format!("recipe_{}_{}.json", epochs[0], epochs[1]));
    std::fs::write(&path, serde_json::to_string_pretty(&config).unwrap()).unwrap();
    path
}

/// The resumed run is whole: every stage's log counts its epochs in order, the teacher's
/// `teacher` long (None: any), and the run's final weights are the last stage's.
fn whole(run: &Path, teacher: Option<usize>) -> Box<dyn Fn() -> bool> {
    let run = run.to_path_buf();
    Box::new(move || {
        let logs: Vec<Option<usize>> = STAGES
            .iter()
            .map(|st| epochs_in_order(&run.join(st).join("log.jsonl")))
            .collect();
        let last = std::fs::read(run.join("v3/final.safetensors")).ok();
        logs.iter().all(|n| n.is_some_and(|n| n >= 1))
            && teacher.is_none_or(|t| logs[0] == Some(t))
            && last.is_some()
            && std::fs::read(run.join("final.safetensors")).ok() == last
    })
}

/// How a run is stopped: the signal, once `ready` exists; the stage it stops in.
struct Stop {
    signal: i32,
    ready: PathBuf,
    stage: &'static str,
}

/// `stop.signal` sent to `args` once `stop.ready`, then the resume to one epoch more than
/// the stopped stage holds; SIGTERM's exit is a case itself.
fn stop_and_resume(
    name: &str,
    args: Vec<String>,
    stop: Stop,
    run: &Path,
    teacher: Option<usize>,
) -> Vec<Case> {
    let Stop {
        signal,
        ready,
        stage,
    } = stop;
    let (log_run, stage_log) = (run.to_path_buf(), run.join(stage).join("log.jsonl"));
    let resume = move || resume_one_more(&log_run, &stage_log);
    let check = whole(run, teacher);
    let title = format!("recipe: resume after {name}");
    if signal == libc::SIGKILL {
        let before = move || drop(signal_when(&args, || ready.exists(), libc::SIGKILL));
        return vec![recovers(&title, &[], &[], check)
            .before(before)
            .runner(resume)];
    }
    let stopped = case(
        &format!("recipe: {name}"),
        &[],
        &["interrupted (stage", "--resume"],
    );
    let mut stopped = stopped.runner(move || signal_when(&args, || ready.exists(), libc::SIGTERM));
    stopped.expect = Some(130);
    vec![stopped, recovers(&title, &[], &[], check).runner(resume)]
}

/// SIGTERM and kill -9 in stage 1, in stage 2, and as stage 1 ends.
fn interruptions(f: &Fixture, data: &Path, done: &Path) -> Vec<Case> {
    let mut cases = Vec::new();
    let long_second = config_with(f, done, [1, 300]);
    for (signal, sig) in [(libc::SIGTERM, "SIGTERM"), (libc::SIGKILL, "kill -9")] {
        let run = f.t.join(format!("recipe_s1_{signal}"));
        let args = recipe_args(data, &run, "heatnet-v3", "300");
        let ready = run.join("teacher-rgb/checkpoint.safetensors");
        let stop = Stop {
            signal,
            ready,
            stage: "teacher-rgb",
        };
        cases.extend(stop_and_resume(
            &format!("{sig} in stage 1"),
            args,
            stop,
            &run,
            None,
        ));
        for (at, ready_file) in [
            ("in stage 2", "v3/checkpoint.safetensors"),
            ("as stage 1 ends", "teacher-rgb/final.safetensors"),
        ] {
            let run = f.t.join(format!("recipe_s2_{signal}_{}", at.len()));
            let args = strings(&["train", "--config", s(&long_second), "--out", s(&run)]);
            let stop = Stop {
                signal,
                ready: run.join(ready_file),
                stage: "v3",
            };
            cases.extend(stop_and_resume(
                &format!("{sig} {at}"),
                args,
                stop,
                &run,
                Some(1),
            ));
        }
    }
    cases
}

/// The finished run: resumed as it is, extended, shortened, restarted without --resume.
fn finished(data: &Path, done: &Path) -> Vec<Case> {
    let d = s(done);
    let check = whole(done, Some(1));
    let extended = done.to_path_buf();
    vec![
        recovers(
            "recipe: finished, resumed (nothing to do)",
            &["train", "--resume", d],
            &["nothing to do"],
            check,
        ),
        recovers(
            "recipe: finished, extended to 2 epochs",
            &["train", "--resume", d, "--epochs", "2"],
            &["final.safetensors"],
            Box::new(move || {
                epochs_in_order(&extended.join("v3/log.jsonl")) == Some(2)
                    && whole(&extended, Some(1))()
            }),
        ),
        case(
            "recipe: extended run shortened to 1 epoch",
            &["train", "--resume", d, "--epochs", "1"],
            &["--epochs 1", "v3"],
        ),
        case(
            "recipe: same folder again without --resume",
            &recipe_args(data, done, "heatnet-v3", "1")
                .iter()
                .map(String::as_str)
                .collect::<Vec<_>>(),
            &["--resume", d],
        ),
        case(
            "recipe: resume of a missing folder",
            &["train", "--resume", s(&done.with_file_name("nowhere"))],
            &["nowhere"],
        ),
    ]
}

pub fn cases(f: &Fixture) -> Vec<Case> {
    let (data, done) = base(f);
    let mut cases = interruptions(f, &data, &done);
    cases.extend(finished(&data, &done));
    cases
}

/// A copy of the finished run changed by `mutate` (at the time the case runs).
fn altered(f: &Fixture, name: &str, mutate: impl Fn(&Path) + 'static) -> (PathBuf, impl Fn()) {
    let (_, done) = base(f);
    let run = f.t.join(name);
    let to = run.clone();
    (run, move || {
        copy_dir(&done, &to);
        mutate(&to);
    })
}

/// Stage folders deleted, corrupt, or taken from another recipe's run.
pub fn stage_folders(f: &Fixture) -> Vec<Case> {
    let (data, _) = base(f);
    let other = f.t.join("recipe_v2");
    ok(&recipe_args(&data, &other, "heatnet-v2", "1")
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>());
    let from_other = other.join("v2");
    // (case, stage, how the folder is changed, what the error says)
    type Variant<'a> = (&'a str, &'a str, Box<dyn Fn(&Path)>, Vec<&'a str>);
    let variants: Vec<Variant> = vec![
        (
            "stage folder of the teacher deleted",
            "rs_noteacher",
            Box::new(|r: &Path| std::fs::remove_dir_all(r.join("teacher-rgb")).unwrap()),
            vec!["teacher-rgb"],
        ),
        (
            "stage folder from another recipe",
            "rs_foreign",
            Box::new(move |r: &Path| {
                std::fs::remove_dir_all(r.join("v3")).unwrap();
                copy_dir(&from_other, &r.join("v3"));
            }),
            vec!["v3"],
        ),
        (
            "stage config.json corrupt",
            "rs_corrupt",
            Box::new(|r: &Path| std::fs::write(r.join("v3/config.json"), b"{\"model\": ").unwrap()),
            vec!["v3/config.json"],
        ),
        (
            "run config.json deleted",
            "rs_noconfig",
            Box::new(|r: &Path| std::fs::remove_file(r.join("config.json")).unwrap()),
            vec!["config.json"],
        ),
    ];
    let mut cases = Vec::new();
    for (name, folder, mutate, must) in variants {
        let (run, prepare) = altered(f, folder, mutate);
        // Three epochs: the last stage (finished at 2) must read its folder to go on.
        let args = ["train", "--resume", s(&run), "--epochs", "3"];
        cases.push(case(&format!("recipe: {name}, resumed"), &args, &must).before(prepare));
    }
    let (run, prepare) = altered(f, "rs_nolast", |r| {
        std::fs::remove_dir_all(r.join("v3")).unwrap()
    });
    let check = whole(&run, Some(1));
    cases.push(
        recovers(
            "recipe: last stage folder deleted, resumed (retrains it)",
            &["train", "--resume", s(&run)],
            &["final.safetensors"],
            check,
        )
        .before(prepare),
    );
    cases
}
