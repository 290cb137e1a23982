//! The `rtf eval --json` files a report shows (not run folders: what `rtf eval` wrote): the
//! scores (all / day / night, missing-modality rows), per-class IoU bars and the confusion
//! matrix as a heat map. Files of the versions before the schema tag read too.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use rtf_eval::EVAL_SCHEMA;
use serde_json::Value;

use crate::charts::{class_bars, heat_map};
use crate::error::ReportError;
use crate::html::{esc, pct, svg_img};
use crate::series::ClassRow;

type Result<T> = std::result::Result<T, ReportError>;

/// An `rtf eval --json` file.
pub(crate) struct EvalFile {
    pub path: PathBuf,
    json: Value,
}

fn read_json(path: &Path) -> Result<Value> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| ReportError::input(path, format!("cannot read: {e}")))?;
    serde_json::from_str(&text)
        .map_err(|e| ReportError::input(path, format!("not valid JSON: {e}")))
}

pub(crate) fn load_eval(path: &Path) -> Result<EvalFile> {
    let json = read_json(path)?;
    let schema = json.get("schema").and_then(Value::as_str);
    let legacy = schema.is_none()
        && json.get("per_class").is_some_and(Value::is_array)
        && json.get("miou").is_some_and(Value::is_number);
    if schema != Some(EVAL_SCHEMA) && !legacy {
        let schema = schema.map_or("missing".to_string(), |s| format!("`{s}`"));
        return Err(ReportError::input(
            path,
            format!(
                "not an `rtf eval --json` score file (schema {schema}, expected `{EVAL_SCHEMA}`)"
            ),
        ));
    }
    Ok(EvalFile {
        path: path.to_path_buf(),
        json,
    })
}

fn scores_row(label: &str, s: &Value) -> String {
    let get = |k: &str| s.get(k).and_then(Value::as_f64);
    let day = s.get("day").filter(|d| !d.is_null());
    let night = s.get("night").filter(|d| !d.is_null());
    let miou = |d: Option<&Value>| d.and_then(|d| d.get("miou")).and_then(Value::as_f64);
    format!(
        "<tr><th>{}</th><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
        esc(label),
        pct(get("miou")),
        pct(get("macc")),
        pct(miou(day)),
        pct(miou(night))
    )
}

fn class_iou(scores: Option<&Value>) -> BTreeMap<String, Option<f64>> {
    scores
        .and_then(|s| s.get("per_class"))
        .and_then(Value::as_array)
        .map(|a| {
            a.iter()
                .filter_map(|c| {
                    Some((
                        c.get("name")?.as_str()?.to_string(),
                        c.get("iou").and_then(Value::as_f64),
                    ))
                })
                .collect()
        })
        .unwrap_or_default()
}

pub(crate) fn eval_section(eval: &EvalFile, html: &mut String) -> Result<()> {
    let j = &eval.json;
    let s = |k: &str| j.get(k).and_then(Value::as_str).unwrap_or("?").to_string();
    writeln!(
        html,
        "<section class=\"eval\"><h2>Evaluation {}</h2><p>{} on <code>{}</code> split <code>{}</code>, {} frames; inference: {}</p>",
        esc(&eval.path.file_name().unwrap_or_default().to_string_lossy()),
        esc(&s("model")),
        esc(&s("data")),
        esc(&s("split")),
        j.get("frames").and_then(Value::as_u64).unwrap_or(0),
        esc(&inference_of(j))
    )?;
    writeln!(html, "<table class=\"scores\"><tr><th></th><th>mIoU</th><th>mAcc</th><th>mIoU day</th><th>mIoU night</th></tr>")?;
    writeln!(html, "{}", scores_row("all modalities", j))?;
    for d in j
        .get("dropped")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
    {
        let label = format!(
            "{} missing ({} fill)",
            d.get("modality").and_then(Value::as_str).unwrap_or("?"),
            d.get("fill").and_then(Value::as_str).unwrap_or("?")
        );
        writeln!(html, "{}", scores_row(&label, d))?;
    }
    writeln!(html, "</table><div class=\"charts\">")?;
    let (rows, labels) = class_rows(j);
    if !rows.is_empty() {
        let svg = class_bars("Per-class IoU, %", &rows, labels)?;
        writeln!(html, "{}", svg_img(&svg, "per-class IoU bars"))?;
    }
    if let (Some(names), Some(matrix)) = (j.get("class_names"), j.get("confusion")) {
        let (names, matrix) = confusion(&eval.path, names, matrix)?;
        let svg = heat_map("Confusion matrix", &names, &matrix)?;
        writeln!(html, "{}", svg_img(&svg, "confusion matrix heat map"))?;
    }
    writeln!(html, "</div></section>")?;
    Ok(())
}

