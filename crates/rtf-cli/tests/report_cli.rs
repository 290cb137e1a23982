//! `rtf report` over a real (tiny) training run, a run with the new log schema, a multi-stage
//! run and an `rtf eval --json` file with missing-modality scores: the page's structure, every
//! embedded image decodes (PNG by the image crate, SVG as XML with an `<svg>` root); bad
//! input is one error naming the file, and no page is written.

use std::path::Path;

use base64::Engine;

mod common;
use common::*;

/// Every `data:` image of the page: (mime, bytes).
fn images(html: &str) -> Vec<(String, Vec<u8>)> {
    html.split("src=\"data:")
        .skip(1)
        .map(|rest| {
            let (mime, rest) = rest.split_once(";base64,").expect("base64 data URI");
            let data = &rest[..rest.find('"').unwrap()];
            let bytes = base64::engine::general_purpose::STANDARD
                .decode(data)
                .expect("valid base64");
            (mime.to_string(), bytes)
        })
        .collect()
}

/// The contents of an SVG's `<text>` elements.
fn svg_texts(svg: &str) -> Vec<String> {
    let doc = roxmltree::Document::parse(svg).expect("SVG parses as XML");
    doc.descendants()
        .filter(|n| n.has_tag_name("text"))
        .map(|n| n.text().unwrap_or("").trim().to_string())
        .collect()
}

/// The SVG of the chart titled `title`.
fn chart<'a>(svgs: &'a [String], title: &str) -> &'a str {
    svgs.iter()
        .find(|svg| svg_texts(svg).iter().any(|t| t == title))
        .unwrap_or_else(|| panic!("no chart titled {title}"))
}

fn svg_images(html: &str) -> Vec<String> {
    images(html)
        .into_iter()
        .filter(|(mime, _)| mime == "image/svg+xml")
        .map(|(_, b)| String::from_utf8(b).unwrap())
        .collect()
}

/// A run folder with `epochs` new-schema log lines and the given configuration.
fn synthetic_run(dir: &Path, epochs: u64, config: &rtf_train::TrainConfig) {
    std::fs::create_dir_all(dir).unwrap();
    let config = serde_json::to_string_pretty(config).unwrap();
    std::fs::write(dir.join("config.json"), config).unwrap();
    let lines: Vec<String> = (0..epochs).map(new_schema_line).collect();
    std::fs::write(dir.join("log.jsonl"), lines.join("\n") + "\n").unwrap();
}

/// An MFNet run's configuration (on a dataset that is not there) with `network` instead.
fn config_of(network: &str) -> rtf_train::TrainConfig {
    let mut cfg = rtf_train::TrainConfig::mfnet_paper("/nowhere/data".into());
    cfg.network.model = rtf_models::ModelConfig::from_name(network, 9).unwrap();
    cfg
}

/// A log line as the adversarial procedure's trainer writes it (loss terms, two networks'
/// learning rates, the critic's metrics, nested validation scores).
fn new_schema_line(epoch: u64) -> String {
    let miou = 0.2 + 0.05 * epoch as f64;
    serde_json::json!({
        "epoch": epoch, "lr": 0.01, "train_loss": 1.0 / (epoch + 1) as f64, "images": 8,
        "seconds": 1.0, "images_per_s": 8.0, "data_wait_fraction": 0.1,
        "val_miou": miou, "val_macc": 0.3,
        "losses": {"ce": 0.8 / (epoch + 1) as f64, "critic": 0.2},
        "lrs": {"segmenter": 0.01, "critic": 0.001},
        "metrics": {"critic_acc_day": 0.6, "critic_acc_night": 0.55},
        "val": {"miou": miou, "macc": 0.3, "miou_day": 0.25,
                "miou_night": 0.15,
                "per_class_iou": {"unlabeled": 0.9, "car": 0.3, "person": null},
                "per_class_iou_day": {"unlabeled": 0.9, "car": 0.35, "person": null},
                "per_class_iou_night": {"unlabeled": 0.88, "car": 0.25, "person": 0.1},
                "selected_by": "miou", "selected": miou}
    })
    .to_string()
}

fn copy(from: &Path, to: &Path, name: &str) {
    std::fs::create_dir_all(to).unwrap();
    std::fs::copy(from.join(name), to.join(name)).unwrap();
}

