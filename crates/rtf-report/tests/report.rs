//! The report library on run folders of every format rtf has written (today's sections and
//! log, the flat config and first log schema of the early builds, a multi-stage recipe), an
//! eval file, several runs compared; bad input is an error naming the file, and `write`
//! never overwrites what the report reads.

use std::path::{Path, PathBuf};

use rtf_report::{build, write, ReportError, ReportOptions};
use rtf_train::config::RunConfig;
use rtf_train::TrainConfig;

const FLAT_SINGLE: &str = include_str!("../../rtf-config/tests/fixtures/flat_single_config.json");
const FLAT_RECIPE: &str = include_str!("../../rtf-config/tests/fixtures/flat_recipe_config.json");
const FLAT_STAGE: &str =
    include_str!("../../rtf-config/tests/fixtures/flat_recipe_stage_config.json");

fn options(runs: &[&Path]) -> ReportOptions {
    ReportOptions {
        runs: runs.iter().map(|p| p.to_path_buf()).collect(),
        evals: Vec::new(),
        data: None,
        split: "test".into(),
        frames: 0,
        device: "cpu".into(),
    }
}

/// A log line of today's schema for `epoch` (validation mIoU 0.2 + 0.05 epoch).
fn todays_line(epoch: usize) -> String {
    serde_json::json!({
        "epoch": epoch, "lr": 0.01, "train_loss": 1.0 / (epoch + 1) as f64, "images": 8,
        "seconds": 1.0, "images_per_s": 8.0, "data_wait_fraction": 0.1,
        "val_miou": 0.2 + 0.05 * epoch as f64, "val_macc": 0.3,
        "losses": {"ce": 0.8 / (epoch + 1) as f64}, "lrs": {"student": 0.01}, "metrics": {},
        "val": {"miou": 0.2 + 0.05 * epoch as f64, "macc": 0.3, "miou_day": 0.25,
                "miou_night": 0.15, "selected_by": "miou", "selected": 0.2,
                "per_class_iou": {"unlabeled": 0.9, "car": 0.3, "person": null},
                "per_class_iou_day": {"unlabeled": 0.9, "car": 0.35, "person": null},
                "per_class_iou_night": {"unlabeled": 0.88, "car": 0.25, "person": 0.1}}
    })
    .to_string()
}

/// A log line of the first builds (flat fields only).
fn first_schema_line(epoch: usize) -> String {
    format!(
        r#"{{"epoch":{epoch},"lr":0.01,"train_loss":2.0,"images":4,"seconds":1.5,"images_per_s":2.5,"data_wait_fraction":0.1,"val_miou":0.125,"val_macc":0.5}}"#
    )
}

fn write_run(dir: &Path, config: &str, lines: &[String]) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("config.json"), config).unwrap();
    std::fs::write(dir.join("log.jsonl"), lines.join("\n") + "\n").unwrap();
    dir.to_path_buf()
}

fn config_of(network: &str) -> String {
    let mut cfg = TrainConfig::mfnet_paper("/nowhere/data".into());
    cfg.network.model = rtf_models::ModelConfig::from_name(network, 9).unwrap();
    serde_json::to_string_pretty(&cfg).unwrap()
}

fn section<'a>(html: &'a str, start: &str) -> &'a str {
    let from = html
        .find(start)
        .unwrap_or_else(|| panic!("{start} in the page"));
    let rest = &html[from..];
    &rest[..rest.find("</table>").unwrap_or(rest.len())]
}

