//! Results of a table: numbers read from the cells' `eval.json`, aggregated over seeds, written
//! as `<table>.json` (the contract scripts read), `.md` (paper columns beside measured ones,
//! each labelled with its source) and `.csv`; the paper's qualitative claims checked from the
//! measured means.

use super::cells::{self, Context, BENCH_FILE, EVAL_FILE, OWN_EVAL_FILE};
use super::io;
use super::tables::{Measure, Metric, Row, Subset, Table};
use anyhow::{bail, Context as _, Result};
use serde_json::{json, Value};
use std::fmt::Write as _;
use std::path::Path;

/// One number of one `rtf eval --json` (percent), None where the split has no such value.
pub fn read_metric(eval: &Value, bench: Option<&Value>, metric: &Metric) -> Option<f64> {
    let scores = |s: Subset| -> Option<&Value> {
        match s {
            Subset::All => Some(eval),
            Subset::Day => eval.get("day").filter(|v| !v.is_null()),
            Subset::Night => eval.get("night").filter(|v| !v.is_null()),
            Subset::DayNight => None,
        }
    };
    // Mean of the day and the night value (HeatNet's Day/Night).
    let day_night = |f: &dyn Fn(Subset) -> Option<f64>| -> Option<f64> {
        Some((f(Subset::Day)? + f(Subset::Night)?) / 2.0)
    };
    let field = |s: Subset, key: &str| -> Option<f64> { scores(s)?.get(key)?.as_f64() };
    let class = |s: Subset, k: usize, key: &str| -> Option<f64> {
        scores(s)?.get("per_class")?.get(k)?.get(key)?.as_f64()
    };
    let v = match metric {
        Metric::MIoU(Subset::DayNight) => day_night(&|s| field(s, "miou")),
        Metric::MIoU(s) => field(*s, "miou"),
        Metric::MAcc(Subset::DayNight) => day_night(&|s| field(s, "macc")),
        Metric::MAcc(s) => field(*s, "macc"),
        Metric::MIoUMfnet(Subset::DayNight) => day_night(&|s| field(s, "miou_mfnet")),
        Metric::MIoUMfnet(s) => field(*s, "miou_mfnet"),
        Metric::ClassAcc(Subset::DayNight, k) => day_night(&|s| class(s, *k, "acc")),
        Metric::ClassAcc(s, k) => class(*s, *k, "acc"),
        Metric::ClassIoU(Subset::DayNight, k) => day_night(&|s| class(s, *k, "iou")),
        Metric::ClassIoU(s, k) => class(*s, *k, "iou"),
        Metric::MeanClassIoU(s, ks) => {
            let one = |s: Subset| -> Option<f64> {
                let v: Option<Vec<f64>> = ks.iter().map(|&k| class(s, k, "iou")).collect();
                v.map(|v| v.iter().sum::<f64>() / v.len() as f64)
            };
            match s {
                Subset::DayNight => day_night(&one),
                s => one(*s),
            }
        }
        Metric::HeatnetMIoU(s) => {
            let key = match s {
                Subset::All => "miou",
                Subset::Day => "day_miou",
                Subset::Night => "night_miou",
                Subset::DayNight => "day_night_miou",
            };
            eval.get("heatnet")?.get(key)?.as_f64()
        }
        Metric::InferenceMs => return bench?.get("median_ms")?.as_f64(),
    };
    v.map(|x| 100.0 * x)
}

/// Mean and sample standard deviation (0 for one seed).
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let std = if v.len() > 1 {
        (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    (mean, std)
}

fn read_json(path: &Path) -> Option<Value> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}

/// A cell that did not give numbers, and why.
pub struct Missing {
    pub cell: String,
    pub reason: String,
}

/// Builds `<table>.json` from the cell folders under `ctx.out` (finished seeds only).
pub fn collect(
    ctx: &Context,
    table: &Table,
    seeds: usize,
    missing: &[Missing],
    command: &str,
) -> Value {
    let real = |d| ctx.data.get(&d).is_some_and(|(_, real)| *real);
    let datasets = table.datasets();
    let synthetic = datasets.iter().any(|&d| !real(d));
    let rows: Vec<Value> = table
        .rows
        .iter()
        .map(|row| row_json(ctx, table, row, seeds, missing))
        .collect();
    let data_roots: serde_json::Map<String, Value> = datasets
        .iter()
        .filter_map(|d| {
            ctx.data
                .get(d)
                .map(|(p, r)| (d.name().to_string(), json!({"root": p, "synthetic": !r})))
        })
        .collect();
    let mut out = json!({
        "table": table.id,
        "title": title(table, synthetic),
        "source": table.source,
        "budget": ctx.budget.describe(table.recipe, &super::tables::networks(std::slice::from_ref(table)), !synthetic),
        "data": if synthetic { "synthetic" } else { "real" },
        "datasets": data_roots,
        "seeds": seeds,
        "device": ctx.device,
        "protocol": {
            "split": "train on the training split, pick the checkpoint on validation (best.safetensors; never on test), report test",
            "freiburg": "no labelled held-out part but the test layout: final weights are reported",
            "day_night": "MF: from the frame names (D/N)",
            "convention": table.convention,
        },
        "columns": table.columns.iter().map(|c| json!({
            "name": c,
            "paper": table.source,
            "measured": "rtf on this machine (mean ± std over seeds; values in percent, times in ms)",
        })).collect::<Vec<_>>(),
        "recipes": cell_recipes(ctx, table),
        "rows": rows,
        "command": command,
    });
    out["claims"] = json!(claims(table.id, &out)
        .iter()
        .map(
            |c| json!({"claim": c.text, "held": c.held, "untested": c.untested, "detail": c.detail})
        )
        .collect::<Vec<_>>());
    out
}

