//! The speed and size tables (MFNet Tab. IV, RTFNet Tab. VII): `rtf bench model` on this
//! machine beside the paper's numbers, each column labelled with where it comes from. They
//! need no dataset (random weights).

use anyhow::{Context, Result};
use serde_json::json;
use std::fmt::Write as _;
use std::path::Path;

/// A paper's table: its columns and, per row, the rtf network measured for it.
pub struct Table {
    pub id: &'static str,
    pub title: &'static str,
    /// Where the paper measured (GPU names), for the column labels.
    paper_columns: &'static [&'static str],
    rows: &'static [Row],
}

struct Row {
    label: &'static str,
    network: &'static str,
    /// The paper's numbers, as printed ("" where the paper leaves the cell empty).
    paper: &'static [&'static str],
}

pub const TABLES: &[Table] = &[
    Table {
        id: "rtfnet-tab7",
        title: "RTFNet Tab. VII: inference speed, 480×640, 4-channel input",
        paper_columns: &[
            "GTX 1080 Ti ms",
            "GTX 1080 Ti FPS",
            "Jetson TX2 ms",
            "Jetson TX2 FPS",
        ],
        rows: &[
            Row {
                label: "ERFNet (4c)",
                network: "erfnet-4c",
                paper: &["5.81", "172.06", "38.89", "25.71"],
            },
            Row {
                label: "UNet (4c)",
                network: "unet-4c",
                paper: &["2.59", "386.63", "15.59", "64.13"],
            },
            Row {
                label: "PSPNet (4c)",
                network: "pspnet-4c",
                paper: &["9.09", "110.01", "49.23", "20.31"],
            },
            Row {
                label: "SegNet (4c)",
                network: "segnet-4c",
                paper: &["3.31", "302.30", "19.06", "52.47"],
            },
            Row {
                label: "DUC-HDC (4c)",
                network: "duchdc-4c",
                paper: &["12.21", "81.93", "67.40", "14.84"],
            },
            Row {
                label: "MFNet",
                network: "mfnet",
                paper: &["4.35", "229.86", "25.74", "38.85"],
            },
            Row {
                label: "FuseNet",
                network: "fusenet",
                paper: &["3.92", "255.27", "22.25", "44.94"],
            },
            Row {
                label: "RTFNet-50",
                network: "rtfnet50",
                paper: &["11.25", "88.87", "59.56", "16.79"],
            },
            Row {
                label: "RTFNet-152",
                network: "rtfnet152",
                paper: &["29.35", "34.07", "508.71", "1.97"],
            },
        ],
    },
    Table {
        id: "mfnet-tab4",
        title: "MFNet Tab. IV: inference speed and model size, 480×640",
        paper_columns: &[
            "Titan X FPS, RGB",
            "Titan X FPS, RGB+T",
            "parameters",
            "model size",
        ],
        rows: &[
            Row {
                label: "SegNet (RGB)",
                network: "segnet-3c",
                paper: &["8.3", "", "29.42M", "110.2MB"],
            },
            Row {
                label: "SegNet (RGB+T)",
                network: "segnet-4c",
                paper: &["", "8.3", "29.42M", "110.2MB"],
            },
            Row {
                label: "ENet (RGB)",
                network: "enet-3c",
                paper: &["66.7", "", "0.37M", "1.4MB"],
            },
            Row {
                label: "MFNet (RGB+T)",
                network: "mfnet",
                paper: &["", "55.6", "0.73M", "3.7MB"],
            },
        ],
    },
];

pub struct Options {
    /// WxH of the timed input (the papers: 640x480; the smoke budget times a small one).
    pub size: String,
    pub device: String,
    pub precision: String,
    pub warmup: usize,
    pub iterations: usize,
}

/// What rtf measured for one network.
#[derive(Debug, Clone, PartialEq)]
struct Measured {
    median_ms: f64,
    fps: f64,
    params: u64,
    megabytes: f64,
}

/// A number field of a JSON object printed by `rtf … --json` (flat, no nesting needed).
fn json_number(json: &serde_json::Value, key: &str) -> Result<f64> {
    json.get(key)
        .and_then(serde_json::Value::as_f64)
        .with_context(|| format!("rtf's JSON has no number `{key}`: {json}"))
}

/// `rtf models --json` → (params, megabytes) of `network`.
fn size_of(models: &serde_json::Value, network: &str) -> Result<(u64, f64)> {
    let entry = models
        .as_array()
        .and_then(|all| all.iter().find(|m| m["name"] == network))
        .with_context(|| format!("`rtf models --json` does not list `{network}`"))?;
    Ok((
        json_number(entry, "params")? as u64,
        json_number(entry, "megabytes")?,
    ))
}

