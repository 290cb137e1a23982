//! The report's charts, drawn with `plotters` as SVG (text is laid out by the browser, no font
//! file in the page): line charts of a run's series against epoch, per-class IoU bars and the
//! confusion matrix as a heat map.

use plotters::prelude::*;

use crate::error::ReportError;
use crate::series::{ClassRow, Series};

type Result<T> = std::result::Result<T, ReportError>;

const W: u32 = 560;
const H: u32 = 300;
/// At most this many labelled ticks per axis, whatever the number of epochs: plotters picks
/// "nice" values (1, 2, 5 × 10^k steps) up to this count, so a 500-epoch run stays legible.
const X_TICKS: usize = 8;
const Y_TICKS: usize = 6;

/// An epoch tick: whole epochs without decimals, the half steps a 2-epoch run gets with one.
pub(crate) fn epoch_label(x: &f64) -> String {
    if x.fract().abs() < 1e-9 {
        format!("{x:.0}")
    } else {
        format!("{x:.1}")
    }
}

fn plot_err<E: std::fmt::Debug>(e: E) -> ReportError {
    ReportError::Chart(format!("{e:?}"))
}

/// plotters lays text out with a registered TrueType font (the workspace builds it with
/// `ab_glyph` for the calibration plots): register the system's DejaVu Sans as "sans-serif",
/// once.
fn register_font() -> Result<()> {
    static REGISTERED: std::sync::OnceLock<std::result::Result<(), String>> =
        std::sync::OnceLock::new();
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
        .map_err(ReportError::Font)
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
pub(crate) fn line_chart(
    title: &str,
    y_desc: &str,
    series: &Series,
    log_y: bool,
) -> Result<String> {
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
pub(crate) const CLASS_NAME_CHARS: usize = 20;

pub(crate) fn short_name(name: &str) -> String {
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
pub(crate) fn class_bars(title: &str, rows: &[ClassRow], labels: [&str; 2]) -> Result<String> {
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
pub(crate) fn heat_map(title: &str, names: &[String], counts: &[Vec<u64>]) -> Result<String> {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The contents of an SVG's `<text>` elements (plotters writes them on their own lines).
    pub(crate) fn svg_texts(svg: &str) -> Vec<String> {
        svg.split("<text")
            .skip(1)
            .filter_map(|t| {
                let body = &t[t.find('>')? + 1..t.find("</text>")?];
                Some(body.trim().to_string())
            })
            .collect()
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