/// How an eval file's network was run (`inference`: mode, scales, flip); files written before
/// the modes existed ran the whole image at scale 1.
fn inference_of(j: &Value) -> String {
    match j.get("inference") {
        None => "whole image, scale 1 (not recorded)".into(),
        Some(v) => serde_json::from_value::<rtf_eval::InferenceOptions>(v.clone())
            .map_or_else(|_| format!("unreadable record {v}"), |o| o.describe()),
    }
}

/// Per-class IoU rows of an eval file (day and night where it has them, else all frames)
/// and the two bar labels.
fn class_rows(j: &Value) -> (Vec<ClassRow>, [&'static str; 2]) {
    let all = class_iou(Some(j));
    let day = class_iou(j.get("day"));
    let night = class_iou(j.get("night"));
    let names: Vec<String> = j
        .get("per_class")
        .and_then(Value::as_array)
        .map(|a| {
            a.iter()
                .filter_map(|c| c.get("name")?.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default();
    if day.is_empty() && night.is_empty() {
        let rows = names
            .iter()
            .map(|n| (n.clone(), all.get(n).copied().flatten(), None))
            .collect();
        return (rows, ["all", ""]);
    }
    let rows = names
        .iter()
        .map(|n| {
            (
                n.clone(),
                day.get(n).copied().flatten(),
                night.get(n).copied().flatten(),
            )
        })
        .collect();
    (rows, ["day", "night"])
}

/// The eval file's class names and confusion counts, checked to be a square matrix of
/// their size (errors name the file).
fn confusion(path: &Path, names: &Value, matrix: &Value) -> Result<(Vec<String>, Vec<Vec<u64>>)> {
    let names: Vec<String> = serde_json::from_value(names.clone()).map_err(|e| {
        ReportError::input(path, format!("`class_names` is not a list of names: {e}"))
    })?;
    let matrix: Vec<Vec<u64>> = serde_json::from_value(matrix.clone()).map_err(|e| {
        ReportError::input(path, format!("`confusion` is not a matrix of counts: {e}"))
    })?;
    if matrix.len() != names.len() || matrix.iter().any(|r| r.len() != names.len()) {
        let n = names.len();
        return Err(ReportError::input(
            path,
            format!("`confusion` is not {n}×{n} like `class_names`"),
        ));
    }
    Ok((names, matrix))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eval_files_name_their_inference_mode() {
        let old = serde_json::json!({"schema": "rtf-eval/1"});
        assert_eq!(inference_of(&old), "whole image, scale 1 (not recorded)");
        let sliding = serde_json::json!({"inference": {"mode": "sliding", "crop": [480, 640],
            "stride_rate": 0.5, "scales": [0.75, 1.0], "flip": true}});
        assert_eq!(
            inference_of(&sliding),
            "sliding 480x640 (HxW), stride rate 0.500, scales 0.75,1, flip"
        );
        let odd = serde_json::json!({"inference": {"mode": "spiral"}});
        assert!(inference_of(&odd).starts_with("unreadable record"));
    }

    #[test]
    fn a_confusion_matrix_of_another_size_is_refused_naming_the_file() {
        let names = serde_json::json!(["a", "b"]);
        let path = Path::new("scores.json");
        let (n, m) = confusion(path, &names, &serde_json::json!([[1, 2], [3, 4]])).unwrap();
        assert_eq!((n.len(), m[1][0]), (2, 3));
        let err = confusion(path, &names, &serde_json::json!([[1, 2]])).unwrap_err();
        assert_eq!(
            err.to_string(),
            "scores.json: `confusion` is not 2×2 like `class_names`"
        );
    }
}