/// One row of `<table>.json`: the paper's values, the measured ones (columns with no finished
/// seed left out), and why the row's missing cells are missing.
fn row_json(ctx: &Context, table: &Table, row: &Row, seeds: usize, missing: &[Missing]) -> Value {
    let mut paper = serde_json::Map::new();
    let mut measured = serde_json::Map::new();
    for (c, column) in table.columns.iter().enumerate() {
        if let Some(p) = row.paper[c] {
            paper.insert(column.clone(), json!(round(p)));
        }
        let Some(m) = &row.measure[c] else { continue };
        if let Some(v) = measured_column(ctx, table, m, seeds) {
            measured.insert(column.clone(), v);
        }
    }
    let cells_of_row: Vec<&str> = row
        .measure
        .iter()
        .flatten()
        .map(|m| m.cell.as_str())
        .collect();
    let status: Vec<String> = missing
        .iter()
        .filter(|m| cells_of_row.contains(&m.cell.as_str()))
        .map(|m| format!("{}: {}", m.cell, m.reason))
        .collect();
    let mut r = json!({"label": row.label, "paper": paper, "measured": measured});
    if !status.is_empty() {
        r["not_measured"] = json!(status);
    }
    r
}

/// `{mean, std, seeds}` of one measured column over the seeds' `eval.json` (and the cell's
/// `bench.json`); `None` when no seed has finished (or the table lacks the cell).
fn measured_column(ctx: &Context, table: &Table, m: &Measure, seeds: usize) -> Option<Value> {
    let cell = table.cell(&m.cell)?;
    let per_seed: Vec<Option<f64>> = (0..seeds)
        .map(|seed| {
            let dir = ctx.cell_dir(table, cell, seed);
            let eval = read_json(&dir.join(EVAL_FILE));
            let bench = read_json(&dir.parent().unwrap_or(&dir).join(BENCH_FILE));
            eval.as_ref()
                .and_then(|e| read_metric(e, bench.as_ref(), &m.metric))
        })
        .collect();
    let values: Vec<f64> = per_seed.iter().flatten().copied().collect();
    if values.is_empty() {
        return None;
    }
    let (mean, std) = mean_std(&values);
    let mut column = json!({
        "mean": round(mean),
        "std": round(std),
        "seeds": per_seed.iter().map(|v| v.map(round)).collect::<Vec<_>>(),
    });
    // Whether the network learned: on its own dataset (a cross-dataset cell's `eval-own.json`,
    // where the all-unlabelled answer is the same bar as for every other cell).
    let scores: Vec<(f64, f64)> = (0..seeds)
        .filter_map(|seed| {
            let dir = ctx.cell_dir(table, cell, seed);
            read_json(&dir.join(OWN_EVAL_FILE)).or_else(|| read_json(&dir.join(EVAL_FILE)))
        })
        .filter_map(|eval| miou_and_trivial(&eval))
        .collect();
    if let Some(learned) = learned(&scores) {
        column["learned"] = json!(learned);
    }
    Some(column)
}

/// An evaluation's mIoU (RTFNet convention: every class, an undefined one counted 0) and the
/// mIoU of the trivial answer, every pixel the most frequent true class (MF: unlabelled), from
/// its confusion matrix: that class's IoU is its pixel share, every other class's 0. None
/// without a confusion matrix.
pub fn miou_and_trivial(eval: &Value) -> Option<(f64, f64)> {
    let rows: Vec<u64> = eval["confusion"]
        .as_array()?
        .iter()
        .map(|r| {
            r.as_array()
                .map(|r| r.iter().filter_map(Value::as_u64).sum())
        })
        .collect::<Option<_>>()?;
    let total: u64 = rows.iter().sum();
    let largest = rows.iter().copied().max()?;
    if total == 0 {
        return None;
    }
    let trivial = largest as f64 / total as f64 / rows.len() as f64;
    Some((eval["miou"].as_f64()?, trivial))
}

/// Whether a cell's network left the trivial answer: its mIoU (mean over the seeds) at least
/// twice the trivial answer's. None without scores.
pub fn learned(scores: &[(f64, f64)]) -> Option<bool> {
    if scores.is_empty() {
        return None;
    }
    let n = scores.len() as f64;
    let miou = scores.iter().map(|s| s.0).sum::<f64>() / n;
    let trivial = scores.iter().map(|s| s.1).sum::<f64>() / n;
    Some(miou >= 2.0 * trivial)
}

/// The verdict of a claim judged on a cell whose network did not learn.
pub const UNTESTED: &str = "untested (network did not train at this budget)";

/// The `rtf train`/`rtf eval` command lines of every cell, by cell id.
fn cell_recipes(ctx: &Context, table: &Table) -> serde_json::Map<String, Value> {
    let mut recipes = serde_json::Map::new();
    for cell in &table.cells {
        if let Ok(spec) = ctx.spec(table, cell, 0) {
            let mut recipe = json!({"rtf_train": spec["rtf_train"], "rtf_eval": spec["rtf_eval"],
                                    "eval_data": spec["eval_data"]});
            if let Some(own) = spec.get("rtf_eval_own") {
                recipe["rtf_eval_own"] = own.clone();
            }
            recipes.insert(cell.id.clone(), recipe);
        }
    }
    recipes
}

fn round(x: f64) -> f64 {
    (x * 1000.0).round() / 1000.0
}

fn title(table: &Table, synthetic: bool) -> String {
    if synthetic {
        format!("{} — synthetic data (`rtf synth`)", table.title)
    } else {
        table.title.to_string()
    }
}

