//! rtf-report: `rtf report RUN… [--eval SCORES.json…] --out report.html` as a library: one
//! self-contained HTML page (every image embedded as a `data:` URI) summarising training runs
//! and evaluations.
//!
//! The page leads with the answer (issue #30). Per run (and per stage of a multi-stage run,
//! `RUN/<stage>/`): a headline (final and best validation mIoU with their epochs, mAcc, day,
//! night), the last validation's per-class IoU as bars by class name, the training curves (each
//! loss term, learning rates, validation mIoU / mAcc, day and night), and the configuration
//! last, collapsed. Several runs: first a table of final and best metrics, the curves overlaid
//! and only the configuration settings that differ. Per `rtf eval --json` file: the scores
//! (all / day / night, missing-modality rows), per-class IoU bars (day / night) and the
//! confusion matrix as a heat map (rows = truth, normalised per row). With weights in the run
//! folders and a dataset (`--data`, else the first run's validation split), a prediction grid:
//! RGB | thermal | truth | each run's prediction, column titles and class legend
//! ([`rtf_eval::figure::annotated_grid`]).
//!
//! Run folders are read through the one run-folder type (rtf-run's `RunFolder`, and its view
//! of a training's configuration): their epochs as typed records of either log schema, their
//! configuration read where the page uses it (network, dataset, inputs, resize) and shown as
//! the settings `config.json` records. rtf-train is not a dependency: a report needs no
//! training code. Charts are drawn with `plotters` (SVG backend: text is
//! laid out by the browser, no font files needed); the grid is a PNG.
//!
//! Layers: `lib` (the page) → `runs`, `evals`, `sections`, `compare`, `grid` → `charts`,
//! `series`, `html`, `error`.

mod charts;
mod compare;
mod error;
mod evals;
mod grid;
mod html;
mod runs;
mod sections;
mod series;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

pub use error::ReportError;

use evals::EvalFile;
use runs::Run;

/// What a report shows, and how (the flags of `rtf report`).
#[derive(Debug, Clone)]
pub struct ReportOptions {
    /// Run folders (written by `rtf train`).
    pub runs: Vec<PathBuf>,
    /// Score files written by `rtf eval --json`.
    pub evals: Vec<PathBuf>,
    /// Dataset root for the prediction grid (None: the first run's dataset, if present).
    pub data: Option<PathBuf>,
    /// Split of `data` for the prediction grid.
    pub split: String,
    /// Frames in the prediction grid (0: no grid).
    pub frames: usize,
    /// Where the grid's networks run ("cpu", "cuda", "cuda:N").
    pub device: String,
}

/// A report's page and what its making has to say (why there is no prediction grid, how a
/// dataset was read, a configuration shown only as recorded), one line each.
#[derive(Debug, Clone)]
pub struct Report {
    pub html: String,
    pub notes: Vec<String>,
}

