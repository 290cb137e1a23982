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

fn new_schema_line(epoch: u64) -> String {
    serde_json::json!({
        "epoch": epoch, "lr": 0.01, "train_loss": 1.0 / (epoch + 1) as f64, "images": 8,
        "seconds": 1.0, "images_per_s": 8.0, "data_wait_fraction": 0.1,
        "losses": {"ce": 0.8 / (epoch + 1) as f64, "critic": 0.2},
        "lrs": {"segmenter": 0.01, "critic": 0.001},
        "metrics": {"critic_acc_day": 0.6, "critic_acc_night": 0.55},
        "val": {"miou": 0.2 + 0.05 * epoch as f64, "macc": 0.3, "miou_day": 0.25,
                "miou_night": 0.15,
                "per_class_iou": {"unlabeled": 0.9, "car": 0.3, "person": null},
                "per_class_iou_day": {"unlabeled": 0.9, "car": 0.35, "person": null},
                "per_class_iou_night": {"unlabeled": 0.88, "car": 0.25, "person": 0.1}}
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
    std::fs::write(
        staged.join("config.json"),
        r#"{"stages": ["supervised", {"name": "adapt"}], "seed": 1}"#,
    )
    .unwrap();
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
    assert_eq!(svgs, 4 * 4 + 2, "{}", imgs.len());
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
        .map(|(_, b)| String::from_utf8_lossy(b).into_owned())
        .find(|t| t.contains("car 35.0/25.0"))
        .expect("day/night IoU bars of the new log");
    assert!(bars.contains("day") && bars.contains("night"));
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
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(run.join("config.json"), "{}").unwrap();
    std::fs::write(
        run.join("log.jsonl"),
        "{\"epoch\": 0, \"train_loss\": 1.0}\nnot json\n",
    )
    .unwrap();
    let err = fails(&["report", s(&run), "--out", s(&out)]);
    assert!(err.contains("log.jsonl:2"), "{err}");

    std::fs::write(
        run.join("log.jsonl"),
        "{\"epoch\": 0, \"train_loss\": 1.0}\n",
    )
    .unwrap();
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