/// Checks the JSON contract: `{table, budget, data, protocol, rows: [{label, paper: {COL:
/// value}, measured: {COL: {mean, std, seeds}}}]}`.
pub fn validate(v: &Value) -> Result<()> {
    for key in [
        "table", "budget", "data", "protocol", "rows", "columns", "claims",
    ] {
        if v.get(key).is_none() {
            bail!("results JSON has no `{key}`");
        }
    }
    if !matches!(v["data"].as_str(), Some("synthetic" | "real" | "none")) {
        bail!("`data` must be \"synthetic\", \"real\" or \"none\" (speed tables)");
    }
    let columns: Vec<&str> = v["columns"]
        .as_array()
        .context("`columns` is no array")?
        .iter()
        .filter_map(|c| c["name"].as_str())
        .collect();
    for row in v["rows"].as_array().context("`rows` is no array")? {
        row["label"].as_str().context("a row without `label`")?;
        for (col, p) in row["paper"].as_object().context("`paper` is no object")? {
            if !columns.contains(&col.as_str()) || !p.is_number() {
                bail!("paper column `{col}`: unknown or not a number");
            }
        }
        for (col, m) in row["measured"]
            .as_object()
            .context("`measured` is no object")?
        {
            if !columns.contains(&col.as_str()) {
                bail!("measured column `{col}` is not a column of the table");
            }
            let seeds = m["seeds"].as_array().context("`seeds` is no array")?;
            if !m["mean"].is_number() || !m["std"].is_number() || seeds.is_empty() {
                bail!("measured `{col}`: needs numbers mean, std and a list of seeds");
            }
        }
    }
    Ok(())
}

/// The table in Markdown.
pub fn markdown(v: &Value) -> String {
    let mut s = format!("### {}\n\n", v["title"].as_str().unwrap_or(""));
    let columns: Vec<&str> = v["columns"]
        .as_array()
        .map(|a| a.iter().filter_map(|c| c["name"].as_str()).collect())
        .unwrap_or_default();
    let _ = writeln!(
        s,
        "Paper columns: {} as printed. Measured columns: rtf, budget `{}`, {} data, {} seed(s), \
         device {}; mean ± std over seeds. {}\n",
        v["source"].as_str().unwrap_or(""),
        v["budget"]["name"].as_str().unwrap_or(""),
        v["data"].as_str().unwrap_or(""),
        v["seeds"],
        v["device"].as_str().unwrap_or(""),
        v["protocol"]["convention"].as_str().unwrap_or("")
    );
    s += &markdown_stand_ins(v);
    s += &markdown_rows(v, &columns);
    s += &markdown_learned(v);
    s += &markdown_claims(v);
    if let Some(f) = v.get("figure").and_then(Value::as_str) {
        let _ = writeln!(
            s,
            "\nFigure `{f}`: measured mAcc (left) and mIoU (right) against the encoder \
             (ResNet-18, 34, 50, 101, 152 from left to right), y from 0 to 100 % with a grid line \
             every 10 %; RTFNet red, NRE blue, NTE green, NUB orange."
        );
    }
    if let Some(e) = v.get("estimate").and_then(|e| e["text"].as_str()) {
        let _ = writeln!(s, "\n{e}");
    }
    let _ = writeln!(
        s,
        "\nCommand: `{}`. Per-cell recipes: `{}.json`.",
        v["command"].as_str().unwrap_or(""),
        v["table"].as_str().unwrap_or("")
    );
    s
}

/// One measured value in Markdown: mean ± std over the table's `seeds`, the mean alone for one
/// seed, and "(n of N seeds)" when only some seeds have finished (`null` in `seeds`).
fn measured_cell(m: &Value, seeds: u64) -> String {
    let done = m["seeds"]
        .as_array()
        .map_or(0, |a| a.iter().filter(|s| s.is_number()).count() as u64);
    let value = match (m["mean"].as_f64(), m["std"].as_f64()) {
        (Some(mean), Some(std)) if done > 1 => format!("{mean:.1} ± {std:.1}"),
        (Some(mean), _) => format!("{mean:.1}"),
        _ => return "—".into(),
    };
    match done < seeds {
        true => format!("{value} ({done} of {seeds} seeds)"),
        false => value,
    }
}

/// The Markdown table itself (paper and measured value side by side per column), then the
/// rows' "Not measured" notes.
fn markdown_rows(v: &Value, columns: &[&str]) -> String {
    let mut s = String::from("| row |");
    for c in columns {
        let _ = write!(s, " paper: {c} | measured: {c} |");
    }
    s += "\n|---|";
    s += &"---:|".repeat(2 * columns.len());
    s += "\n";
    let mut notes = Vec::new();
    for row in v["rows"].as_array().into_iter().flatten() {
        let _ = write!(s, "| {} |", row["label"].as_str().unwrap_or(""));
        for c in columns {
            let paper = row["paper"][c]
                .as_f64()
                .map_or("—".to_string(), |p| format!("{p:.1}"));
            let measured = measured_cell(&row["measured"][c], v["seeds"].as_u64().unwrap_or(1));
            let _ = write!(s, " {paper} | {measured} |");
        }
        s += "\n";
        for n in row["not_measured"].as_array().into_iter().flatten() {
            notes.push(format!(
                "{}: {}",
                row["label"].as_str().unwrap_or(""),
                n.as_str().unwrap_or("")
            ));
        }
    }
    if !notes.is_empty() {
        s += "\nNot measured:\n\n";
        notes.dedup();
        for n in notes {
            let _ = writeln!(s, "- {n}");
        }
    }
    s
}