/// The table in Markdown: the paper's columns as printed, then this machine's.
fn render(table: &Table, measured: &[Measured], context: &str) -> String {
    let mut out = format!("### {}\n\n{context}\n\n| network | rtf name |", table.title);
    for c in table.paper_columns {
        let _ = write!(out, " paper: {c} |");
    }
    out +=
        " measured: ms | measured: FPS | measured: parameters | measured: MiB (f32) |\n|---|---|";
    out += &"---:|".repeat(table.paper_columns.len() + 4);
    out += "\n";
    for (row, m) in table.rows.iter().zip(measured) {
        let _ = write!(out, "| {} | `{}` |", row.label, row.network);
        for cell in row.paper {
            let _ = write!(out, " {} |", if cell.is_empty() { "—" } else { cell });
        }
        let _ = writeln!(
            out,
            " {:.2} | {:.2} | {} | {:.2} |",
            m.median_ms, m.fps, m.params, m.megabytes
        );
    }
    out
}

/// Measures `table` and writes `<out>/<id>.md` and `.json` (paper values as printed, parsed to
/// numbers where they are numbers).
pub fn run(
    root: &Path,
    table: &Table,
    o: &Options,
    out: &Path,
    command: &str,
    budget: &str,
) -> Result<()> {
    let (measured, threads) = measure(root, table, o)?;
    let context = format!(
        "Paper columns: the paper's numbers as printed (its GPUs). Measured columns: `rtf bench \
         model` on this machine, device {} ({} threads), {} fast path, batch 1, {}, random \
         weights, median of {} passes after {} warm-up; parameters and f32 size from `rtf \
         models --json`. Command: `{command}`.",
        o.device,
        threads,
        o.precision,
        o.size.replace('x', "×"),
        o.iterations,
        o.warmup,
    );
    let text = render(table, &measured, &context);
    print!("{text}");
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let v = table_json(table, &measured, o, threads, command, budget);
    super::report::validate(&v)?;
    super::io::write_json(&out.join(format!("{}.json", table.id)), &v)?;
    super::io::write_atomic(&out.join(format!("{}.md", table.id)), text.as_bytes())?;
    eprintln!(
        "reproduce: wrote {}",
        out.join(format!("{}.md", table.id)).display()
    );
    Ok(())
}

/// Times every row's network with `rtf bench model` and sizes it with `rtf models`; returns
/// the measurements in row order and the thread count `rtf` ran with.
fn measure(root: &Path, table: &Table, o: &Options) -> Result<(Vec<Measured>, f64)> {
    let models: serde_json::Value =
        serde_json::from_str(&crate::rtf_stdout(root, &["models", "--json"])?)
            .context("parsing `rtf models --json`")?;
    let mut measured = Vec::new();
    let mut threads = 0.0;
    for row in table.rows {
        eprintln!("reproduce: timing {} ({}) ...", row.label, row.network);
        let bench = crate::rtf_stdout(
            root,
            &[
                "bench",
                "model",
                "--model",
                row.network,
                "--device",
                &o.device,
                "--precision",
                &o.precision,
                "--warmup",
                &o.warmup.to_string(),
                "--iterations",
                &o.iterations.to_string(),
                "--size",
                &o.size,
                "--json",
            ],
        )?;
        let bench: serde_json::Value =
            serde_json::from_str(&bench).context("parsing `rtf bench model --json`")?;
        threads = json_number(&bench, "threads")?;
        let (params, megabytes) = size_of(&models, row.network)?;
        measured.push(Measured {
            median_ms: json_number(&bench, "median_ms")?,
            fps: json_number(&bench, "fps")?,
            params,
            megabytes,
        });
    }
    Ok((measured, threads))
}

/// The leading number of a paper cell as printed ("29.42M" → 29.42); `None` for "" or text.
fn paper_number(s: &str) -> Option<f64> {
    let end = s
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(s.len());
    s[..end].parse().ok()
}

