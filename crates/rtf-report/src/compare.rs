//! Several runs (or stages) side by side: the final and best metrics table, the validation
//! mIoU and training loss curves overlaid, and the configuration settings that differ.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use rtf_run::EpochRecord;

use crate::charts::line_chart;
use crate::error::ReportError;
use crate::html::{epoch_text, esc, pct, svg_img};
use crate::runs::Run;
use crate::series::{best_point, last, loss_series, val_series, Series};

type Result<T> = std::result::Result<T, ReportError>;

/// Several runs (or stages): the final and best metrics table, the curves overlaid, and the
/// configuration settings that differ.
pub(crate) fn compare_section(runs: &[Run], html: &mut String) -> Result<()> {
    writeln!(html, "<section class=\"compare\"><h2>Side by side</h2>")?;
    comparison_table(runs, html)?;
    writeln!(html, "<div class=\"charts\">")?;
    for (key, title, pick) in [
        (
            "miou",
            "Validation mIoU",
            val_series as fn(&[EpochRecord]) -> Series,
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
            .map(|e| e.images_per_s)
            .filter(|v| v.is_finite())
            .map_or("–".into(), |v| format!("{v:.1}"));
        writeln!(
            html,
            "<tr><th>{}</th><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&run.label),
            esc(run.network()),
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
pub(crate) fn differing_settings(runs: &[Run]) -> BTreeMap<String, Vec<String>> {
    let flat: Vec<BTreeMap<String, String>> = runs
        .iter()
        .map(|r| r.settings.iter().cloned().collect())
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A run folder at `dir` with `config` and an empty log, read as the report reads it.
    fn run_with(dir: &std::path::Path, config: serde_json::Value) -> Run {
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(dir.join("config.json"), config.to_string()).unwrap();
        std::fs::write(dir.join("log.jsonl"), "").unwrap();
        let mut notes = Vec::new();
        let mut runs = crate::runs::load_runs(dir, &mut notes).unwrap();
        assert_eq!(notes.len(), 1, "not a training configuration: {notes:?}");
        runs.pop().unwrap()
    }

    #[test]
    fn only_differing_settings_are_compared() {
        let tmp = tempfile::tempdir().unwrap();
        let runs = [
            run_with(
                &tmp.path().join("a"),
                serde_json::json!({"model": {"network": "mfnet"}, "lr": 0.01, "seed": 1}),
            ),
            run_with(
                &tmp.path().join("b"),
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
        assert!(runs.iter().all(|r| r.network() == "?"));
    }
}