const STYLE: &str = "body{font-family:sans-serif;margin:24px;color:#222;max-width:1300px}
h1{margin-bottom:4px}h2{border-bottom:1px solid #ccc;padding-bottom:4px}
table{border-collapse:collapse;margin:8px 0}td,th{border:1px solid #ddd;padding:3px 8px;text-align:right}
th{background:#f4f4f4;text-align:left}table.config td{text-align:left;font-family:monospace}
.charts img{margin:6px;border:1px solid #eee;vertical-align:top}.path{color:#777;font-family:monospace}
img.grid{max-width:100%;border:1px solid #eee}
.headline{display:flex;flex-wrap:wrap;gap:12px;margin:8px 0 12px}
.headline .figure{border:1px solid #ddd;border-radius:6px;padding:8px 16px;min-width:120px}
.headline .value{display:block;font-size:30px;font-weight:bold}.headline .label{color:#555}
table.config-diff td{text-align:left;font-family:monospace}details.config{margin:8px 0}";

/// The runs (each stage of a multi-stage run its own) and eval files of `options`, read.
fn inputs(
    options: &ReportOptions,
    notes: &mut Vec<String>,
) -> Result<(Vec<Run>, Vec<EvalFile>), ReportError> {
    let mut runs = Vec::new();
    for dir in &options.runs {
        runs.extend(runs::load_runs(dir, notes)?);
    }
    let evals = options
        .evals
        .iter()
        .map(|p| evals::load_eval(p))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((runs, evals))
}

/// The report of `options`.
pub fn build(options: &ReportOptions) -> Result<Report, ReportError> {
    let mut notes = Vec::new();
    let (runs, evals) = inputs(options, &mut notes)?;
    let html = page(options, &runs, &evals, &mut notes)?;
    Ok(Report { html, notes })
}

/// The report of `options` written to `out` (atomically); a `--out` that names a file the
/// report reads (a run's config.json or log.jsonl, an eval file; also through `..` or a
/// link) is refused before anything is written. Returns the notes.
pub fn write(options: &ReportOptions, out: &Path) -> Result<Vec<String>, ReportError> {
    let mut notes = Vec::new();
    let (runs, evals) = inputs(options, &mut notes)?;
    refuse_overwriting_inputs(out, &runs, &options.evals)?;
    let html = page(options, &runs, &evals, &mut notes)?;
    rtf_core::write_bytes_atomic(out, html.as_bytes()).map_err(|e| ReportError::Write {
        path: out.to_path_buf(),
        message: e.to_string(),
    })?;
    Ok(notes)
}

fn refuse_overwriting_inputs(
    out: &Path,
    runs: &[Run],
    evals: &[PathBuf],
) -> Result<(), ReportError> {
    // Resolved through the folders --out would create (`run/new/../log.jsonl` is the log).
    let out_path = rtf_core::resolved(out);
    for input in runs::inputs(runs).chain(evals.iter().cloned()) {
        if rtf_core::resolved(&input) == out_path {
            return Err(ReportError::Overwrite {
                out: out.to_path_buf(),
                input,
            });
        }
    }
    Ok(())
}

/// The page: header, the comparison (several runs), each run, each evaluation, the grid.
fn page(
    options: &ReportOptions,
    runs: &[Run],
    evals: &[EvalFile],
    notes: &mut Vec<String>,
) -> Result<String, ReportError> {
    let mut html = String::new();
    writeln!(html, "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>rtf report</title><style>{STYLE}</style></head><body>")?;
    writeln!(
        html,
        "<h1>rtf report</h1><p>{} run(s){}, written by rtf {}.</p>",
        runs.len(),
        if evals.is_empty() {
            String::new()
        } else {
            format!(", {} evaluation(s)", evals.len())
        },
        env!("CARGO_PKG_VERSION")
    )?;
    let comparing = runs.len() > 1;
    if comparing {
        compare::compare_section(runs, &mut html)?;
    }
    for run in runs {
        // Comparing: the differences above stand for the configurations.
        sections::run_section(run, !comparing, &mut html)?;
    }
    for eval in evals {
        evals::eval_section(eval, &mut html)?;
    }
    grid_section(options, runs, notes, &mut html)?;
    writeln!(html, "</body></html>")?;
    Ok(html)
}

/// The prediction grid's section, or why there is none.
fn grid_section(
    options: &ReportOptions,
    runs: &[Run],
    notes: &mut Vec<String>,
    html: &mut String,
) -> Result<(), ReportError> {
    match grid::prediction_grid(options, runs, notes) {
        Ok(Some(png)) => writeln!(
            html,
            "<section><h2>Predictions</h2>{}</section>",
            html::img("image/png", &png, "prediction grid")
                .replace("<img ", "<img class=\"grid\" ")
        )?,
        Ok(None) => {}
        Err(why) => {
            notes.push(format!("report: no prediction grid: {why}"));
            writeln!(
                html,
                "<section><h2>Predictions</h2><p>No prediction grid: {}</p></section>",
                html::esc(&why)
            )?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Randomised run (`rtf_data::fuzzing`): seeded mutations of a run's `log.jsonl` and
    /// `config.json` and random bytes; the run loads and its section renders, or an error
    /// names the file; never a panic.
    #[test]
    fn mutated_logs_and_configs_never_panic() {
        let dir = tempfile::tempdir().unwrap();
        let record = |epoch: usize, miou: f64| {
            serde_json::json!({"epoch": epoch, "lr": 0.01, "train_loss": 2.0 - miou,
                "images": 16, "seconds": 2.0, "images_per_s": 8.0, "data_wait_fraction": 0.1,
                "val_miou": miou, "val_macc": miou + 0.1,
                "losses": {"ce": 1.5}, "lrs": {"student": 0.01}, "metrics": {},
                "val": {"miou": miou, "macc": miou + 0.1, "miou_day": miou, "miou_night": null,
                        "per_class_iou": {"car": miou, "person": 0.5, "bike": null},
                        "per_class_iou_day": {"car": miou, "person": 0.5, "bike": null},
                        "selected_by": "miou", "selected": miou}})
            .to_string()
        };
        let log: String = (0..4).map(|e| record(e, 0.1 * e as f64) + "\n").collect();
        let config =
            serde_json::to_string(&rtf_train::TrainConfig::mfnet_paper("data".into())).unwrap();
        std::fs::write(dir.path().join("config.json"), &config).unwrap();
        let render = || {
            let mut notes = Vec::new();
            let runs = runs::load_runs(dir.path(), &mut notes)?;
            let mut html = String::new();
            for run in &runs {
                sections::run_section(run, true, &mut html)?;
            }
            Ok::<_, ReportError>(html.len())
        };
        let log_path = dir.path().join("log.jsonl");
        let outcome =
            rtf_data::fuzzing::check_reader("log.jsonl", log.as_bytes(), 21, 150, "", |b| {
                std::fs::write(&log_path, b).unwrap();
                render()
            });
        assert!(outcome.refused > 20, "{outcome:?}");
        std::fs::write(&log_path, &log).unwrap();
        let config_path = dir.path().join("config.json");
        let outcome =
            rtf_data::fuzzing::check_reader("config.json", config.as_bytes(), 22, 150, "", |b| {
                std::fs::write(&config_path, b).unwrap();
                render()
            });
        assert!(outcome.refused > 20, "{outcome:?}");
    }
}
