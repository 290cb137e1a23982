//! `rtf eval --drop` on networks that see one modality, and `--precision` across a resume
//! (a bf16 run continued in fp32 and the reverse).

use std::path::PathBuf;

use crate::common::*;
use crate::verdict::{
    case, epochs_in_order, interrupted, long_train, recovers, resume_one_more, Case,
};
use crate::Fixture;

/// A one-step run seeing only `inputs` (rgb or thermal); its final weights.
fn single_modality(f: &Fixture, inputs: &str) -> PathBuf {
    let run = f.t.join(format!("only_{inputs}"));
    ok(&short_train(
        &f.data,
        &run,
        "1",
        &["--val-split", "none", "--inputs", inputs],
    ));
    run.join("final.safetensors")
}

fn drop_cases(f: &Fixture) -> Vec<Case> {
    let mut cases = Vec::new();
    for inputs in ["rgb", "thermal"] {
        let weights = single_modality(f, inputs);
        for dropped in ["rgb", "thermal"] {
            let args = [
                "eval",
                "--weights",
                s(&weights),
                "--data",
                s(&f.data),
                "--drop",
                dropped,
            ];
            // The scores are right (the network with that modality missing); the note says
            // what they mean for a network that sees one modality.
            let name = format!("drop: --drop {dropped} on a {inputs}-only network (a note)");
            let note = format!("note: --drop {dropped}: the network sees only {inputs}");
            cases.push(recovers(&name, &args, &[&note, "mIoU"], Box::new(|| true)));
        }
    }
    cases
}

fn precision_cases(f: &Fixture) -> Vec<Case> {
    let mut cases = Vec::new();
    for (trained, asked) in [("bf16", "fp32"), ("fp32", "bf16")] {
        let run = f.t.join(format!("prec_{trained}"));
        let log = run.join("log.jsonl");
        let args = long_train(&f.data, &run, &["--precision", trained]);
        let ready = log.clone();
        cases.push(interrupted(
            &format!("precision: a {trained} run stopped by SIGTERM"),
            args,
            ready,
            &["interrupted", "--resume"],
        ));
        let flag = ["train", "--resume", s(&run), "--precision", asked];
        cases.push(case(
            &format!("precision: {trained} run resumed with --precision {asked}"),
            &flag,
            &["--precision", "--resume"],
        ));
        let (config, log2, run2) = (run.join("config.json"), log.clone(), run.clone());
        let keep = trained.to_string();
        cases.push(
            recovers(
                &format!("precision: {trained} run resumed (keeps {trained})"),
                &[],
                &[],
                Box::new(move || {
                    let config = json_file(&config);
                    config["learning"]["precision"].as_str().unwrap_or("fp32") == keep
                        && epochs_in_order(&log2).is_some_and(|n| n >= 2)
                }),
            )
            .runner(move || resume_one_more(&run2, &log)),
        );
    }
    let run = f.t.join("prec_fp16");
    let args = short_train(&f.data, &run, "1", &["--precision", "fp16"]);
    cases.push(case("precision: fp16 on a CPU", &args, &["fp16", "CUDA"]));
    cases
}

pub fn cases(f: &Fixture) -> Vec<Case> {
    let mut all = drop_cases(f);
    all.extend(precision_cases(f));
    all
}