#[test]
fn report_of_runs_and_evaluations_is_one_self_contained_page() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, run) = (tmp.path().join("data"), tmp.path().join("run"));
    synth_mf(&data, "8", "5", "64x48");
    ok(&short_train(&data, &run, "2", &["--model", "mfnet"]));

    // The new core's log schema, same config and weights.
    let run2 = tmp.path().join("run-new");
    copy(&run, &run2, "config.json");
    copy(&run, &run2, "final.safetensors");
    let lines: Vec<String> = (0..3).map(new_schema_line).collect();
    std::fs::write(run2.join("log.jsonl"), lines.join("\n") + "\n").unwrap();

    // A multi-stage run: the stages' folders hold their own config and log.
    let staged = tmp.path().join("staged");
    std::fs::create_dir_all(&staged).unwrap();
    let stage = |name: &str| {
        let config = json_file(&run.join("config.json"));
        serde_json::json!({"name": name, "config": config})
    };
    let pipeline = serde_json::json!({"recipe": null,
        "stages": [stage("supervised"), stage("adapt")]});
    std::fs::write(staged.join("config.json"), pipeline.to_string()).unwrap();
    for stage in ["supervised", "adapt"] {
        copy(&run, &staged.join(stage), "config.json");
        copy(&run2, &staged.join(stage), "log.jsonl");
    }

    let scores = tmp.path().join("scores.json");
    ok(&[
        "eval",
        "--model",
        "mfnet",
        "--weights",
        s(&run.join("final.safetensors")),
        "--data",
        s(&data),
        "--split",
        "test",
        "--json",
        s(&scores),
        "--drop",
        "thermal",
        "--drop",
        "rgb",
        "--drop-fill",
        "mean",
    ]);
    let eval = json_file(&scores);
    assert_eq!(eval["schema"], "rtf-eval/1");
    assert_eq!(eval["dropped"].as_array().unwrap().len(), 2);
    assert_eq!(eval["dropped"][0]["modality"], "thermal");
    assert_eq!(eval["dropped"][0]["fill"], "mean");
    assert!(eval["dropped"][1]["miou"].is_number() && eval["dropped"][1]["day"].is_object());
    let n = eval["class_names"].as_array().unwrap().len();
    let confusion: Vec<Vec<u64>> = serde_json::from_value(eval["confusion"].clone()).unwrap();
    assert_eq!(confusion.len(), n);
    assert_eq!(
        confusion.iter().flatten().sum::<u64>(),
        eval["pixels"].as_u64().unwrap()
    );

    let out = tmp.path().join("report.html");
    ok(&[
        "report",
        s(&run),
        s(&run2),
        s(&staged),
        "--eval",
        s(&scores),
        "--out",
        s(&out),
        "--frames",
        "2",
    ]);
    let html = std::fs::read_to_string(&out).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    assert!(
        !html.contains("src=\"http") && !html.contains("href=\"http"),
        "self-contained"
    );
    for section in [
        "<h2>Side by side</h2>",
        "<h2>Run run</h2>",
        "<h2>Run run-new</h2>",
        "<h2>Run staged / supervised</h2>",
        "<h2>Run staged / adapt</h2>",
        "<h2>Evaluation scores.json</h2>",
        "<h2>Predictions</h2>",
        "thermal missing (mean fill)",
        "rgb missing (mean fill)",
    ] {
        assert!(html.contains(section), "missing {section}");
    }
    // A header row, then one row per run or stage.
    let table = &html[html.find("class=\"compare\"").unwrap()..];
    let table = &table[..table.find("</table>").unwrap()];
    assert_eq!(table.matches("<tr><th>").count(), 1 + 4);

    let imgs = images(&html);
    let (mut svgs, mut pngs) = (0, 0);
    for (mime, bytes) in &imgs {
        match mime.as_str() {
            "image/svg+xml" => {
                let text = std::str::from_utf8(bytes).unwrap();
                let doc = roxmltree::Document::parse(text).expect("SVG parses as XML");
                assert_eq!(doc.root_element().tag_name().name(), "svg");
                svgs += 1;
            }
            "image/png" => {
                let img = image::load_from_memory(bytes).expect("PNG decodes");
                assert!(img.width() > 64 && img.height() > 48);
                pngs += 1;
            }
            other => panic!("unexpected image type {other}"),
        }
    }
    // Every run (the one `rtf train` wrote, run-new, both stages): loss, lr, val, class bars;
    // eval: bars, heat map; one prediction grid. (Old-schema logs: the unit tests.)
    // Comparing: validation mIoU and training loss, the runs overlaid.
    assert_eq!(svgs, 4 * 4 + 2 + 2, "{}", imgs.len());
    assert_eq!(pngs, 1);
    for title in [
        "Training loss",
        "Learning rate",
        "Validation",
        "Confusion matrix",
    ] {
        let found = imgs
            .iter()
            .any(|(_, b)| String::from_utf8_lossy(b).contains(title));
        assert!(found, "a chart titled {title}");
    }
    let bars = imgs
        .iter()
        .map(|(_, b)| svg_texts(&String::from_utf8_lossy(b)))
        .find(|t| t.iter().any(|t| t == "35.0/25.0"))
        .expect("day/night IoU bars of the new log");
    for label in ["car", "day", "night"] {
        assert!(bars.iter().any(|t| t == label), "{label} in {bars:?}");
    }
}