/// The networks a budget trains in the place of the table's (CMX's CPU stand-ins); empty
/// when every cell trains its own.
fn markdown_stand_ins(v: &Value) -> String {
    let Some(map) = v["budget"]["stand_ins"]
        .as_object()
        .filter(|m| !m.is_empty())
    else {
        return String::new();
    };
    let pairs: Vec<String> = map
        .iter()
        .map(|(cell, net)| format!("`{cell}` → `{}`", net.as_str().unwrap_or("")))
        .collect();
    format!(
        "Trained in the table's networks' place on this budget (cell → network): {}. The \
         measured columns are these networks' numbers.\n\n",
        pairs.join(", ")
    )
}

/// Which rows' networks left the all-unlabelled answer (`learned`, mean test mIoU at least
/// twice that answer's); empty when no column says.
fn markdown_learned(v: &Value) -> String {
    let mut judged = false;
    let mut below = Vec::new();
    for row in v["rows"].as_array().into_iter().flatten() {
        let flags: Vec<bool> = row["measured"]
            .as_object()
            .into_iter()
            .flat_map(|m| m.values())
            .filter_map(|c| c["learned"].as_bool())
            .collect();
        judged |= !flags.is_empty();
        if flags.contains(&false) {
            below.push(row["label"].as_str().unwrap_or("").to_string());
        }
    }
    let bar = "mean test mIoU at least twice the all-unlabelled answer's; a network scored on \
               another dataset: on its own dataset's test split";
    match (judged, below.is_empty()) {
        (false, _) => String::new(),
        (true, true) => format!("\nEvery row's network learned ({bar}).\n"),
        (true, false) => format!("\nNot learned ({bar}): {}.\n", below.join(", ")),
    }
}

/// The paper's claims with their verdicts on the measured means (empty when the table has none).
fn markdown_claims(v: &Value) -> String {
    let claims = v["claims"].as_array().cloned().unwrap_or_default();
    if claims.is_empty() {
        return String::new();
    }
    let mut s = String::from("\nThe paper's claims, checked on the measured means:\n\n");
    for c in claims {
        let verdict = match (c["held"].as_bool(), c["untested"].as_bool()) {
            (_, Some(true)) => UNTESTED,
            (Some(true), _) => "**held**",
            (Some(false), _) => "**not held**",
            (None, _) => "not checkable (numbers missing)",
        };
        let _ = writeln!(
            s,
            "- {}: {verdict} ({})",
            c["claim"].as_str().unwrap_or(""),
            c["detail"].as_str().unwrap_or("")
        );
    }
    s
}

/// The table as CSV: one line per (row, column).
pub fn csv(v: &Value) -> String {
    let mut s = String::from("row,column,paper,measured_mean,measured_std,seeds\n");
    let q = |t: &str| format!("\"{}\"", t.replace('"', "\"\""));
    let columns: Vec<&str> = v["columns"]
        .as_array()
        .map(|a| a.iter().filter_map(|c| c["name"].as_str()).collect())
        .unwrap_or_default();
    for row in v["rows"].as_array().into_iter().flatten() {
        for c in &columns {
            let num = |x: &Value| x.as_f64().map_or(String::new(), |x| x.to_string());
            let m = &row["measured"][c];
            let seeds: Vec<String> = m["seeds"]
                .as_array()
                .map(|a| a.iter().map(num).collect())
                .unwrap_or_default();
            let _ = writeln!(
                s,
                "{},{},{},{},{},{}",
                q(row["label"].as_str().unwrap_or("")),
                q(c),
                num(&row["paper"][c]),
                num(&m["mean"]),
                num(&m["std"]),
                q(&seeds.join(";"))
            );
        }
    }
    s
}

/// A qualitative claim of a paper, checked on the measured means.
pub struct Claim {
    pub text: String,
    /// None when a number is missing or the claim is untested.
    pub held: Option<bool>,
    /// A compared cell's network did not leave the trivial answer (`learned`: false): the
    /// claim compares untrained networks and is not judged.
    pub untested: bool,
    pub detail: String,
}

/// Measured column (row label, column) of a results JSON.
fn measured_entry<'a>(v: &'a Value, row: &str, col: &str) -> Option<&'a Value> {
    Some(&v["rows"].as_array()?.iter().find(|r| r["label"] == row)?["measured"][col])
}

/// Measured mean of (row label, column) in a results JSON.
fn measured(v: &Value, row: &str, col: &str) -> Option<f64> {
    measured_entry(v, row, col)?["mean"].as_f64()
}

/// Whether the network behind (row label, column) stayed at the trivial answer.
fn untrained(v: &Value, row: &str, col: &str) -> bool {
    measured_entry(v, row, col).is_some_and(|m| m["learned"].as_bool() == Some(false))
}

/// A (row label, column) of a results table.
type Cell<'a> = (&'a str, &'a str);

/// `a > b` for every pair, each a (row, column) of the results.
fn greater(v: &Value, text: &str, pairs: &[(Cell, Cell)]) -> Claim {
    let mut detail = Vec::new();
    let mut held = Some(true);
    let mut not_learned = Vec::new();
    for ((ra, ca), (rb, cb)) in pairs {
        for (r, c) in [(ra, ca), (rb, cb)] {
            if untrained(v, r, c) && !not_learned.contains(r) {
                not_learned.push(*r);
            }
        }
        match (measured(v, ra, ca), measured(v, rb, cb)) {
            (Some(a), Some(b)) => {
                detail.push(format!("{ra} {ca} {a:.1} vs {rb} {cb} {b:.1}"));
                if a <= b {
                    held = held.map(|_| false);
                }
            }
            _ => {
                detail.push(format!("{ra} / {rb}: missing"));
                held = None;
            }
        }
    }
    let untested = held.is_some() && !not_learned.is_empty();
    if untested {
        detail.push(format!(
            "mIoU below twice the all-unlabelled answer's: {}",
            not_learned.join(", ")
        ));
    }
    Claim {
        text: text.into(),
        held: if untested { None } else { held },
        untested,
        detail: detail.join("; "),
    }
}