#[test]
fn a_run_of_today_leads_with_the_answer_and_records_its_settings() {
    let tmp = tempfile::tempdir().unwrap();
    let lines: Vec<String> = (0..5).map(todays_line).collect();
    let run = write_run(&tmp.path().join("today"), &config_of("mfnet"), &lines);
    let report = build(&options(&[&run])).unwrap();
    let html = &report.html;
    assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    assert!(html.contains("<h2>Run today</h2>"));
    let headline = section(html, "class=\"headline\"");
    for figure in [
        "40.0",
        "final mIoU (epoch 4)",
        "best mIoU (epoch 4)",
        "mIoU night",
    ] {
        assert!(headline.contains(figure), "{figure} in {headline}");
    }
    // The settings config.json records, collapsed, under their section names.
    assert!(html.contains("<details class=\"config\">"));
    assert!(html.contains("<th>network.model.network</th><td>&quot;mfnet&quot;</td>"));
    assert!(html.contains("<th>schedule.batch_size</th>"));
    assert!(report.notes.is_empty(), "{:?}", report.notes);
    // No grid asked for: no section.
    assert!(!html.contains("<h2>Predictions</h2>"));
}

/// The early builds' folders (flat config.json, first log schema) and a multi-stage recipe
/// folder of that layout: every stage is a run of the page, their settings as recorded.
#[test]
fn folders_of_the_early_builds_and_multi_stage_recipes_report() {
    let tmp = tempfile::tempdir().unwrap();
    let lines: Vec<String> = (0..3).map(first_schema_line).collect();
    let flat = write_run(&tmp.path().join("flat"), FLAT_SINGLE, &lines);
    let recipe = tmp.path().join("recipe");
    std::fs::create_dir_all(&recipe).unwrap();
    std::fs::write(recipe.join("config.json"), FLAT_RECIPE).unwrap();
    let RunConfig::Pipeline(p) = RunConfig::parse(FLAT_RECIPE, false).unwrap() else {
        panic!("a pipeline")
    };
    let teacher = serde_json::to_string(&p.stages[0].config).unwrap();
    write_run(&recipe.join("teacher-rgb"), &teacher, &lines);
    write_run(&recipe.join("v3"), FLAT_STAGE, &[todays_line(0)]);
    let report = build(&options(&[&flat, &recipe])).unwrap();
    let html = &report.html;
    for heading in [
        "<h2>Run flat</h2>",
        "<h2>Run recipe / teacher-rgb</h2>",
        "<h2>Run recipe / v3</h2>",
    ] {
        assert!(html.contains(heading), "{heading}");
    }
    // A header row, then one row per run or stage, each naming its network.
    let table = section(html, "<table class=\"compare\">");
    assert_eq!(table.matches("<tr><th>").count(), 1 + 3);
    assert_eq!(table.matches("<td>mfnet</td>").count(), 3, "{table}");
    // The flat layout's settings and the sections' differ by name: both are listed.
    let diff = section(html, "<table class=\"config-diff\">");
    assert!(diff.contains("<th>batch_size</th>") && diff.contains("<th>schedule.batch_size</th>"));
    assert!(report.notes.is_empty(), "{:?}", report.notes);
}

#[test]
fn several_runs_compare_and_an_eval_file_shows_its_scores() {
    let tmp = tempfile::tempdir().unwrap();
    let lines: Vec<String> = (0..3).map(todays_line).collect();
    let a = write_run(&tmp.path().join("run-a"), &config_of("mfnet"), &lines);
    let b = write_run(
        &tmp.path().join("run-b"),
        &config_of("rtfnet50"),
        &lines[..2],
    );
    let scores = tmp.path().join("scores.json");
    let eval = serde_json::json!({"schema": "rtf-eval/1", "model": "mfnet", "data": "d",
        "split": "test", "frames": 2, "miou": 0.5, "macc": 0.6,
        "per_class": [{"name": "a", "iou": 0.5}, {"name": "b", "iou": null}],
        "class_names": ["a", "b"], "confusion": [[3, 1], [0, 4]]});
    std::fs::write(&scores, eval.to_string()).unwrap();
    let mut opts = options(&[&a, &b]);
    opts.evals.push(scores);
    let html = build(&opts).unwrap().html;
    let table = section(&html, "<table class=\"compare\">");
    for cell in [
        "<th>run-a</th>",
        "<td>mfnet</td>",
        "<td>rtfnet</td>",
        "<td>30.0</td>",
    ] {
        assert!(table.contains(cell), "{cell} in {table}");
    }
    let diff = section(&html, "<table class=\"config-diff\">");
    assert!(diff.contains("<th>network.model.network</th>") && !diff.contains("batch_size"));
    assert!(html.contains("<h2>Evaluation scores.json</h2>"));
    assert!(html.contains("whole image, scale 1 (not recorded)"));
}