#[test]
fn bad_input_names_the_file_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("report.html");
    let empty = tmp.path().join("empty-run");
    std::fs::create_dir_all(&empty).unwrap();
    std::fs::write(empty.join("config.json"), "{}").unwrap();
    let err = fails(&["report", s(&empty), "--out", s(&out)]);
    assert!(
        err.contains("log.jsonl") && err.contains("empty-run"),
        "{err}"
    );

    let run = tmp.path().join("run");
    synthetic_run(&run, 1, &config_of("mfnet"));
    let line = new_schema_line(0);
    std::fs::write(run.join("log.jsonl"), format!("{line}\nnot json\n")).unwrap();
    let err = fails(&["report", s(&run), "--out", s(&out)]);
    assert!(err.contains("log.jsonl:2"), "{err}");
    // A renamed field is an error naming the line and the field, not an empty chart.
    let renamed = line.replace("\"train_loss\"", "\"loss\"");
    std::fs::write(run.join("log.jsonl"), format!("{renamed}\n")).unwrap();
    let err = fails(&["report", s(&run), "--out", s(&out)]);
    assert!(
        err.contains("log.jsonl:1") && err.contains("train_loss"),
        "{err}"
    );

    std::fs::write(run.join("log.jsonl"), format!("{line}\n")).unwrap();
    let other = tmp.path().join("other.json");
    std::fs::write(&other, r#"{"schema": "something-else/3", "miou": 0.5}"#).unwrap();
    let err = fails(&["report", s(&run), "--eval", s(&other), "--out", s(&out)]);
    assert!(
        err.contains("other.json") && err.contains("something-else/3"),
        "{err}"
    );

    assert!(!out.exists(), "no page written");
    // A valid run alone works (no weights: the page says why there is no grid).
    ok(&["report", s(&run), "--out", s(&out)]);
    let html = std::fs::read_to_string(&out).unwrap();
    assert!(html.contains("No prediction grid"));
}

#[test]
fn a_run_report_leads_with_the_answer_and_stays_legible_at_500_epochs() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("long");
    synthetic_run(&run, 500, &config_of("mfnet"));
    let out = tmp.path().join("report.html");
    ok(&["report", s(&run), "--out", s(&out), "--frames", "0"]);
    let html = std::fs::read_to_string(&out).unwrap();

    // new_schema_line: val miou 0.2 + 0.05 epoch, so the last epoch (499) is also the best.
    let headline = &html[html.find("class=\"headline\"").unwrap()..];
    let headline = &headline[..headline.find("</div>\n</div>").unwrap()];
    let final_miou = format!("{:.1}", 100.0 * (0.2 + 0.05 * 499.0));
    for figure in [
        final_miou.as_str(),
        "final mIoU (epoch 499)",
        "best mIoU (epoch 499)",
        "mAcc",
        "30.0",
        "mIoU day",
        "25.0",
        "mIoU night",
        "15.0",
    ] {
        assert!(headline.contains(figure), "{figure} in {headline}");
    }
    // The answer, then the class bars, the curves, and the configuration last, collapsed.
    let at = |needle: &str| {
        html.find(needle)
            .unwrap_or_else(|| panic!("{needle} in the page"))
    };
    let order = [
        at("class=\"headline\""),
        at("alt=\"per-class IoU bars\""),
        at("alt=\"validation mIoU curves\""),
        at("alt=\"training loss curves\""),
        at("<details class=\"config\">"),
    ];
    assert!(order.windows(2).all(|w| w[0] < w[1]), "{order:?}");
    assert!(!html.contains("<details open"), "configuration collapsed");
    assert!(html.contains("<th>network.model.network</th>"));

    // Tick thinning: at most 8 numeric labels on the epoch axis, 6 on the score axis.
    let svgs = svg_images(&html);
    let validation = chart(&svgs, "Validation");
    let numeric = svg_texts(validation)
        .into_iter()
        .filter(|t| t.parse::<f64>().is_ok())
        .count();
    assert!((4..=8 + 6).contains(&numeric), "{numeric} tick labels");
    let bars = svg_texts(chart(&svgs, "Per-class IoU (last validation), %"));
    for name in ["unlabeled", "car", "person"] {
        assert!(bars.iter().any(|t| t == name), "{name} in {bars:?}");
    }
}