/// The claims the issue asks to check, per table.
pub fn claims(table: &str, v: &Value) -> Vec<Claim> {
    match table {
        "mfnet-tab2" => vec![
            greater(
                v,
                "Thermal helps at night (MFNet Sec. V-A): 4-channel and fusion night mean IoU above the RGB-only SegNet",
                &[
                    (("SegNet_4ch (A) (night)", "mean IoU"), ("SegNet (night)", "mean IoU")),
                    (("MFNet (night)", "mean IoU"), ("SegNet (night)", "mean IoU")),
                ],
            ),
        ],
        "mfnet-tab3" => vec![
            greater(
                v,
                "MFNet beats MFNet_RGB (model B): the thermal encoder helps",
                &[(("MFNet", "mean IoU"), ("MFNet_RGB (B)", "mean IoU"))],
            ),
            greater(
                v,
                "LeakyReLU beats ReLU (MFNet vs MFNet_relu, model F)",
                &[(("MFNet", "mean IoU"), ("MFNet_relu (F)", "mean IoU"))],
            ),
        ],
        "rtfnet-tab4" => vec![
            greater(
                v,
                "NRE (thermal only) beats NTE (RGB only) at night (RTFNet Tab. IV)",
                &[
                    (("ResNet-50", "Nighttime NRE"), ("ResNet-50", "Nighttime NTE")),
                    (("ResNet-152", "Nighttime NRE"), ("ResNet-152", "Nighttime NTE")),
                ],
            ),
            greater(
                v,
                "NTE (RGB only) beats NRE (thermal only) by day (RTFNet Tab. IV)",
                &[
                    (("ResNet-50", "Daytime NTE"), ("ResNet-50", "Daytime NRE")),
                    (("ResNet-152", "Daytime NTE"), ("ResNet-152", "Daytime NRE")),
                ],
            ),
        ],
        "rtfnet-tab6" => {
            let nets = ["ERFNet", "UNet", "PSPNet", "SegNet", "DUC-HDC"];
            let labels: Vec<(String, String)> = nets
                .iter()
                .map(|n| (format!("{n} (4c)"), format!("{n} (3c)")))
                .collect();
            let pairs: Vec<(Cell, Cell)> = labels
                .iter()
                .map(|(a, b)| ((a.as_str(), "Nighttime mIoU"), (b.as_str(), "Nighttime mIoU")))
                .collect();
            vec![greater(
                v,
                "Thermal helps at night: every baseline's 4c night mIoU above its 3c",
                &pairs,
            )]
        }
        "heatnet-tab1" => vec![greater(
            v,
            "MF-trained networks do not generalise to FR-T (HeatNet Sec. V-B): MFNet's and \
             RTFNet-50's person/car/bicycle mean on MF above the same on FR-T Day/Night",
            &[
                (("MF→MF: MFNet", "Mean"), ("MF→FR-T Day/Night: MFNet", "Mean")),
                (("MF→MF: RTFNet-50", "Mean"), ("MF→FR-T Day/Night: RTFNet-50", "Mean")),
            ],
        )],
        "heatnet-tab2" => vec![greater(
            v,
            "The domain discriminator helps at night: V5 night mIoU above V3",
            &[(("V5", "Night mIoU"), ("V3", "Night mIoU"))],
        )],
        _ => vec![],
    }
}

/// Paper-budget time estimates from the quick run's training rates (`log.jsonl`): the CPU time
/// by pixel scaling, the H100 time from the measured GPU rates (`paper_time`).
pub fn estimate(ctx: &Context, table: &Table) -> Option<Value> {
    use super::budget::Budget;
    use super::tables::{Data, RecipeFamily, Train};
    let (_, q_size) = ctx.budget.synth(Data::Mf);
    let pixels = |s: &str| -> f64 {
        let (w, h) = s.split_once('x').unwrap_or(("1", "1"));
        w.parse::<f64>().unwrap_or(1.0) * h.parse::<f64>().unwrap_or(1.0)
    };
    // Paper budget: training images per run (MF: 784 training frames per epoch).
    let epochs = match table.recipe {
        RecipeFamily::Mfnet => 80.0,
        RecipeFamily::Rtfnet => 100.0,
        // CMX's official MF schedule (the `cmx-mf` recipe).
        RecipeFamily::Cmx => 500.0,
        RecipeFamily::Heatnet => return None,
    };
    let mut rates = Vec::new();
    for cell in &table.cells {
        let Train::Model(name) = cell.train else {
            continue;
        };
        // A reused cell's training log is in the folder it was copied from.
        let dir = ctx.cell_dir(table, cell, 0);
        let trained = read_json(&dir.join(cells::CELL_FILE))
            .and_then(|c| c["reused_from"].as_str().map(std::path::PathBuf::from))
            .unwrap_or(dir);
        let last = rtf_run::RunFolder::open(&trained).and_then(|run| run.last_epoch());
        if let Ok(Some(epoch)) = last {
            rates.push((name, epoch.images_per_s));
        }
    }
    // Only the quick budget's rates mean something (smoke's are start-up costs).
    if rates.is_empty() || ctx.budget != Budget::Quick {
        return None;
    }
    let e = super::paper_time::estimate(&rates, pixels(q_size), epochs * 784.0);
    Some(
        json!({"cpu_hours": round(e.cpu_hours), "gpu_hours": round(e.gpu_hours.1),
                "gpu_hours_range": [round(e.gpu_hours.0), round(e.gpu_hours.1)],
                "text": estimate_text(&e, q_size, epochs, table.recipe == RecipeFamily::Cmx)}),
    )
}

