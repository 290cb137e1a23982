//! `rtf report RUN… [--eval SCORES.json…] --out report.html`: one self-contained HTML page
//! (every image embedded as a `data:` URI) summarising training runs and evaluations.
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
//! Charts are drawn with `plotters` (SVG backend: text is laid out by the browser, no font
//! files needed); the grid is a PNG.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use base64::Engine;
use plotters::prelude::*;
use serde_json::Value;

use super::eval::EVAL_SCHEMA;

#[derive(clap::Args)]
pub struct Args {
    /// Run folders (written by `rtf train`).
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// Score files written by `rtf eval --json` (repeatable).
    #[arg(long = "eval")]
    pub evals: Vec<PathBuf>,
    /// The HTML page to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Dataset root for the prediction grid (default: the first run's dataset, if present).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Split of --data for the prediction grid.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Frames in the prediction grid (0: no grid).
    #[arg(long, default_value_t = 4)]
    pub frames: usize,
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

/// One epoch line of `log.jsonl`, old or new schema.
struct Epoch {
    epoch: f64,
    raw: Value,
}

/// A run folder or one stage of it.
struct Run {
    label: String,
    dir: PathBuf,
    config: Value,
    log: Vec<Epoch>,
}

/// An `rtf eval --json` file.
struct EvalFile {
    path: PathBuf,
    json: Value,
}

fn read_json(path: &Path) -> Result<Value> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: not valid JSON", path.display()))
}

fn read_log(path: &Path) -> Result<Vec<Epoch>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let raw: Value = serde_json::from_str(line)
            .with_context(|| format!("{}:{}: not a JSON line", path.display(), i + 1))?;
        let epoch = raw.get("epoch").and_then(Value::as_f64).ok_or_else(|| {
            anyhow!(
                "{}:{}: a log record without a numeric `epoch`",
                path.display(),
                i + 1
            )
        })?;
        out.push(Epoch { epoch, raw });
    }
    Ok(out)
}

/// The run at `dir` and, for a multi-stage run, each stage (`config.json` `"stages"`).
fn load_runs(dir: &Path) -> Result<Vec<Run>> {
    let config_path = dir.join("config.json");
    let log_path = dir.join("log.jsonl");
    if !dir.is_dir() {
        bail!("{}: not a run folder (no such directory)", dir.display());
    }
    let config = if config_path.exists() {
        read_json(&config_path)?
    } else {
        Value::Null
    };
    let label = dir.file_name().map_or_else(
        || dir.display().to_string(),
        |n| n.to_string_lossy().to_string(),
    );
    let stages: Vec<String> = config
        .get("stages")
        .and_then(Value::as_array)
        .map(|stages| {
            stages
                .iter()
                .filter_map(|s| {
                    s.as_str()
                        .or_else(|| s.get("name").and_then(Value::as_str))
                        .map(str::to_string)
                })
                .collect()
        })
        .unwrap_or_default();
    let mut runs = Vec::new();
    if log_path.exists() || stages.is_empty() {
        if !log_path.exists() {
            bail!(
                "{}: not a run folder: {} is missing (written by `rtf train`)",
                dir.display(),
                log_path.display()
            );
        }
        if config.is_null() {
            bail!(
                "{}: missing (written by `rtf train`)",
                config_path.display()
            );
        }
        runs.push(Run {
            label: label.clone(),
            dir: dir.to_path_buf(),
            log: read_log(&log_path)?,
            config: config.clone(),
        });
    }
    for stage in stages {
        let sub = dir.join(&stage);
        let sub_log = sub.join("log.jsonl");
        if !sub_log.exists() {
            bail!(
                "{}: stage `{stage}` listed in {} has no log",
                sub_log.display(),
                config_path.display()
            );
        }
        let sub_config = sub.join("config.json");
        runs.push(Run {
            label: format!("{label} / {stage}"),
            dir: sub.clone(),
            config: if sub_config.exists() {
                read_json(&sub_config)?
            } else {
                Value::Null
            },
            log: read_log(&sub_log)?,
        });
    }
    Ok(runs)
}

fn load_eval(path: &Path) -> Result<EvalFile> {
    let json = read_json(path)?;
    let schema = json.get("schema").and_then(Value::as_str);
    let legacy = schema.is_none()
        && json.get("per_class").is_some_and(Value::is_array)
        && json.get("miou").is_some_and(Value::is_number);
    if schema != Some(EVAL_SCHEMA) && !legacy {
        bail!(
            "{}: not an `rtf eval --json` score file (schema {}, expected `{EVAL_SCHEMA}`)",
            path.display(),
            schema.map_or("missing".to_string(), |s| format!("`{s}`"))
        );
    }
    Ok(EvalFile {
        path: path.to_path_buf(),
        json,
    })
}

// ---------------------------------------------------------------------------------------------
// Values out of log records (old flat fields and the new nested maps).

/// A class's (name, day or overall IoU, night IoU).
type ClassRow = (String, Option<f64>, Option<f64>);
/// A run's masked network and the (width, height) it was trained at.
type RunNetwork = (Box<dyn rtf_models::Network>, Option<(usize, usize)>);

/// Named series of a run's log: (tag, points).
type Series = Vec<(String, Vec<(f64, f64)>)>;