/// `<id>.json` in the results schema ([`super::report::validate`]): the paper's numbers and
/// this machine's, one seed each.
fn table_json(
    table: &Table,
    measured: &[Measured],
    o: &Options,
    threads: f64,
    command: &str,
    budget: &str,
) -> serde_json::Value {
    let rows: Vec<serde_json::Value> = table
        .rows
        .iter()
        .zip(measured)
        .map(|(row, m)| {
            let paper: serde_json::Map<String, serde_json::Value> = table
                .paper_columns
                .iter()
                .zip(row.paper)
                .filter_map(|(c, v)| Some((c.to_string(), json!(paper_number(v)?))))
                .collect();
            let one = |v: f64| json!({"mean": v, "std": 0.0, "seeds": [v]});
            json!({
                "label": row.label,
                "network": row.network,
                "paper": paper,
                "measured": {
                    "ms": one(m.median_ms),
                    "FPS": one(m.fps),
                    "parameters": one(m.params as f64),
                    "MiB (f32)": one(m.megabytes),
                },
            })
        })
        .collect();
    let mut columns: Vec<serde_json::Value> = table
        .paper_columns
        .iter()
        .map(|c| json!({"name": c, "paper": table.title, "measured": null}))
        .collect();
    for c in ["ms", "FPS", "parameters", "MiB (f32)"] {
        columns.push(json!({"name": c, "paper": null, "measured": "rtf bench model / rtf models"}));
    }
    json!({
        "table": table.id,
        "title": table.title,
        "budget": {"name": budget, "warmup": o.warmup, "iterations": o.iterations,
                   "precision": o.precision, "size": o.size},
        "data": "none",
        "device": o.device,
        "threads": threads,
        "protocol": {"convention": "speed: median ms per frame, batch 1, 480×640, random weights"},
        "columns": columns,
        "rows": rows,
        "claims": [],
        "command": command,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_row_has_a_paper_cell_per_column() {
        for t in TABLES {
            for row in t.rows {
                assert_eq!(
                    row.paper.len(),
                    t.paper_columns.len(),
                    "{} {}",
                    t.id,
                    row.label
                );
            }
        }
    }

    /// MFNet Tab. IV and one made-up measurement (every row gets it).
    fn mfnet_tab4_measured() -> (&'static Table, Measured) {
        let table = TABLES.iter().find(|t| t.id == "mfnet-tab4").unwrap();
        let m = Measured {
            median_ms: 44.0,
            fps: 22.7,
            params: 736275,
            megabytes: 2.81,
        };
        (table, m)
    }

    #[test]
    fn table_shows_paper_and_measured_columns_side_by_side() {
        let models = serde_json::json!([
            {"name": "mfnet", "params": 736275, "megabytes": 2.81},
            {"name": "segnet-3c", "params": 29443211, "megabytes": 112.3},
        ]);
        assert_eq!(size_of(&models, "mfnet").unwrap(), (736275, 2.81));
        assert!(size_of(&models, "nope").is_err());
        let (table, m) = mfnet_tab4_measured();
        let text = render(table, &vec![m; table.rows.len()], "ctx");
        let lines: Vec<&str> = text.lines().collect();
        assert!(lines[0].starts_with("### MFNet Tab. IV"));
        assert!(
            lines[4].contains("paper: Titan X FPS, RGB+T") && lines[4].contains("measured: FPS")
        );
        let mfnet = lines
            .iter()
            .find(|l| l.starts_with("| MFNet (RGB+T)"))
            .unwrap();
        assert_eq!(
            *mfnet,
            "| MFNet (RGB+T) | `mfnet` | — | 55.6 | 0.73M | 3.7MB | 44.00 | 22.70 | 736275 | 2.81 |"
        );
        // Header and separator have as many cells as the rows.
        let cells = |l: &str| l.matches('|').count();
        assert_eq!(cells(lines[4]), cells(mfnet));
        assert_eq!(cells(lines[5]), cells(mfnet));
    }

    #[test]
    fn json_holds_the_printed_paper_numbers_and_the_measurements_in_the_schema() {
        assert_eq!(paper_number("29.42M"), Some(29.42));
        assert_eq!(paper_number("55.6"), Some(55.6));
        assert_eq!(paper_number(""), None);
        let (table, m) = mfnet_tab4_measured();
        let o = Options {
            size: "96x64".into(),
            device: "cpu".into(),
            precision: "fp32".into(),
            warmup: 0,
            iterations: 1,
        };
        let v = table_json(table, &vec![m; table.rows.len()], &o, 2.0, "cmd", "smoke");
        super::super::report::validate(&v).unwrap();
        let rows = v["rows"].as_array().unwrap();
        assert_eq!(rows.len(), table.rows.len());
        let mfnet = rows.iter().find(|r| r["network"] == "mfnet").unwrap();
        // "" (not reported by the paper) is left out; "0.73M" and "3.7MB" keep their number.
        let paper = mfnet["paper"].as_object().unwrap();
        assert_eq!(paper.len(), 3, "{paper:?}");
        assert!(paper.values().any(|x| x == 0.73) && paper.values().any(|x| x == 3.7));
        assert_eq!(mfnet["measured"]["ms"]["mean"], 44.0);
        assert_eq!(mfnet["measured"]["parameters"]["seeds"][0], 736275.0);
        assert_eq!(v["threads"], 2.0);
        assert_eq!(v["budget"]["precision"], "fp32");
    }
}
