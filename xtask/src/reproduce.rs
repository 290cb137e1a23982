//! `cargo xtask reproduce <table>`: runs the measurements behind a table of the papers with the
//! release `rtf` binary and prints them beside the paper's own numbers, each column labelled
//! with where it comes from. So far the speed and size tables, which need no dataset.

use anyhow::{bail, Context, Result};
use std::fmt::Write as _;
use std::path::Path;

/// A paper's table: its columns and, per row, the rtf network measured for it.
struct Table {
    id: &'static str,
    title: &'static str,
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

const TABLES: &[Table] = &[
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

struct Options {
    table: &'static Table,
    device: String,
    precision: String,
    warmup: usize,
    iterations: usize,
    out: Option<String>,
}

fn usage() -> String {
    let mut text = String::from(
        "usage: cargo xtask reproduce <table> [--device cpu|cuda] [--precision fp32|bf16] \
         [--warmup N] [--iterations N] [--out FILE.md]\n\ntables:\n",
    );
    for t in TABLES {
        let _ = writeln!(text, "  {:<12} {}", t.id, t.title);
    }
    text
}

fn parse(args: &[String]) -> Result<Options> {
    let Some(id) = args.first().filter(|a| !a.starts_with('-')) else {
        bail!("{}", usage());
    };
    let Some(table) = TABLES.iter().find(|t| t.id == id) else {
        bail!("unknown table `{id}`\n\n{}", usage());
    };
    let mut o = Options {
        table,
        device: "cpu".into(),
        precision: "fp32".into(),
        warmup: 1,
        iterations: 5,
        out: None,
    };
    let mut it = args[1..].iter();
    while let Some(flag) = it.next() {
        let mut value = || it.next().with_context(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--device" => o.device = value()?.clone(),
            "--precision" => o.precision = value()?.clone(),
            "--warmup" => o.warmup = value()?.parse().context("--warmup: a number")?,
            "--iterations" => o.iterations = value()?.parse().context("--iterations: a number")?,
            "--out" => o.out = Some(value()?.clone()),
            other => bail!("reproduce: unknown option `{other}`\n\n{}", usage()),
        }
    }
    Ok(o)
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

pub fn reproduce(root: &Path, args: &[String]) -> Result<()> {
    if matches!(
        args.first().map(String::as_str),
        None | Some("-h" | "--help" | "help")
    ) {
        print!("{}", usage());
        return Ok(());
    }
    let o = parse(args)?;
    crate::setup::ensure_libtorch(root)?;
    crate::run(root, "cargo", &["build", "--release", "-p", "rtf-cli"])?;
    let models: serde_json::Value =
        serde_json::from_str(&crate::rtf_stdout(root, &["models", "--json"])?)
            .context("parsing `rtf models --json`")?;
    let mut measured = Vec::new();
    let mut threads = 0.0;
    for row in o.table.rows {
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
    let context = format!(
        "Paper columns: the paper's numbers as printed (its GPUs). Measured columns: `rtf bench \
         model` on this machine, device {} ({} threads), {} fast path, batch 1, 480×640, random \
         weights, median of {} passes after {} warm-up; parameters and f32 size from `rtf \
         models --json`. Command: `cargo xtask reproduce {}{}`.",
        o.device,
        threads,
        o.precision,
        o.iterations,
        o.warmup,
        o.table.id,
        args[1..].iter().fold(String::new(), |acc, a| acc + " " + a)
    );
    let text = render(o.table, &measured, &context);
    print!("{text}");
    if let Some(path) = &o.out {
        let path = root.join(path);
        let tmp = path.with_extension("md.tmp");
        std::fs::write(&tmp, &text).with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, &path).with_context(|| format!("writing {}", path.display()))?;
        eprintln!("reproduce: wrote {}", path.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_row_has_a_paper_cell_per_column_and_a_known_table_id() {
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
        let args = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(
            parse(&args(&["rtfnet-tab7"])).unwrap().table.id,
            "rtfnet-tab7"
        );
        let o = parse(&args(&[
            "mfnet-tab4",
            "--device",
            "cuda",
            "--iterations",
            "9",
        ]))
        .unwrap();
        assert_eq!((o.device.as_str(), o.iterations), ("cuda", 9));
        let err = parse(&args(&["tab99"])).err().unwrap().to_string();
        assert!(
            err.contains("unknown table `tab99`") && err.contains("rtfnet-tab7"),
            "{err}"
        );
        assert!(parse(&args(&["mfnet-tab4", "--bogus"])).is_err());
    }

    #[test]
    fn table_shows_paper_and_measured_columns_side_by_side() {
        let models = serde_json::json!([
            {"name": "mfnet", "params": 736275, "megabytes": 2.81},
            {"name": "segnet-3c", "params": 29443211, "megabytes": 112.3},
        ]);
        assert_eq!(size_of(&models, "mfnet").unwrap(), (736275, 2.81));
        assert!(size_of(&models, "nope").is_err());
        let table = TABLES.iter().find(|t| t.id == "mfnet-tab4").unwrap();
        let m = Measured {
            median_ms: 44.0,
            fps: 22.7,
            params: 736275,
            megabytes: 2.81,
        };
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
}