fn series_of(log: &[Epoch], pick: impl Fn(&Value) -> Vec<(String, f64)>) -> Series {
    let mut map: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    for e in log {
        for (name, v) in pick(&e.raw) {
            if v.is_finite() {
                map.entry(name).or_default().push((e.epoch, v));
            }
        }
    }
    map.into_iter().collect()
}

fn numbers_of(map: Option<&Value>, prefix: &str) -> Vec<(String, f64)> {
    map.and_then(Value::as_object)
        .map(|m| {
            m.iter()
                .filter_map(|(k, v)| v.as_f64().map(|v| (format!("{prefix}{k}"), v)))
                .collect()
        })
        .unwrap_or_default()
}

fn loss_series(log: &[Epoch]) -> Series {
    series_of(log, |r| {
        let mut out = numbers_of(r.get("losses"), "");
        if let Some(v) = r.get("train_loss").and_then(Value::as_f64) {
            out.push(("total".into(), v));
        }
        out
    })
}

fn lr_series(log: &[Epoch]) -> Series {
    series_of(log, |r| {
        let mut out = numbers_of(r.get("lrs"), "");
        if out.is_empty() {
            if let Some(v) = r.get("lr").and_then(Value::as_f64) {
                out.push(("lr".into(), v));
            }
        }
        out
    })
}

fn val_series(log: &[Epoch]) -> Series {
    series_of(log, |r| {
        let val = r.get("val");
        let mut out = Vec::new();
        for key in ["miou", "macc", "miou_day", "miou_night", "miou_heatnet"] {
            if let Some(v) = val.and_then(|v| v.get(key)).and_then(Value::as_f64) {
                out.push((key.to_string(), v));
            }
        }
        for (flat, key) in [("val_miou", "miou"), ("val_macc", "macc")] {
            if !out.iter().any(|(k, _)| k == key) {
                if let Some(v) = r.get(flat).and_then(Value::as_f64) {
                    out.push((key.to_string(), v));
                }
            }
        }
        out.extend(numbers_of(r.get("metrics"), ""));
        out
    })
}

/// (class, day IoU, night IoU) of the last record with per-class IoU; day/night fall back to
/// the overall IoU in the first column when the log has no split.
fn last_class_iou(log: &[Epoch]) -> Option<Vec<ClassRow>> {
    let val = log.iter().rev().find_map(|e| {
        e.raw
            .get("val")
            .filter(|v| v.get("per_class_iou").is_some() || v.get("per_class_iou_day").is_some())
    })?;
    let get = |key: &str| val.get(key).and_then(Value::as_object);
    let (first, second) = match (get("per_class_iou_day"), get("per_class_iou_night")) {
        (Some(d), n) => (d, n),
        (None, _) => (get("per_class_iou")?, None),
    };
    Some(
        first
            .iter()
            .map(|(k, v)| {
                (
                    k.clone(),
                    v.as_f64(),
                    second.and_then(|n| n.get(k)).and_then(Value::as_f64),
                )
            })
            .collect(),
    )
}

// ---------------------------------------------------------------------------------------------
// Charts (plotters, SVG).

const W: u32 = 560;
const H: u32 = 300;
/// At most this many labelled ticks per axis, whatever the number of epochs: plotters picks
/// "nice" values (1, 2, 5 × 10^k steps) up to this count, so a 500-epoch run stays legible.
const X_TICKS: usize = 8;
const Y_TICKS: usize = 6;

/// An epoch tick: whole epochs without decimals, the half steps a 2-epoch run gets with one.
fn epoch_label(x: &f64) -> String {
    if x.fract().abs() < 1e-9 {
        format!("{x:.0}")
    } else {
        format!("{x:.1}")
    }
}

fn plot_err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("drawing a chart: {e:?}")
}

/// plotters lays text out with a registered TrueType font (the workspace builds it with
/// `ab_glyph` for the calibration plots): register the system's DejaVu Sans as "sans-serif",
/// once.
fn register_font() -> Result<()> {
    static REGISTERED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            let font = [
                "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
                "/usr/share/fonts/dejavu/DejaVuSans.ttf",
                "/usr/share/fonts/TTF/DejaVuSans.ttf",
            ]
            .iter()
            .find_map(|p| std::fs::read(p).ok())
            .ok_or("no TrueType font for the charts (install DejaVu Sans: fonts-dejavu-core)")?;
            plotters::style::register_font(
                "sans-serif",
                plotters::style::FontStyle::Normal,
                Box::leak(font.into_boxed_slice()),
            )
            .map_err(|_| "cannot register DejaVu Sans for the charts".to_string())
        })
        .clone()
        .map_err(anyhow::Error::msg)
}

fn colour(i: usize) -> RGBColor {
    const C: [RGBColor; 8] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
    ];
    C[i % C.len()]
}