/// What the estimate is and how it was made; `stand_ins`: the quick cells trained lighter
/// networks than the paper's (CMX), said with the CPU figure.
fn estimate_text(
    e: &super::paper_time::Estimate,
    q_size: &str,
    epochs: f64,
    stand_ins: bool,
) -> String {
    let (fast, slow) = e.gpu_hours;
    let gpu = match (slow - fast).abs() < 0.05 {
        true => format!("{slow:.1} h"),
        false => format!("{fast:.1}–{slow:.1} h"),
    };
    format!(
        "Paper-budget estimate for the {} cells measured here (one seed), {epochs:.0} epochs × 784 \
         frames at 480×640 each: {gpu} on one H100 and at most about {:.0} h on this CPU. GPU: \
         the H100 training rates of docs/src/getting-started.md (MFNet 108, RTFNet-50 42, \
         RTFNet-152 22 images/s); a network without its own rate gets the measured range \
         (108–22 images/s), never a rate scaled from a CPU one. CPU: each cell's last-epoch \
         training rate of this run (images/s at {q_size}) scaled by pixel count, an upper \
         bound (small frames and short epochs weigh fixed per-step costs more; rates on this \
         shared 2-core machine are disturbed by other jobs).{}",
        e.cells,
        e.cpu_hours,
        if stand_ins { CMX_ESTIMATE_NOTE } else { "" }
    )
}

/// The CMX table's caveats on its estimate.
const CMX_ESTIMATE_NOTE: &str = " CMX: no CMX training rate has been measured on a GPU, so \
     MiT-B2 and MiT-B4 get the range of the networks measured (MFNet to RTFNet-152), which \
     is not a measured bound for a transformer. The CPU figure is for the stand-ins trained here \
     (cmx-mit-b0 for B2, cmx-mit-b1 for B4; an upper bound for them), not B2's and B4's: they \
     are larger (66.6 M and 139.9 M parameters against 12.1 M and 44.5 M) and were not timed \
     on this CPU.";