#[test]
fn several_runs_compare_metrics_curves_and_configuration_differences() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("run-a"), tmp.path().join("run-b"));
    synthetic_run(&a, 3, &config_of("mfnet"));
    synthetic_run(&b, 5, &config_of("rtfnet50"));
    let out = tmp.path().join("compare.html");
    ok(&["report", s(&a), s(&b), "--out", s(&out), "--frames", "0"]);
    let html = std::fs::read_to_string(&out).unwrap();

    let table = &html[html.find("<table class=\"compare\">").unwrap()..];
    let table = &table[..table.find("</table>").unwrap()];
    for cell in [
        "final mIoU",
        "best mIoU",
        "best epoch",
        "<th>run-a</th>",
        "<th>run-b</th>",
        "<td>30.0</td>",
        "<td>40.0</td>",
    ] {
        assert!(table.contains(cell), "{cell} in {table}");
    }
    // Only the settings that differ: the network, not lr / batch / seed.
    let diff = &html[html.find("<table class=\"config-diff\">").unwrap()..];
    let diff = &diff[..diff.find("</table>").unwrap()];
    assert!(diff.contains("<th>network.model.network</th>") && diff.contains("rtfnet"));
    for same in [
        "<th>learning.optimizer.lr</th>",
        "<th>schedule.batch_size</th>",
        "<th>schedule.seed</th>",
    ] {
        assert!(!diff.contains(same), "{same} is the same in both runs");
    }
    assert!(
        !html.contains("<details class=\"config\">"),
        "no full configurations"
    );

    let svgs = svg_images(&html);
    for title in ["Validation mIoU", "Training loss"] {
        let texts = svg_texts(chart(&svgs, title));
        assert!(
            texts.iter().any(|t| t == "run-a") && texts.iter().any(|t| t == "run-b"),
            "{title}: both runs overlaid, {texts:?}"
        );
    }
}

/// The page as a browser draws it: headless Chromium (scripts/report_screenshot.sh) renders
/// the report, and the screenshot is not blank. Gated: `RTF_CHROMIUM=1` (needs `chromium`).
#[test]
fn chromium_renders_the_report() {
    if std::env::var("RTF_CHROMIUM").as_deref() != Ok("1") {
        eprintln!("skipped: set RTF_CHROMIUM=1 (needs chromium) to render the report");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    synthetic_run(&run, 50, &config_of("mfnet"));
    let (page, shot) = (tmp.path().join("report.html"), tmp.path().join("shot.png"));
    ok(&["report", s(&run), "--out", s(&page), "--frames", "0"]);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/report_screenshot.sh");
    let status = std::process::Command::new("bash")
        .args([s(&script), s(&page), s(&shot), "1000x1200"])
        .status()
        .expect("bash runs");
    assert!(status.success(), "report_screenshot.sh failed");
    let img = image::open(&shot).expect("a PNG screenshot").to_rgb8();
    assert_eq!(img.dimensions(), (1000, 1200));
    // Drawn, not blank: dark text and the bars' / curves' blue both appear.
    let dark = img.pixels().filter(|p| p.0.iter().all(|&c| c < 80)).count();
    let blue = img
        .pixels()
        .filter(|p| p.0[2] > 150 && p.0[0] < 80 && p.0[1] < 150)
        .count();
    assert!(dark > 1000 && blue > 1000, "dark {dark}, blue {blue}");
}