/// A line chart of `series` against epoch.
fn line_chart(title: &str, y_desc: &str, series: &Series, log_y: bool) -> Result<String> {
    register_font()?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let points = || series.iter().flat_map(|(_, p)| p.iter());
        let (x0, x1) = points().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
        let (x0, x1) = if x0 < x1 {
            (x0, x1)
        } else {
            (x0 - 1.0, x0 + 1.0)
        };
        let mut chart_builder = ChartBuilder::on(&root);
        chart_builder
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(32)
            .y_label_area_size(56);
        if log_y {
            let positive = || points().map(|p| p.1).filter(|v| *v > 0.0);
            let lo = positive().fold(f64::MAX, f64::min);
            let hi = positive().fold(f64::MIN, f64::max);
            let (lo, hi) = if lo <= hi {
                (lo / 1.5, hi * 1.5)
            } else {
                (1e-6, 1.0)
            };
            let mut chart = chart_builder
                .build_cartesian_2d(x0..x1, (lo..hi).log_scale())
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_desc("epoch")
                .y_desc(y_desc)
                .x_labels(X_TICKS)
                .y_labels(Y_TICKS)
                .x_label_formatter(&epoch_label)
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .draw()
                .map_err(plot_err)?;
            // A log axis cannot show zero or negative values: those points are left out.
            draw_lines(&mut chart, series, |p| p.1 > 0.0)?;
        } else {
            let lo = points().map(|p| p.1).fold(f64::MAX, f64::min).min(0.0);
            let hi = points().map(|p| p.1).fold(f64::MIN, f64::max);
            let hi = if hi > lo { hi * 1.05 } else { lo + 1.0 };
            let mut chart = chart_builder
                .build_cartesian_2d(x0..x1, lo..hi)
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_desc("epoch")
                .y_desc(y_desc)
                .x_labels(X_TICKS)
                .y_labels(Y_TICKS)
                .x_label_formatter(&epoch_label)
                .draw()
                .map_err(plot_err)?;
            draw_lines(&mut chart, series, |_| true)?;
        }
        root.present().map_err(plot_err)?;
    }
    Ok(svg)
}

/// Each series as a coloured line (the points `keep` accepts) with its legend entry, then
/// the legend box.
fn draw_lines<'a, DB, CT>(
    chart: &mut ChartContext<'a, DB, CT>,
    series: &Series,
    keep: impl Fn(&(f64, f64)) -> bool,
) -> Result<()>
where
    DB: DrawingBackend + 'a,
    CT: CoordTranslate<From = (f64, f64)>,
{
    for (i, (name, pts)) in series.iter().enumerate() {
        let c = colour(i);
        let pts: Vec<(f64, f64)> = pts.iter().copied().filter(|p| keep(p)).collect();
        chart
            .draw_series(LineSeries::new(pts, c.stroke_width(2)))
            .map_err(plot_err)?
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)?;
    Ok(())
}

/// Longest class name drawn whole in the bar chart's name column; longer names are cut with
/// an ellipsis so that they never run into the bars (DejaVu Sans 12 px ≈ 7 px a character).
const CLASS_NAME_CHARS: usize = 20;

fn short_name(name: &str) -> String {
    if name.chars().count() <= CLASS_NAME_CHARS {
        name.to_string()
    } else {
        let head: String = name.chars().take(CLASS_NAME_CHARS - 1).collect();
        format!("{head}…")
    }
}

/// Horizontal bars of per-class IoU by class name, day and night side by side. Three columns
/// that cannot overlap: names (x < 0, cut to [`CLASS_NAME_CHARS`]), bars (0..1), values
/// (x > 1); one 26 px row per class.
fn class_bars(title: &str, rows: &[ClassRow], labels: [&str; 2]) -> Result<String> {
    register_font()?;
    let n = rows.len().max(1);
    let height = 76 + 26 * n as u32;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (W + 80, height)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(28)
            .y_label_area_size(4)
            // A strip above the rows for the legend.
            .build_cartesian_2d(-0.6f64..1.3f64, 0f64..n as f64 + 0.6)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .disable_y_mesh()
            .y_labels(0)
            .x_desc("IoU")
            .x_label_formatter(&|x| {
                // The 0 tick may come out as -1e-17.
                if (-1e-9..=1.0 + 1e-9).contains(x) {
                    format!("{:.1}", x.abs())
                } else {
                    String::new()
                }
            })
            .draw()
            .map_err(plot_err)?;
        let has_second = rows.iter().any(|r| r.2.is_some());
        for (i, (name, a, b)) in rows.iter().enumerate() {
            let y = (n - 1 - i) as f64;
            let bars = if has_second {
                [(a, y + 0.1, y + 0.5, 0), (b, y + 0.5, y + 0.9, 1)]
            } else {
                [(a, y + 0.15, y + 0.85, 0), (&None, 0.0, 0.0, 1)]
            };
            for (v, lo, hi, c) in bars {
                if let Some(v) = v {
                    chart
                        .draw_series([Rectangle::new([(0.0, lo), (*v, hi)], colour(c).filled())])
                        .map_err(plot_err)?;
                }
            }
            let value =
                |v: &Option<f64>| v.map_or("-".to_string(), |v| format!("{:.1}", 100.0 * v));
            let values = if has_second {
                format!("{}/{}", value(a), value(b))
            } else {
                value(a)
            };
            let font = ("sans-serif", 12);
            chart
                .draw_series([
                    Text::new(short_name(name), (-0.59, y + 0.7), font),
                    Text::new(values, (1.02, y + 0.7), font),
                ])
                .map_err(plot_err)?;
        }
        bar_legend(&mut chart, n, &labels[..if has_second { 2 } else { 1 }])?;
        root.present().map_err(plot_err)?;
    }
    Ok(svg)
}

type BarChart<'a, 'b> = ChartContext<
    'a,
    SVGBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// The bar colours' legend, in the strip above the top row.
