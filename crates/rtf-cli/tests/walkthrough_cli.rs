//! The MSRS walk-through of docs/src/data.md (`scripts/walkthrough_msrs.sh`, issue 26 §5),
//! small: 4 real MSRS scenes labelled by the published MFNet at 640x480, read back through
//! the MSRS layout, fine-tuned for one step at 64x48 and evaluated. About 20 s of CPU;
//! skipped (said on stderr) where ../shared/data is not there.

use std::path::Path;
use std::process::Command;

mod common;
use common::*;

#[test]
fn the_msrs_walkthrough_labels_reads_back_fine_tunes_and_scores_agreement() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let shared = repo.join("../shared/data");
    if !shared.join("msrs-samples/frames.txt").is_file() {
        eprintln!("skipped: {} has no msrs-samples", shared.display());
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("walk");
    let run = Command::new("bash")
        .arg(repo.join("scripts/walkthrough_msrs.sh"))
        .arg(&out)
        .env("RTF", env!("CARGO_BIN_EXE_rtf"))
        .env("SAMPLES", shared.join("msrs-samples"))
        .env("WEIGHTS", shared.join("mf-samples/mfnet_final.safetensors"))
        .envs([("SCENES", "4"), ("SIZE", "64x48"), ("EPOCHS", "1")])
        .env("MAX_STEPS", "1")
        .output()
        .unwrap();
    let printed = text(&run);
    assert!(run.status.success(), "{printed}");
    // Day and night scenes alternate between train and test.
    let splits = std::fs::read_to_string(out.join("splits.txt")).unwrap();
    assert_eq!(
        splits,
        "00004N train\n00032N test\n00055D train\n00107D test\n"
    );
    let check = std::fs::read_to_string(out.join("check.txt")).unwrap();
    assert!(
        check.lines().next().unwrap().contains("MSRS layout")
            && check.contains("9 classes (msrs)")
            && check.contains("4 frames decoded, 0 problem(s)"),
        "{check}"
    );
    let label = out.join("msrs/test/Label/00107D.png");
    let png = rtf_data::pngio::read_png(&label).unwrap();
    assert_eq!((png.width, png.height, png.channels), (640, 480, 1));
    let summary = json_file(&out.join("summary.json"));
    // The labels are the published network's own predictions, read back intact.
    let full = &summary["published_full_size"];
    assert_eq!(full["all"]["pixel_agreement"], 1.0, "{summary}");
    assert_eq!(full["frames"], 2, "{summary}");
    for key in ["published_at_size", "finetuned_at_size"] {
        let agreement = summary[key]["all"]["pixel_agreement"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&agreement), "{key}: {summary}");
        assert!(
            summary[key]["night"].is_object(),
            "{key}: day/night from the names"
        );
    }
    assert!(out.join("run/final.safetensors").is_file());
}
