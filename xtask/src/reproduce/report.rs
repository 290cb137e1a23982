//! Results of a table: numbers read from the cells' `eval.json`, aggregated over seeds, written
//! as `<table>.json` (the contract scripts read), `.md` (paper columns beside measured ones,
//! each labelled with its source) and `.csv`; the paper's qualitative claims checked from the
//! measured means.

use super::cells::{self, Context, BENCH_FILE, EVAL_FILE};
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
        "budget": ctx.budget.describe(table.recipe, !synthetic),
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
        .map(|c| json!({"claim": c.text, "held": c.held, "detail": c.detail}))
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
    Some(json!({
        "mean": round(mean),
        "std": round(std),
        "seeds": per_seed.iter().map(|v| v.map(round)).collect::<Vec<_>>(),
    }))
}

/// The `rtf train`/`rtf eval` command lines of every cell, by cell id.
fn cell_recipes(ctx: &Context, table: &Table) -> serde_json::Map<String, Value> {
    let mut recipes = serde_json::Map::new();
    for cell in &table.cells {
        if let Ok(spec) = ctx.spec(table, cell, 0) {
            recipes.insert(
                cell.id.clone(),
                json!({"rtf_train": spec["rtf_train"], "rtf_eval": spec["rtf_eval"],
                       "eval_data": spec["eval_data"]}),
            );
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
    s += &markdown_rows(v, &columns);
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
            let m = &row["measured"][c];
            let measured = match (m["mean"].as_f64(), m["std"].as_f64()) {
                (Some(mean), Some(std)) if v["seeds"].as_u64().unwrap_or(1) > 1 => {
                    format!("{mean:.1} ± {std:.1}")
                }
                (Some(mean), _) => format!("{mean:.1}"),
                _ => "—".into(),
            };
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

/// The paper's claims with their verdicts on the measured means (empty when the table has none).
fn markdown_claims(v: &Value) -> String {
    let claims = v["claims"].as_array().cloned().unwrap_or_default();
    if claims.is_empty() {
        return String::new();
    }
    let mut s = String::from("\nThe paper's claims, checked on the measured means:\n\n");
    for c in claims {
        let verdict = match c["held"].as_bool() {
            Some(true) => "**held**",
            Some(false) => "**not held**",
            None => "not checkable (numbers missing)",
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
    pub held: Option<bool>,
    pub detail: String,
}

/// Measured mean of (row label, column) in a results JSON.
fn measured(v: &Value, row: &str, col: &str) -> Option<f64> {
    v["rows"].as_array()?.iter().find(|r| r["label"] == row)?["measured"][col]["mean"].as_f64()
}

/// A (row label, column) of a results table.
type Cell<'a> = (&'a str, &'a str);

/// `a > b` for every pair, each a (row, column) of the results.
fn greater(v: &Value, text: &str, pairs: &[(Cell, Cell)]) -> Claim {
    let mut detail = Vec::new();
    let mut held = Some(true);
    for ((ra, ca), (rb, cb)) in pairs {
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
    Claim {
        text: text.into(),
        held,
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
        "heatnet-tab2" => vec![greater(
            v,
            "The domain discriminator helps at night: V5 night mIoU above V3",
            &[(("V5", "Night mIoU"), ("V3", "Night mIoU"))],
        )],
        _ => vec![],
    }
}

/// Paper-budget time estimates from the quick run's training rates (`log.jsonl`): images per
/// second at the quick size, scaled by pixels to the paper's frames, times the paper's images.
pub fn estimate(ctx: &Context, table: &Table) -> Option<Value> {
    use super::budget::Budget;
    use super::tables::{Data, RecipeFamily, Train};
    let (q_frames, q_size) = ctx.budget.synth(Data::Mf);
    let _ = q_frames;
    let pixels = |s: &str| -> f64 {
        let (w, h) = s.split_once('x').unwrap_or(("1", "1"));
        w.parse::<f64>().unwrap_or(1.0) * h.parse::<f64>().unwrap_or(1.0)
    };
    let scale = pixels(q_size) / pixels("640x480");
    // Paper budget: training images per run (MF: 784 training frames per epoch).
    let (epochs, frames) = match table.recipe {
        RecipeFamily::Mfnet => (80.0, 784.0),
        RecipeFamily::Rtfnet => (100.0, 784.0),
        RecipeFamily::Heatnet => return None,
    };
    let mut cpu_s = 0.0;
    let mut gpu_s = 0.0;
    let mut n = 0;
    for cell in &table.cells {
        let Train::Model(name) = cell.train else {
            continue;
        };
        // A reused cell's training log is in the folder it was copied from.
        let dir = ctx.cell_dir(table, cell, 0);
        let log = read_json(&dir.join(cells::CELL_FILE))
            .and_then(|c| c["reused_from"].as_str().map(std::path::PathBuf::from))
            .unwrap_or(dir)
            .join("log.jsonl");
        let Some(rate) = std::fs::read_to_string(&log).ok().and_then(|t| {
            let last = t.lines().rfind(|l| !l.trim().is_empty())?.to_string();
            serde_json::from_str::<Value>(&last).ok()?["images_per_s"].as_f64()
        }) else {
            continue;
        };
        let cpu_rate = rate * scale;
        cpu_s += epochs * frames / cpu_rate;
        // GPU: the H100 rates of docs/src/getting-started.md at 480×640 (MFNet 108, RTFNet-50
        // 42, RTFNet-152 22 images/s); other networks by their CPU rate relative to MFNet's.
        let gpu_rate = match name {
            "mfnet" => 108.0,
            n if n.starts_with("rtfnet50") => 42.0,
            n if n.starts_with("rtfnet152") => 22.0,
            _ => 108.0 * cpu_rate / MFNET_CPU_RATE_480,
        };
        gpu_s += epochs * frames / gpu_rate;
        n += 1;
    }
    // Only the quick budget's rates mean something (smoke's are start-up costs).
    if n == 0 || ctx.budget != Budget::Quick {
        return None;
    }
    let text = format!(
        "Paper-budget estimate for the {n} cells measured here (one seed): about {:.0} h on this \
         CPU and {:.1} h on one H100. Method: each cell's last-epoch training rate of this run \
         (images/s at {q_size}) scaled by pixel count to 480×640, times {epochs:.0} epochs × 784 \
         frames; GPU rates from docs/src/getting-started.md (MFNet 108, RTFNet-50 42, RTFNet-152 \
         22 images/s), other networks scaled from MFNet's by their CPU rate. Rates on this \
         shared 2-core machine are disturbed by other jobs.",
        cpu_s / 3600.0,
        gpu_s / 3600.0
    );
    Some(
        json!({"cpu_hours": round(cpu_s / 3600.0), "gpu_hours": round(gpu_s / 3600.0), "text": text}),
    )
}

/// MFNet's training rate on this CPU at 480×640 (the brief's 1–1.5 images/s).
const MFNET_CPU_RATE_480: f64 = 1.25;

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
}