/// Writes `<out>/<table>.{json,md,csv}`.
pub fn write(out: &Path, v: &Value) -> Result<()> {
    validate(v)?;
    let id = v["table"].as_str().context("table id")?;
    io::write_json(&out.join(format!("{id}.json")), v)?;
    io::write_atomic(&out.join(format!("{id}.md")), markdown(v).as_bytes())?;
    io::write_atomic(&out.join(format!("{id}.csv")), csv(v).as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn eval_json() -> Value {
        let per_class = |iou: f64| {
            (0..9)
                .map(|k| json!({"name": k.to_string(), "acc": 0.5, "iou": if k == 6 { Value::Null } else { json!(iou + k as f64 / 100.0) }}))
                .collect::<Vec<_>>()
        };
        json!({
            "miou": 0.4, "macc": 0.5, "miou_mfnet": 0.45, "per_class": per_class(0.3),
            "day": {"miou": 0.5, "macc": 0.6, "miou_mfnet": 0.55, "per_class": per_class(0.4)},
            "night": {"miou": 0.3, "macc": 0.4, "miou_mfnet": 0.35, "per_class": per_class(0.2)},
            "heatnet": {"miou": 0.1, "day_miou": 0.2, "night_miou": 0.3, "day_night_miou": 0.25}
        })
    }

    #[test]
    fn metrics_are_read_in_percent_from_rtf_eval_json() {
        let e = eval_json();
        let r = |m| read_metric(&e, Some(&json!({"median_ms": 12.5})), &m);
        let close = |a: Option<f64>, b: f64| (a.unwrap() - b).abs() < 1e-9;
        assert!(close(r(Metric::MIoU(Subset::All)), 40.0));
        assert!(close(r(Metric::MIoU(Subset::Night)), 30.0));
        assert!(close(r(Metric::MAcc(Subset::Day)), 60.0));
        assert!(close(r(Metric::MIoUMfnet(Subset::All)), 45.0));
        assert!(close(r(Metric::ClassIoU(Subset::Day, 2)), 42.0));
        assert!(close(r(Metric::ClassIoU(Subset::DayNight, 2)), 32.0));
        assert_eq!(
            r(Metric::ClassIoU(Subset::All, 6)),
            None,
            "NaN IoU stays missing"
        );
        assert!(close(
            r(Metric::MeanClassIoU(Subset::All, &[1, 2, 3])),
            32.0
        ));
        assert!(close(r(Metric::HeatnetMIoU(Subset::DayNight)), 25.0));
        assert!(close(r(Metric::InferenceMs), 12.5), "times stay in ms");
        assert_eq!(read_metric(&e, None, &Metric::InferenceMs), None);
        let no_day = json!({"miou": 0.1, "day": null});
        assert_eq!(read_metric(&no_day, None, &Metric::MIoU(Subset::Day)), None);
        // A class set whose class 0 is a class (rtf eval writes null): no MFNet-convention
        // number, never a 0 or a number that dropped a real class.
        let road =
            json!({"miou": 0.4, "miou_mfnet": null, "day": {"miou": 0.5, "miou_mfnet": null}});
        for s in [Subset::All, Subset::Day, Subset::DayNight] {
            assert_eq!(read_metric(&road, None, &Metric::MIoUMfnet(s)), None);
        }
        assert!(
            (read_metric(&road, None, &Metric::MIoU(Subset::All)).unwrap() - 40.0).abs() < 1e-9
        );
    }

    /// A cell whose seeds have not all finished says how many it averages.
    #[test]
    fn partly_finished_cells_say_how_many_seeds_they_average() {
        let cell = |seeds: Value| json!({"mean": 57.4, "std": 4.1, "seeds": seeds});
        assert_eq!(
            measured_cell(&cell(json!([54.6, 60.3, 57.3])), 3),
            "57.4 ± 4.1"
        );
        assert_eq!(
            measured_cell(&cell(json!([54.6, 60.3, null])), 3),
            "57.4 ± 4.1 (2 of 3 seeds)"
        );
        assert_eq!(
            measured_cell(&cell(json!([null, 57.4, null])), 3),
            "57.4 (1 of 3 seeds)"
        );
        assert_eq!(measured_cell(&cell(json!([57.4])), 1), "57.4");
        assert_eq!(measured_cell(&json!({}), 3), "—");
    }

    #[test]
    fn mean_and_sample_std() {
        assert_eq!(mean_std(&[2.0]), (2.0, 0.0));
        let (m, s) = mean_std(&[1.0, 2.0, 3.0]);
        assert!((m - 2.0).abs() < 1e-12 && (s - 1.0).abs() < 1e-12);
    }

    fn results() -> Value {
        json!({
            "table": "mfnet-tab3", "title": "T", "source": "S", "budget": {"name": "smoke"},
            "data": "synthetic", "seeds": 2, "device": "cpu",
            "protocol": {"convention": "C"},
            "columns": [{"name": "mean IoU"}, {"name": "class avg."}],
            "rows": [
                {"label": "MFNet", "paper": {"mean IoU": 64.86},
                 "measured": {"mean IoU": {"mean": 30.0, "std": 1.0, "seeds": [29.0, 31.0]}}},
                {"label": "MFNet_RGB (B)", "paper": {},
                 "measured": {"mean IoU": {"mean": 25.0, "std": 0.0, "seeds": [25.0, 25.0]}}},
                {"label": "MFNet_relu (F)", "paper": {}, "measured": {},
                 "not_measured": ["mfnet-f: failed"]}
            ],
            "claims": [], "command": "cargo xtask reproduce mfnet-tab3"
        })
    }

    /// A cell's network learned when its mIoU is at least twice the trivial answer's, read from
    /// the confusion matrix of its `rtf eval --json` (rows = truth).
    #[test]
    fn the_trivial_answer_comes_from_the_confusion_matrix() {
        // 90 % of the pixels unlabelled, 3 classes: the all-unlabelled answer scores 0.9 / 3.
        let eval =
            |miou: f64| json!({"miou": miou, "confusion": [[80, 10, 0], [5, 5, 0], [0, 0, 0]]});
        let (miou, trivial) = miou_and_trivial(&eval(0.25)).unwrap();
        assert!((miou - 0.25).abs() < 1e-12 && (trivial - 0.3).abs() < 1e-12);
        assert_eq!(learned(&[(0.25, 0.3)]), Some(false));
        assert_eq!(learned(&[(0.61, 0.3)]), Some(true));
        // The mean over seeds decides.
        assert_eq!(learned(&[(0.9, 0.3), (0.4, 0.3)]), Some(true));
        assert_eq!(learned(&[(0.7, 0.3), (0.4, 0.3)]), Some(false));
        assert_eq!(learned(&[]), None);
        assert_eq!(miou_and_trivial(&json!({"miou": 0.2})), None, "no matrix");
    }

    /// rtfnet-tab4's quick run: four untrained networks tie at the trivial answer, which must
    /// not read as a verdict either way.
    #[test]
    fn claims_on_networks_that_did_not_learn_are_untested() {
        let col = |mean: f64, learned: bool| json!({"mean": mean, "std": 0.0, "seeds": [mean], "learned": learned});
        let mut v = json!({
            "table": "rtfnet-tab4", "title": "T", "source": "S", "budget": {"name": "quick"},
            "data": "synthetic", "seeds": 1, "device": "cpu", "protocol": {"convention": "C"},
            "columns": [{"name": "Daytime NRE"}, {"name": "Daytime NTE"},
                        {"name": "Nighttime NRE"}, {"name": "Nighttime NTE"}],
            "rows": [
                {"label": "ResNet-50", "paper": {}, "measured": {
                    "Daytime NRE": col(11.6, false), "Daytime NTE": col(11.6, false),
                    "Nighttime NRE": col(12.2, false), "Nighttime NTE": col(11.1, false)}},
                {"label": "ResNet-152", "paper": {}, "measured": {
                    "Daytime NRE": col(31.2, true), "Daytime NTE": col(41.6, true),
                    "Nighttime NRE": col(41.5, true), "Nighttime NTE": col(30.8, true)}}
            ],
            "claims": [], "command": "cargo xtask reproduce rtfnet-tab4"
        });
        validate(&v).unwrap();
        let c = claims("rtfnet-tab4", &v);
        assert_eq!(c.len(), 2);
        for claim in &c {
            assert!(claim.untested && claim.held.is_none(), "{}", claim.detail);
            assert!(claim.detail.contains("ResNet-50"), "{}", claim.detail);
            assert!(!claim.detail.contains("ResNet-152,"), "{}", claim.detail);
        }
        v["claims"] = json!(c
            .iter()
            .map(|c| json!({"claim": c.text, "held": c.held, "untested": c.untested, "detail": c.detail}))
            .collect::<Vec<_>>());
        let md = markdown(&v);
        assert_eq!(md.matches(UNTESTED).count(), 2, "{md}");
        assert!(!md.contains("not held") && !md.contains("**held**"), "{md}");

        // Every network learned: the claims are judged again.
        for row in v["rows"].as_array_mut().unwrap() {
            for (_, m) in row["measured"].as_object_mut().unwrap() {
                m["learned"] = json!(true);
            }
        }
        let c = claims("rtfnet-tab4", &v);
        assert!(c.iter().all(|c| !c.untested));
        assert_eq!(c[0].held, Some(true), "{}", c[0].detail);
        assert_eq!(c[1].held, Some(false), "day: 11.6 vs 11.6 is no win");
    }

    #[test]
    fn json_schema_is_checked() {
        let v = results();
        validate(&v).unwrap();
        for (path, bad) in [("data", json!("made-up")), ("rows", json!({}))] {
            let mut w = v.clone();
            w[path] = bad;
            assert!(validate(&w).is_err(), "{path}");
        }
        let mut w = v.clone();
        w["rows"][0]["measured"]["mean IoU"]["seeds"] = json!([]);
        assert!(validate(&w).is_err());
        let mut w = v.clone();
        w["rows"][0]["measured"]["mIoU?"] = json!({"mean": 1.0, "std": 0.0, "seeds": [1.0]});
        assert!(validate(&w).unwrap_err().to_string().contains("mIoU?"));
        let mut w = v.clone();
        w.as_object_mut().unwrap().remove("protocol");
        assert!(validate(&w).is_err());
    }

    #[test]
    fn claims_markdown_and_csv() {
        let v = results();
        let c = claims("mfnet-tab3", &v);
        assert_eq!(c.len(), 2);
        assert_eq!(c[0].held, Some(true), "{}", c[0].detail);
        assert_eq!(c[1].held, None, "model F has no number");
        let mut v2 = v.clone();
        v2["claims"] = json!([{"claim": "B below", "held": true, "detail": "d"}]);
        let md = markdown(&v2);
        let lines: Vec<&str> = md.lines().collect();
        let header = lines.iter().find(|l| l.starts_with("| row |")).unwrap();
        assert!(header.contains("paper: mean IoU | measured: mean IoU |"));
        let mfnet = lines.iter().find(|l| l.starts_with("| MFNet |")).unwrap();
        assert_eq!(*mfnet, "| MFNet | 64.9 | 30.0 ± 1.0 | — | — |");
        assert_eq!(header.matches('|').count(), mfnet.matches('|').count());
        assert!(md.contains("mfnet-f: failed"));
        assert!(md.contains("B below: **held**"));
        let csv = csv(&v);
        assert!(
            csv.contains("\"MFNet\",\"mean IoU\",64.86,30,1,\"29;31\""),
            "{csv}"
        );
        assert_eq!(csv.lines().count(), 1 + 3 * 2);
    }

    /// The CMX table's paper-budget estimate: 500 epochs × 784 frames per cell, the measured
    /// GPU range (no CMX rate), the stand-ins' CPU rates, each said in the text.
    #[test]
    fn cmx_estimate_takes_its_papers_epochs_and_says_what_it_rests_on() {
        use crate::reproduce::budget::Budget;
        let tmp = tempfile::tempdir().unwrap();
        let mut ctx = crate::reproduce::cells::tests::fake_context(tmp.path());
        let tables = crate::reproduce::tables::all(false);
        let t = tables.iter().find(|t| t.id == "cmx-mf").unwrap();
        for c in &t.cells {
            crate::reproduce::cells::run(&ctx, t, c, 0).unwrap();
        }
        assert!(
            estimate(&ctx, t).is_none(),
            "smoke rates are start-up costs"
        );
        ctx.budget = Budget::Quick;
        let e = estimate(&ctx, t).unwrap();
        // The fake rtf trains at 10 images/s; GPU: 392 000 images per cell at 108–22 images/s.
        let per = |rate: f64| 500.0 * 784.0 / rate / 3600.0;
        let range = e["gpu_hours_range"].as_array().unwrap();
        assert!(
            (range[0].as_f64().unwrap() - 2.0 * per(108.0)).abs() < 1e-3,
            "{e}"
        );
        assert!(
            (range[1].as_f64().unwrap() - 2.0 * per(22.0)).abs() < 1e-3,
            "{e}"
        );
        let text = e["text"].as_str().unwrap();
        assert!(
            text.contains("2 cells") && text.contains("500 epochs"),
            "{text}"
        );
        assert!(
            text.contains("no CMX training rate") && text.contains("cmx-mit-b1 for"),
            "{text}"
        );
    }

    /// Stand-ins and the learning verdict are said above and below the table.
    #[test]
    fn markdown_names_stand_ins_and_which_rows_learned() {
        let mut v = results();
        assert!(
            !markdown(&v).contains("learned"),
            "no verdict without `learned`"
        );
        v["budget"]["stand_ins"] = json!({"cmx-mit-b2": "cmx-mit-b0"});
        v["rows"][0]["measured"]["mean IoU"]["learned"] = json!(true);
        let md = markdown(&v);
        assert!(md.contains("`cmx-mit-b2` → `cmx-mit-b0`"), "{md}");
        assert!(md.contains("Every row's network learned"), "{md}");
        v["rows"][1]["measured"]["mean IoU"]["learned"] = json!(false);
        let md = markdown(&v);
        assert!(md.contains("Not learned (mean test mIoU"), "{md}");
        assert!(md.contains("): MFNet_RGB (B)."), "{md}");
    }
}