#[test]
fn bad_input_names_the_file_and_nothing_read_is_overwritten() {
    let tmp = tempfile::tempdir().unwrap();
    let run = write_run(
        &tmp.path().join("run"),
        &config_of("mfnet"),
        &[todays_line(0)],
    );
    let err = |o: &ReportOptions| build(o).unwrap_err().to_string();
    std::fs::write(
        run.join("log.jsonl"),
        todays_line(0).replace("\"epoch\"", "\"epoch_index\""),
    )
    .unwrap();
    let e = err(&options(&[&run]));
    assert!(e.contains("log.jsonl:1") && e.contains("`epoch`"), "{e}");
    std::fs::write(run.join("log.jsonl"), todays_line(0) + "\n").unwrap();
    let e = err(&options(&[&tmp.path().join("gone")]));
    assert!(e.contains("gone") && e.contains("no such directory"), "{e}");
    std::fs::create_dir_all(tmp.path().join("empty")).unwrap();
    let e = err(&options(&[&tmp.path().join("empty")]));
    assert!(e.contains("log.jsonl is missing"), "{e}");
    let mut with_eval = options(&[&run]);
    let other = tmp.path().join("other.json");
    std::fs::write(&other, r#"{"schema": "something-else/3"}"#).unwrap();
    with_eval.evals.push(other);
    let e = err(&with_eval);
    assert!(
        e.contains("other.json") && e.contains("something-else/3"),
        "{e}"
    );

    let log = run.join("log.jsonl");
    let before = std::fs::read(&log).unwrap();
    let refused = write(&options(&[&run]), &run.join("../run/log.jsonl"));
    assert!(
        matches!(refused, Err(ReportError::Overwrite { .. })),
        "{refused:?}"
    );
    assert_eq!(std::fs::read(&log).unwrap(), before);
    // Through a folder the atomic write would create: still the log.
    let through_missing = run.join("new-dir/../log.jsonl");
    let refused = write(&options(&[&run]), &through_missing);
    assert!(
        matches!(refused, Err(ReportError::Overwrite { .. })),
        "{refused:?}"
    );
    assert_eq!(std::fs::read(&log).unwrap(), before);
    let out = tmp.path().join("report.html");
    let mut grid = options(&[&run]);
    grid.frames = 2;
    let notes = write(&grid, &out).unwrap();
    assert_eq!(
        notes,
        ["report: no prediction grid: no run folder holds final.safetensors or best.safetensors"]
    );
    assert!(std::fs::read_to_string(&out)
        .unwrap()
        .contains("No prediction grid"));
}

/// A config.json this build does not read (a later version's field): the run still reports,
/// its settings shown as recorded, and a note says why the network is unknown.
#[test]
fn a_configuration_of_another_version_is_shown_as_recorded() {
    let tmp = tempfile::tempdir().unwrap();
    let mut config: serde_json::Value = serde_json::from_str(&config_of("mfnet")).unwrap();
    config["a_field_from_the_future"] = serde_json::json!({"x": 1});
    let run = write_run(
        &tmp.path().join("future"),
        &config.to_string(),
        &[todays_line(0)],
    );
    let report = build(&options(&[&run])).unwrap();
    assert!(report
        .html
        .contains("<th>a_field_from_the_future.x</th><td>1</td>"));
    assert_eq!(report.notes.len(), 1);
    assert!(
        report.notes[0].contains("config.json")
            && report.notes[0].contains("a_field_from_the_future")
    );
}
