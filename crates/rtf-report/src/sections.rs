//! A run's section of the page: the answer first (headline figures, per-class IoU bars), then
//! its curves, then (alone on the page) its whole configuration, collapsed.

use std::fmt::Write as _;

use crate::charts::{class_bars, line_chart};
use crate::error::ReportError;
use crate::html::{epoch_text, esc, pct, svg_img};
use crate::runs::Run;
use crate::series::{
    best_point, last, last_class_iou, last_point, loss_series, lr_series, val_series,
};

type Result<T> = std::result::Result<T, ReportError>;

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
pub(crate) fn run_section(run: &Run, with_config: bool, html: &mut String) -> Result<()> {
    writeln!(
        html,
        "<section class=\"run\"><h2>Run {}</h2>\n<p class=\"path\">{}</p>",
        esc(&run.label),
        esc(&run.dir().display().to_string())
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
        config_details(&run.settings, html)?;
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
fn config_details(rows: &[(String, String)], html: &mut String) -> Result<()> {
    if rows.is_empty() {
        return Ok(());
    }
    writeln!(
        html,
        "<details class=\"config\"><summary>Configuration ({} settings)</summary><table class=\"config\">",
        rows.len()
    )?;
    for (k, v) in rows {
        writeln!(html, "<tr><th>{}</th><td>{}</td></tr>", esc(k), esc(v))?;
    }
    writeln!(html, "</table></details>")?;
    Ok(())
}