fn bar_legend(chart: &mut BarChart, n: usize, labels: &[&str]) -> Result<()> {
    for (k, label) in labels.iter().enumerate() {
        let x = 0.55 + 0.22 * k as f64;
        chart
            .draw_series([Rectangle::new(
                [(x, n as f64 + 0.5), (x + 0.04, n as f64 + 0.25)],
                colour(k).filled(),
            )])
            .map_err(plot_err)?;
        chart
            .draw_series([Text::new(
                label.to_string(),
                (x + 0.05, n as f64 + 0.5),
                ("sans-serif", 12),
            )])
            .map_err(plot_err)?;
    }
    Ok(())
}

/// Row-normalised confusion matrix as a heat map (rows = truth, columns = prediction).
fn heat_map(title: &str, names: &[String], counts: &[Vec<u64>]) -> Result<String> {
    register_font()?;
    let n = names.len().max(1) as u32;
    let cell = (420 / n).clamp(18, 40);
    let (left, top) = (110u32, 40u32);
    let bottom = 100u32;
    let (width, height) = (left + n * cell + 20, top + n * cell + bottom);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        root.draw(&Text::new(title.to_string(), (10, 10), ("sans-serif", 16)))
            .map_err(plot_err)?;
        for (t, row) in counts.iter().enumerate() {
            let total: u64 = row.iter().sum();
            for (p, &c) in row.iter().enumerate() {
                let frac = if total > 0 {
                    c as f64 / total as f64
                } else {
                    0.0
                };
                let shade = |full: u8| (255.0 - frac * (255.0 - full as f64)).round() as u8;
                let colour = RGBColor(shade(8), shade(48), shade(107));
                let (x, y) = (left + p as u32 * cell, top + t as u32 * cell);
                root.draw(&Rectangle::new(
                    [(x as i32, y as i32), ((x + cell) as i32, (y + cell) as i32)],
                    colour.filled(),
                ))
                .map_err(plot_err)?;
                if cell >= 26 && total > 0 {
                    let text_colour = if frac > 0.5 { WHITE } else { BLACK };
                    root.draw(&Text::new(
                        format!("{:.0}", 100.0 * frac),
                        (x as i32 + 3, y as i32 + cell as i32 / 2 - 5),
                        ("sans-serif", 10).into_font().color(&text_colour),
                    ))
                    .map_err(plot_err)?;
                }
            }
        }
        for (i, name) in names.iter().enumerate() {
            let y = top + i as u32 * cell + cell / 2 - 6;
            root.draw(&Text::new(name.clone(), (6, y as i32), ("sans-serif", 12)))
                .map_err(plot_err)?;
            let x = left + i as u32 * cell + cell / 2 - 6;
            root.draw(&Text::new(
                name.clone(),
                (x as i32, (top + n * cell + 6) as i32),
                ("sans-serif", 12)
                    .into_font()
                    .transform(FontTransform::Rotate90),
            ))
            .map_err(plot_err)?;
        }
        root.draw(&Text::new(
            "rows: truth, columns: prediction, % of the row".to_string(),
            (10, (height - 16) as i32),
            ("sans-serif", 12),
        ))
        .map_err(plot_err)?;
        root.present().map_err(plot_err)?;
    }
    Ok(svg)
}

// ---------------------------------------------------------------------------------------------
// HTML.

fn esc(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn img(mime: &str, bytes: &[u8], alt: &str) -> String {
    format!(
        "<img alt=\"{}\" src=\"data:{mime};base64,{}\">",
        esc(alt),
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

fn svg_img(svg: &str, alt: &str) -> String {
    img("image/svg+xml", svg.as_bytes(), alt)
}

fn pct(v: Option<f64>) -> String {
    v.map_or("–".to_string(), |v| format!("{:.1}", 100.0 * v))
}

/// Scalar leaves of a JSON value as `a.b.c = v` rows (arrays of more than 8 items elided).
fn flatten_config(prefix: &str, value: &Value, out: &mut Vec<(String, String)>) {
    match value {
        Value::Object(map) => {
            for (k, v) in map {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten_config(&key, v, out);
            }
        }
        Value::Array(items) if items.len() > 8 => {
            out.push((prefix.into(), format!("[{} items]", items.len())))
        }
        Value::Null => {}
        other => out.push((prefix.into(), other.to_string())),
    }
}

fn last(series: &Series, name: &str) -> Option<f64> {
    series
        .iter()
        .find(|(n, _)| n == name)
        .and_then(|(_, p)| p.last().map(|p| p.1))
}

/// An epoch number as people write it (`80`, not `80.0`).
fn epoch_text(epoch: f64) -> String {
    epoch_label(&epoch)
}

/// The (epoch, value) of the highest point of `name` (the first epoch on a tie).
fn best_point(series: &Series, name: &str) -> Option<(f64, f64)> {
    let (_, points) = series.iter().find(|(n, _)| n == name)?;
    points
        .iter()
        .copied()
        .fold(None, |acc: Option<(f64, f64)>, p| match acc {
            Some(a) if a.1 >= p.1 => Some(a),
            _ => Some(p),
        })
}

fn last_point(series: &Series, name: &str) -> Option<(f64, f64)> {
    let (_, points) = series.iter().find(|(n, _)| n == name)?;
    points.last().copied()
}

/// The answer first: final and best validation mIoU (with its epoch), mAcc, day and night,
/// each the last validation's value, as large figures.
fn headline(run: &Run, html: &mut String) -> Result<()> {
    let val = val_series(&run.log);
    let Some((final_epoch, final_miou)) = last_point(&val, "miou") else {
        let loss =
            last(&loss_series(&run.log), "total").map_or("–".into(), |v| format!("{v:.4}"));
        writeln!(
            html,
            "<p class=\"headline\">No validation score in the log (a run with <code>--val-split none</code>?); final training loss {loss}.</p>"
        )?;
        return Ok(());
    };
    let (best_epoch, best_miou) = best_point(&val, "miou").unwrap_or((final_epoch, final_miou));
    let mut figures = vec![
        (
            pct(Some(final_miou)),
            format!("final mIoU (epoch {})", epoch_text(final_epoch)),
        ),
        (
            pct(Some(best_miou)),
            format!("best mIoU (epoch {})", epoch_text(best_epoch)),
        ),
    ];
    for (key, label) in [
        ("macc", "mAcc"),
        ("miou_day", "mIoU day"),
        ("miou_night", "mIoU night"),
    ] {
        if let Some(v) = last(&val, key) {
            figures.push((pct(Some(v)), label.to_string()));
        }
    }
    writeln!(html, "<div class=\"headline\">")?;
    for (value, label) in figures {
        writeln!(
            html,
            "<div class=\"figure\"><span class=\"value\">{value}</span><span class=\"label\">{}</span></div>",
            esc(&label)
        )?;
    }
    writeln!(html, "</div>")?;
    Ok(())
}

/// A run's answer (headline, per-class IoU bars), then its curves, then (when `with_config`)
/// its whole configuration, collapsed: what people look for first comes first.
fn run_section(run: &Run, with_config: bool, html: &mut String) -> Result<()> {
    writeln!(
        html,
        "<section class=\"run\"><h2>Run {}</h2>\n<p class=\"path\">{}</p>",
        esc(&run.label),
        esc(&run.dir.display().to_string())
    )?;
    if run.log.is_empty() {
        writeln!(html, "<p>No epoch finished yet (empty log).</p>")?;
    } else {
        headline(run, html)?;
        writeln!(html, "<div class=\"charts\">")?;
        if let Some(classes) = last_class_iou(&run.log) {
            let labels = if classes.iter().any(|c| c.2.is_some()) {
                ["day", "night"]
            } else {
                ["all", ""]
            };
            let svg = class_bars("Per-class IoU (last validation), %", &classes, labels)?;
            writeln!(html, "{}", svg_img(&svg, "per-class IoU bars"))?;
        }
        curves(run, html)?;
        writeln!(html, "</div>")?;
    }
    if with_config {
        config_details(&run.config, html)?;
    }
    writeln!(html, "</section>")?;
    Ok(())
}

/// Validation, loss and learning-rate curves of one run.
fn curves(run: &Run, html: &mut String) -> Result<()> {
    let val = val_series(&run.log);
    if !val.is_empty() {
        let svg = line_chart("Validation", "score", &val, false)?;
        writeln!(html, "{}", svg_img(&svg, "validation mIoU curves"))?;
    }
    let losses = loss_series(&run.log);
    if !losses.is_empty() {
        let svg = line_chart("Training loss", "loss", &losses, false)?;
        writeln!(html, "{}", svg_img(&svg, "training loss curves"))?;
    }
    let lrs = lr_series(&run.log);
    if !lrs.is_empty() {
        let svg = line_chart("Learning rate", "lr", &lrs, true)?;
        writeln!(html, "{}", svg_img(&svg, "learning rate"))?;
    }
    Ok(())
}

/// The whole configuration as `a.b.c = v` rows, collapsed (`<details>` without `open`).
fn config_details(config: &Value, html: &mut String) -> Result<()> {
    let mut rows = Vec::new();
    flatten_config("", config, &mut rows);
    if rows.is_empty() {
        return Ok(());
    }
    writeln!(
        html,
        "<details class=\"config\"><summary>Configuration ({} settings)</summary><table class=\"config\">",
        rows.len()
    )?;
    for (k, v) in rows {
        writeln!(html, "<tr><th>{}</th><td>{}</td></tr>", esc(&k), esc(&v))?;
    }
    writeln!(html, "</table></details>")?;
    Ok(())
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

fn eval_section(eval: &EvalFile, html: &mut String) -> Result<()> {
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
    let names: Vec<String> = serde_json::from_value(names.clone())
        .with_context(|| format!("{}: `class_names` is not a list of names", path.display()))?;
    let matrix: Vec<Vec<u64>> = serde_json::from_value(matrix.clone())
        .with_context(|| format!("{}: `confusion` is not a matrix of counts", path.display()))?;
    if matrix.len() != names.len() || matrix.iter().any(|r| r.len() != names.len()) {
        bail!(
            "{}: `confusion` is not {n}×{n} like `class_names`",
            path.display(),
            n = names.len()
        );
    }
    Ok((names, matrix))
}

fn model_name(run: &Run) -> String {
    let model = setting(&run.config, "model");
    model
        .get("network")
        .or_else(|| (!model.is_null()).then_some(model))
        .map(|v| v.as_str().map_or_else(|| v.to_string(), str::to_string))
        .unwrap_or_else(|| "?".into())
}

/// A setting of a run's `config.json`, in its section (`data.dataset`) or at the top level
/// (the flat layout written before the sections); null when absent.
fn setting<'a>(config: &'a Value, key: &str) -> &'a Value {
    config
        .get(key)
        .or_else(|| {
            rtf_train::config::SECTIONS
                .iter()
                .find_map(|s| config.get(s)?.get(key))
        })
        .unwrap_or(&Value::Null)
}

/// Several runs (or stages): the final and best metrics table, the curves overlaid, and the
/// configuration settings that differ.
fn compare_section(runs: &[Run], html: &mut String) -> Result<()> {
    writeln!(html, "<section class=\"compare\"><h2>Side by side</h2>")?;
    comparison_table(runs, html)?;
    writeln!(html, "<div class=\"charts\">")?;
    for (key, title, pick) in [
        (
            "miou",
            "Validation mIoU",
            val_series as fn(&[Epoch]) -> Series,
        ),
        ("total", "Training loss", loss_series),
    ] {
        let overlaid: Series = runs
            .iter()
            .filter_map(|r| {
                let series = pick(&r.log);
                let (_, points) = series.into_iter().find(|(n, _)| n == key)?;
                Some((r.label.clone(), points))
            })
            .collect();
        if !overlaid.is_empty() {
            let svg = line_chart(title, key, &overlaid, false)?;
            writeln!(
                html,
                "{}",
                svg_img(&svg, &format!("{title}, runs overlaid"))
            )?;
        }
    }
    writeln!(html, "</div>")?;
    config_differences(runs, html)?;
    writeln!(html, "</section>")?;
    Ok(())
}

fn comparison_table(runs: &[Run], html: &mut String) -> Result<()> {
    writeln!(html, "<table class=\"compare\"><tr><th>run</th><th>model</th><th>epochs</th><th>final loss</th><th>final mIoU</th><th>best mIoU</th><th>best epoch</th><th>final mAcc</th><th>day</th><th>night</th><th>images/s</th></tr>")?;
    for run in runs {
        let val = val_series(&run.log);
        let loss = loss_series(&run.log);
        let best = best_point(&val, "miou");
        let speed = run
            .log
            .last()
            .and_then(|e| e.raw.get("images_per_s"))
            .and_then(Value::as_f64)
            .map_or("–".into(), |v| format!("{v:.1}"));
        writeln!(
            html,
            "<tr><th>{}</th><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&run.label),
            esc(&model_name(run)),
            run.log.len(),
            last(&loss, "total").map_or("–".into(), |v| format!("{v:.4}")),
            pct(last(&val, "miou")),
            pct(best.map(|b| b.1)),
            best.map_or("–".into(), |b| epoch_text(b.0)),
            pct(last(&val, "macc")),
            pct(last(&val, "miou_day")),
            pct(last(&val, "miou_night")),
            speed
        )?;
    }
    writeln!(html, "</table>")?;
    Ok(())
}

/// The settings whose values are not the same in every run (missing counts as a value: `–`).
fn differing_settings(runs: &[Run]) -> BTreeMap<String, Vec<String>> {
    let flat: Vec<BTreeMap<String, String>> = runs
        .iter()
        .map(|r| {
            let mut rows = Vec::new();
            flatten_config("", &r.config, &mut rows);
            rows.into_iter().collect()
        })
        .collect();
    let keys: std::collections::BTreeSet<&String> = flat.iter().flat_map(|m| m.keys()).collect();
    keys.into_iter()
        .map(|k| {
            let values = flat
                .iter()
                .map(|m| m.get(k).cloned().unwrap_or_else(|| "–".into()));
            (k.clone(), values.collect::<Vec<_>>())
        })
        .filter(|(_, values)| values.iter().any(|v| *v != values[0]))
        .collect()
}

fn config_differences(runs: &[Run], html: &mut String) -> Result<()> {
    let differing = differing_settings(runs);
    writeln!(html, "<h3>Configuration differences</h3>")?;
    if differing.is_empty() {
        writeln!(html, "<p>The runs have the same configuration.</p>")?;
        return Ok(());
    }
    write!(html, "<table class=\"config-diff\"><tr><th>setting</th>")?;
    for run in runs {
        write!(html, "<th>{}</th>", esc(&run.label))?;
    }
    writeln!(html, "</tr>")?;
    for (key, values) in differing {
        write!(html, "<tr><th>{}</th>", esc(&key))?;
        for v in values {
            write!(html, "<td>{}</td>", esc(&v))?;
        }
        writeln!(html, "</tr>")?;
    }
    writeln!(html, "</table>")?;
    Ok(())
}

/// The prediction grid as PNG bytes, or why there is none.
fn prediction_grid(args: &Args, runs: &[Run]) -> Result<Option<Vec<u8>>, String> {
    if args.frames == 0 {
        return Ok(None);
    }
    let with_weights: Vec<(&Run, PathBuf)> = runs
        .iter()
        .filter_map(|r| {
            ["final.safetensors", "best.safetensors"]
                .iter()
                .map(|f| r.dir.join(f))
                .find(|p| p.exists())
                .map(|p| (r, p))
        })
        .collect();
    if with_weights.is_empty() {
        return Err("no run folder holds final.safetensors or best.safetensors".into());
    }
    let (root, split) = grid_dataset(args, with_weights[0].0)?;
    if !root.exists() {
        return Err(format!(
            "dataset {} not found (give --data)",
            root.display()
        ));
    }
    draw_prediction_grid(args, &with_weights, &root, &split)
        .map(Some)
        .map_err(|e| format!("{e:#}"))
}

/// The dataset the grid is drawn from: `--data` and `--split`, else the first run's dataset
/// root and validation split.
fn grid_dataset(args: &Args, run: &Run) -> Result<(PathBuf, String), String> {
    if let Some(root) = &args.data {
        return Ok((root.clone(), args.split.clone()));
    }
    let ds = setting(&run.config, "dataset");
    let root = ds
        .get("root")
        .and_then(Value::as_str)
        .ok_or("no --data and the run's config names no dataset root")?;
    let split = ds
        .get("val_split")
        .and_then(Value::as_str)
        .unwrap_or(&args.split);
    Ok((PathBuf::from(root), split.to_string()))
}

/// The PNG: the same frames for every run, one prediction column per run.
fn draw_prediction_grid(
    args: &Args,
    with_weights: &[(&Run, PathBuf)],
    root: &Path,
    split: &str,
) -> Result<Vec<u8>> {
    let device = rtf_train::config::available_device(&args.device).map_err(anyhow::Error::msg)?;
    let (source, _) = super::eval::open_split(root, split)?;
    let classes = source.class_set().clone();
    let mut rows = None;
    let mut columns = Vec::new();
    for (run, weights) in with_weights {
        let (net, resize) = run_network(run, weights, device)?;
        let rows = match &mut rows {
            Some(rows) => rows,
            None => rows.insert(rtf_eval::figure::rows_for(
                net.as_ref(),
                source.as_ref(),
                args.frames,
                resize,
                device,
            )?),
        };
        let ids = rows
            .iter()
            .map(|row| rtf_eval::figure::predict_row(net.as_ref(), row, device))
            .collect::<Result<Vec<_>, _>>()?;
        columns.push(rtf_eval::figure::PredictionColumn {
            title: run.label.clone(),
            ids,
        });
    }
    let image =
        rtf_eval::figure::annotated_grid(rows.as_deref().unwrap_or(&[]), &columns, &classes);
    let mut png = Vec::new();
    image.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
    Ok(png)
}

/// A run's network with its weights, behind the input mask it was trained with (RGB-only,
/// thermal-only runs), and the resize it was trained at.
fn run_network(run: &Run, weights: &Path, device: tch::Device) -> Result<RunNetwork> {
    let cfg: rtf_models::ModelConfig =
        serde_json::from_value(setting(&run.config, "model").clone()).with_context(|| {
            format!(
                "{}: `model` is not a network configuration",
                run.dir.join("config.json").display()
            )
        })?;
    let mut vs = tch::nn::VarStore::new(device);
    let net = rtf_models::build(&vs.root(), &cfg)?;
    rtf_models::weights::load_safetensors(&mut vs, weights)?;
    let inputs = serde_json::from_value(setting(&run.config, "inputs").clone())
        .ok()
        .unwrap_or_default();
    let resize = serde_json::from_value(setting(&run.config, "resize").clone())
        .ok()
        .flatten();
    Ok((rtf_models::masked(net, inputs), resize))
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

/// `--out` naming a file the report reads (a run's config.json or log.jsonl, an --eval file;
/// also through `..` or a link) is refused before anything is written.
fn refuse_overwriting_inputs(out: &Path, runs: &[Run], evals: &[PathBuf]) -> Result<()> {
    let Ok(out_path) = out.canonicalize() else {
        return Ok(());
    };
    let inputs = runs
        .iter()
        .flat_map(|r| [r.dir.join("config.json"), r.dir.join("log.jsonl")])
        .chain(evals.iter().cloned());
    for input in inputs {
        if input.canonicalize().is_ok_and(|p| p == out_path) {
            bail!(
                "--out {}: is {}, which the report reads; refusing to overwrite it",
                out.display(),
                input.display()
            );
        }
    }
    Ok(())
}

pub fn run(args: Args) -> Result<()> {
    let mut runs = Vec::new();
    for dir in &args.runs {
        runs.extend(load_runs(dir)?);
    }
    let evals = args
        .evals
        .iter()
        .map(|p| load_eval(p))
        .collect::<Result<Vec<_>>>()?;
    refuse_overwriting_inputs(&args.out, &runs, &args.evals)?;
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
        compare_section(&runs, &mut html)?;
    }
    for run in &runs {
        // Comparing: the differences above stand for the configurations.
        run_section(run, !comparing, &mut html)?;
    }
    for eval in &evals {
        eval_section(eval, &mut html)?;
    }
    match prediction_grid(&args, &runs) {
        Ok(Some(png)) => writeln!(
            html,
            "<section><h2>Predictions</h2>{}</section>",
            img("image/png", &png, "prediction grid").replace("<img ", "<img class=\"grid\" ")
        )?,
        Ok(None) => {}
        Err(why) => {
            eprintln!("report: no prediction grid: {why}");
            writeln!(
                html,
                "<section><h2>Predictions</h2><p>No prediction grid: {}</p></section>",
                esc(&why)
            )?;
        }
    }
    writeln!(html, "</body></html>")?;
    rtf_core::write_bytes_atomic(&args.out, html.as_bytes())
        .with_context(|| format!("writing {}", args.out.display()))?;
    println!("report: {}", args.out.display());
    Ok(())
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
    fn old_and_new_log_records_give_series() {
        let log: Vec<Epoch> = [
            serde_json::json!({"epoch": 1, "lr": 0.01, "train_loss": 2.0, "val_miou": 0.1}),
            serde_json::json!({"epoch": 2, "lr": 0.01, "train_loss": 1.0, "losses": {"ce": 0.9},
                               "lrs": {"seg": 0.01, "critic": 0.001},
                               "val": {"miou": 0.2, "miou_day": 0.3, "miou_night": 0.1,
                                       "per_class_iou_day": {"car": 0.5, "person": null},
                                       "per_class_iou_night": {"car": 0.25}}}),
        ]
        .into_iter()
        .map(|raw| Epoch {
            epoch: raw["epoch"].as_f64().unwrap(),
            raw,
        })
        .collect();
        let loss = loss_series(&log);
        assert_eq!(last(&loss, "total"), Some(1.0));
        assert_eq!(last(&loss, "ce"), Some(0.9));
        let lr = lr_series(&log);
        assert_eq!(
            lr.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>(),
            ["critic", "lr", "seg"],
            "sorted by name; the flat `lr` only where a record has no `lrs`"
        );
        let val = val_series(&log);
        assert_eq!(best_point(&val, "miou"), Some((2.0, 0.2)));
        assert_eq!(last(&val, "miou_night"), Some(0.1));
        let classes = last_class_iou(&log).unwrap();
        assert_eq!(classes[0], ("car".to_string(), Some(0.5), Some(0.25)));
        assert_eq!(classes[1], ("person".to_string(), None, None));
    }

    #[test]
    fn charts_are_svg_with_their_titles() {
        let series = vec![("total".to_string(), vec![(1.0, 2.0), (2.0, 1.0)])];
        let svg = line_chart("Training loss", "loss", &series, false).unwrap();
        assert!(
            svg.starts_with("<svg") && svg.contains("Training loss") && svg.contains("<polyline")
        );
        let bars = class_bars(
            "IoU",
            &[("car".into(), Some(0.5), Some(0.25))],
            ["day", "night"],
        )
        .unwrap();
        let texts = svg_texts(&bars);
        assert!(texts.contains(&"car".to_string()) && texts.contains(&"50.0/25.0".to_string()));
        let heat = heat_map(
            "Confusion",
            &["a".into(), "b".into()],
            &[vec![3, 1], vec![0, 4]],
        )
        .unwrap();
        assert!(heat.contains("Confusion") && heat.matches("<rect").count() >= 4);
    }

    /// Randomised run (`rtf_data::fuzzing`): seeded mutations of a run's `log.jsonl` and
    /// `config.json` and random bytes; the run loads and its section renders, or an error
    /// names the file; never a panic.
    #[test]
    fn mutated_logs_and_configs_never_panic() {
        let dir = tempfile::tempdir().unwrap();
        let record = |epoch: usize, miou: f64| {
            serde_json::json!({"epoch": epoch, "lr": 0.01, "train_loss": 2.0 - miou,
                "losses": {"ce": 1.5}, "lrs": {"student": 0.01}, "images": 16,
                "val": {"miou": miou, "macc": miou + 0.1, "miou_day": miou, "miou_night": null,
                        "per_class_iou": {"car": miou, "person": 0.5, "bike": null}}})
            .to_string()
        };
        let log: String = (0..4).map(|e| record(e, 0.1 * e as f64) + "\n").collect();
        let config = serde_json::json!({"model": {"network": "mfnet", "num_classes": 9},
            "epochs": 4, "batch_size": 2, "stages": null, "optimizer": {"lr": 0.01}})
        .to_string();
        std::fs::write(dir.path().join("config.json"), &config).unwrap();
        let render = || {
            let runs = load_runs(dir.path())?;
            let mut html = String::new();
            for run in &runs {
                run_section(run, true, &mut html)?;
            }
            anyhow::Ok(html.len())
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

    /// The contents of an SVG's `<text>` elements (plotters writes them on their own lines).
    fn svg_texts(svg: &str) -> Vec<String> {
        svg.split("<text")
            .skip(1)
            .filter_map(|t| {
                let body = &t[t.find('>')? + 1..t.find("</text>")?];
                Some(body.trim().to_string())
            })
            .collect()
    }

    fn run_with(label: &str, config: Value) -> Run {
        Run {
            label: label.into(),
            dir: PathBuf::from(label),
            config,
            log: Vec::new(),
        }
    }

    #[test]
    fn only_differing_settings_are_compared() {
        let runs = [
            run_with(
                "a",
                serde_json::json!({"model": {"network": "mfnet"}, "lr": 0.01, "seed": 1}),
            ),
            run_with(
                "b",
                serde_json::json!({"model": {"network": "rtfnet"}, "lr": 0.01}),
            ),
        ];
        let differing = differing_settings(&runs);
        assert_eq!(
            differing.into_iter().collect::<Vec<_>>(),
            [
                (
                    "model.network".to_string(),
                    vec!["\"mfnet\"".to_string(), "\"rtfnet\"".into()]
                ),
                ("seed".to_string(), vec!["1".to_string(), "–".into()]),
            ]
        );
    }

    #[test]
    fn long_class_names_are_cut_before_the_bars() {
        assert_eq!(short_name("car"), "car");
        let long = "a_very_long_class_name_indeed";
        let cut = short_name(long);
        assert_eq!(cut.chars().count(), CLASS_NAME_CHARS);
        assert!(cut.ends_with('…') && long.starts_with(cut.trim_end_matches('…')));
        assert_eq!(epoch_label(&80.0), "80");
        assert_eq!(epoch_label(&1.5), "1.5");
    }
}
