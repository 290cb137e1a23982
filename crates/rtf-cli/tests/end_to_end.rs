//! synth → train (a few steps) → resume → eval → predict through the `rtf` binary, on a tiny
//! synthetic dataset, checking what each step writes; and the CLI's bad-input contract.

use std::path::Path;

mod common;
use common::*;

/// A synthetic 32×32 dataset under `dir` and MFNet weights trained on it for one step.
fn tiny_weights(dir: &Path, frames: &str, seed: &str) -> std::path::PathBuf {
    let (data, run) = (dir.join("data"), dir.join("run"));
    synth_mf(&data, frames, seed, "32x32");
    ok(&short_train(&data, &run, "1", &["--val-split", "none"]));
    run.join("final.safetensors")
}

#[test]
fn synth_train_resume_eval_predict() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let run = tmp.path().join("run");
    synth_mf(&data, "12", "3", "64x48");
    for split in ["train", "val", "test", "test_day", "test_night"] {
        assert!(
            data.join(format!("{split}.txt")).exists(),
            "{split}.txt written"
        );
    }

    let train = short_train(&data, &run, "2", &["--model", "mfnet"]);
    ok(&train);
    let config = json_file(&run.join("config.json"));
    assert_eq!(config["network"]["model"]["network"], "mfnet");
    assert_eq!(config["schedule"]["seed"], 0);
    assert!(run.join("final.safetensors").exists() && run.join("checkpoint.safetensors").exists());
    let err = fails(&train);
    assert!(
        err.contains("--resume"),
        "a second run into the same folder is refused: {err}"
    );

    ok(&["train", "--resume", s(&run), "--epochs", "2"]);
    let log = rtf_run::log::read(&run.join("log.jsonl")).unwrap();
    let epochs: Vec<usize> = log.iter().map(|r| r.epoch).collect();
    assert_eq!(epochs, vec![0, 1], "resume continued at the next epoch");
    // Resumed again with nothing left: said, exit 0, the weights' path as a finished run prints.
    let out = rtf(&["train", "--resume", s(&run)]);
    assert!(out.status.success(), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("nothing to do: finished at epoch 2 of 2"),
        "{stderr}"
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("final.safetensors"));

    let weights = run.join("final.safetensors");
    let json = tmp.path().join("scores.json");
    let figure = tmp.path().join("grid.png");
    let table = ok(&[
        "eval",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--data",
        s(&data),
        "--split",
        "test",
        "--json",
        s(&json),
        "--figure",
        s(&figure),
        "--figure-frames",
        "2",
    ]);
    assert!(
        table.contains("mIoU") && table.contains("person"),
        "{table}"
    );
    let scores = json_file(&json);
    for key in ["miou", "macc", "miou_mfnet"] {
        let v = scores[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{key} missing"));
        assert!((0.0..=1.0).contains(&v), "{key} = {v}");
    }
    let per_class = scores["per_class"].as_array().unwrap();
    assert_eq!(per_class.len(), 9);
    // The scores say which data they came from.
    let fingerprint = json_out(&["data", "fingerprint", s(&data), "--json"]);
    assert_eq!(scores["data_fingerprint"], fingerprint);
    assert_eq!(per_class[0]["name"], "unlabeled");
    assert!(per_class
        .iter()
        .all(|c| c["iou"].is_null() || c["iou"].as_f64().is_some()));
    let grid = image::open(&figure).unwrap();
    // 4 panels of 64 with 4-pixel gaps; a 16-pixel title strip, 2 rows of 48 + 4, then the
    // class legend in 16-pixel lines.
    assert_eq!(grid.width(), 4 * 64 + 3 * 4, "4 panels");
    let legend = grid.height() as i64 - 16 - 2 * (48 + 4);
    assert!(
        legend > 0 && legend % 16 == 0,
        "titles, 2 rows, legend: {}",
        grid.height()
    );

    // The fast inference path (BatchNorm folded, channels-last) scores (almost) the same.
    let json_fast = tmp.path().join("scores_fast.json");
    ok(&[
        "eval",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--data",
        s(&data),
        "--split",
        "test",
        "--json",
        s(&json_fast),
        "--precision",
        "fp32",
    ]);
    let fast = json_file(&json_fast);
    let (fast_miou, plain_miou) = (
        fast["miou"].as_f64().unwrap(),
        scores["miou"].as_f64().unwrap(),
    );
    eprintln!("fast path mIoU {fast_miou:.5}, plain {plain_miou:.5} (line: 0.01 apart)");
    assert!((fast_miou - plain_miou).abs() < 0.01);

    let test_names = std::fs::read_to_string(data.join("test.txt")).unwrap();
    let name = test_names.lines().next().unwrap().trim().to_string();
    let image = data.join("images").join(format!("{name}.png"));
    let pred = tmp.path().join("pred");
    ok(&[
        "predict",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--out",
        s(&pred),
        "--logits",
        s(&image),
    ]);
    let ids = image::open(pred.join(format!("{name}.png")))
        .unwrap()
        .to_luma8();
    assert_eq!(ids.dimensions(), (64, 48));
    assert!(ids.pixels().all(|p| p.0[0] < 9));
    assert_eq!(
        image::open(pred.join(format!("{name}_color.png")))
            .unwrap()
            .to_rgb8()
            .dimensions(),
        (64, 48)
    );
    let (shape, logits) =
        rtf_core::npy::decode_f32(&std::fs::read(pred.join(format!("{name}.npy"))).unwrap())
            .unwrap();
    assert_eq!(shape, vec![9, 48, 64]);
    // The class-id PNG is the argmax of the logits.
    let argmax0 = (0..9)
        .max_by(|&a, &b| logits[a * 48 * 64].total_cmp(&logits[b * 48 * 64]))
        .unwrap();
    assert_eq!(ids.get_pixel(0, 0).0[0] as usize, argmax0);
}

#[test]
fn freiburg_root_trains_validates_on_its_test_layout_and_evaluates_heatnet_style() {
    let dir = tempfile::tempdir().unwrap();
    let (data, run) = (dir.path().join("fr"), dir.path().join("run"));
    let synth = [
        "synth",
        "--format",
        "freiburg",
        "--out",
        s(&data),
        "--count",
        "12",
        "--size",
        "96x64",
    ];
    ok(&synth);
    let train = short_train(&data, &run, "1", &["--optimizer", "rmsprop"]);
    ok(&train);
    let config = json_file(&run.join("config.json"));
    assert_eq!(config["data"]["dataset"]["format"], "freiburg");
    assert_eq!(config["network"]["model"]["num_classes"], 13);
    // --optimizer rmsprop takes the HeatNet paper's schedule.
    let optimizer = &config["learning"]["optimizer"];
    assert_eq!(optimizer["kind"], "rmsprop");
    assert_eq!(
        (optimizer["lr"].as_f64(), optimizer["decay_every"].as_u64()),
        (Some(1e-4), Some(30))
    );
    // The reference preprocessing leaves 700×320, trained through a 640×320 window.
    assert_eq!(
        config["data"]["augment"]["window"],
        serde_json::json!([640, 320])
    );
    let record = &rtf_run::log::read(&run.join("log.jsonl")).unwrap()[0];
    assert!(
        record.val_miou.is_some(),
        "validated on the test layout: {record:?}"
    );

    let weights = run.join("final.safetensors");
    let json = dir.path().join("eval.json");
    let eval = [
        "eval",
        "--weights",
        s(&weights),
        "--data",
        s(&data),
        "--json",
        s(&json),
    ];
    let printed = ok(&eval);
    assert!(
        printed.contains("background") && printed.contains("HeatNet convention"),
        "{printed}"
    );
    let report = json_file(&json);
    assert_eq!(report["per_class"].as_array().unwrap().len(), 13);
    let heatnet = &report["heatnet"];
    let (day, night) = (
        heatnet["day_miou"].as_f64().unwrap(),
        heatnet["night_miou"].as_f64().unwrap(),
    );
    assert!((heatnet["day_night_miou"].as_f64().unwrap() - (day + night) / 2.0).abs() < 1e-12);

    let err = fails(&[
        "eval",
        "--weights",
        s(&weights),
        "--data",
        s(&data),
        "--split",
        "val",
    ]);
    assert!(
        err.contains(s(&data)) && err.contains("`test` and `train`"),
        "{err}"
    );
    let err = fails(&[
        "train",
        "--data",
        s(&data),
        "--out",
        s(&dir.path().join("run2")),
        "--train-split",
        "a",
    ]);
    assert!(
        err.contains(s(&data)) && err.contains("no named splits"),
        "{err}"
    );
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let err = fails(&[
        "train",
        "--data",
        s(&empty),
        "--out",
        s(&dir.path().join("run3")),
    ]);
    assert!(err.contains("not a training dataset"), "{err}");
}

#[test]
fn ctrl_c_checkpoints_and_resume_finishes_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let (data, run) = (dir.path().join("data"), dir.path().join("run"));
    synth_mf(&data, "12", "4", "32x32");
    let out = train_then_signal(&data, &run, libc::SIGINT);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("--resume"), "{stderr}");
    assert!(run.join("checkpoint.safetensors").exists());
    assert!(!run.join("final.safetensors").exists());
    // Resuming with a shorter schedule finishes from the checkpoint and writes the weights.
    // The schedule ends with the epoch the signal interrupted: how far the run got in its
    // first 300 ms depends on the machine, and a resume never cuts a run below where it
    // stands (checked in train_cli's sigterm test).
    let state = rtf_train::checkpoint::read_state(&run.join("checkpoint.safetensors")).unwrap();
    let epochs = (state.epochs_done + 1).to_string();
    ok(&["train", "--resume", s(&run), "--epochs", &epochs]);
    assert!(run.join("final.safetensors").exists());
}

#[test]
fn bad_inputs_name_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let weights = tmp.path().join("missing.safetensors");
    let rgb = tmp.path().join("rgb.png");
    image::RgbImage::new(32, 32).save(&rgb).unwrap();
    // Missing weights.
    let err = fails(&[
        "predict",
        "--weights",
        s(&weights),
        "--out",
        s(&tmp.path().join("o")),
        s(&rgb),
    ]);
    assert!(err.contains("missing.safetensors"), "{err}");
    // Missing dataset.
    let err = fails(&[
        "eval",
        "--weights",
        s(&weights),
        "--data",
        s(&tmp.path().join("nodata")),
    ]);
    assert!(err.contains("nodata"), "{err}");
    // A 3-channel image where RGBA is expected, with valid weights.
    let weights = tiny_weights(tmp.path(), "8", "1");
    let out_dir = tmp.path().join("pred");
    let err = fails(&[
        "predict",
        "--weights",
        s(&weights),
        "--out",
        s(&out_dir),
        s(&rgb),
    ]);
    assert!(err.contains("rgb.png") && err.contains("channel"), "{err}");
    assert!(
        !out_dir.exists() || std::fs::read_dir(&out_dir).unwrap().count() == 0,
        "nothing written"
    );
    // Unknown model name.
    let err = fails(&[
        "train",
        "--model",
        "nosuchnet",
        "--data",
        s(&tmp.path().join("data")),
        "--out",
        s(&tmp.path().join("r2")),
    ]);
    assert!(err.contains("nosuchnet"), "{err}");
}

#[test]
fn predict_takes_separate_rgb_and_16_bit_thermal() {
    let tmp = tempfile::tempdir().unwrap();
    let weights = tiny_weights(tmp.path(), "6", "2");
    let rgb = tmp.path().join("cam_rgb.png");
    let thermal = tmp.path().join("cam_ir.png");
    image::RgbImage::from_fn(32, 32, |x, y| image::Rgb([x as u8 * 8, y as u8 * 8, 90]))
        .save(&rgb)
        .unwrap();
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(32, 32, |x, _| {
        image::Luma([22000 + 80 * x as u16])
    })
    .save(&thermal)
    .unwrap();
    let out = tmp.path().join("pred");
    ok(&[
        "predict",
        "--weights",
        s(&weights),
        "--out",
        s(&out),
        "--rgb",
        s(&rgb),
        "--thermal",
        s(&thermal),
    ]);
    assert_eq!(
        image::open(out.join("cam_rgb.png"))
            .unwrap()
            .to_luma8()
            .dimensions(),
        (32, 32)
    );
    // A thermal image of another size is refused, naming both files.
    let small = tmp.path().join("small_ir.png");
    image::GrayImage::new(16, 16).save(&small).unwrap();
    let err = fails(&[
        "predict",
        "--weights",
        s(&weights),
        "--out",
        s(&out),
        "--rgb",
        s(&rgb),
        "--thermal",
        s(&small),
    ]);
    assert!(
        err.contains("small_ir.png") && err.contains("cam_rgb.png"),
        "{err}"
    );
}

#[test]
fn synth_writes_a_calibration_rig_with_ground_truth() {
    let tmp = tempfile::tempdir().unwrap();
    let rig = tmp.path().join("rig");
    ok(&[
        "synth",
        "--format",
        "calibration-rig",
        "--out",
        s(&rig),
        "--count",
        "2",
        "--seed",
        "5",
        "--size",
        "160x120",
    ]);
    let yaml = std::fs::read_to_string(rig.join("rig.yaml")).unwrap();
    assert!(
        yaml.contains("frames") && yaml.contains("focal_length_mm"),
        "{yaml}"
    );
    let truth = std::fs::read_to_string(rig.join("ground_truth.yaml")).unwrap();
    for key in ["rotation", "translation", "se3", "distortion"] {
        assert!(truth.contains(key), "{key} missing in ground_truth.yaml");
    }
}

#[test]
fn weights_carry_their_network_and_foreign_files_are_flagged() {
    let tmp = tempfile::tempdir().unwrap();
    let weights = tiny_weights(tmp.path(), "6", "4");
    let data = tmp.path().join("data");
    let eval = |model: &str, file: &Path, extra: &[&str]| {
        let mut args = vec![
            "eval",
            "--model",
            model,
            "--weights",
            s(file),
            "--data",
            s(&data),
        ];
        args.extend_from_slice(extra);
        rtf(&args)
    };
    // Same tensor names and shapes, other network: refused, naming the file and both names.
    let out = eval("mfnet-h", &weights, &[]);
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out);
    for needle in [
        "final.safetensors",
        "`mfnet`",
        "`mfnet-h`",
        "--foreign-weights",
    ] {
        assert!(err.contains(needle), "{needle} not in: {err}");
    }
    // Explicit override: loads, with a warning.
    let out = eval("mfnet-h", &weights, &["--foreign-weights"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("loaded anyway"),
        "{}",
        text(&out)
    );
    // The right network: no warning.
    let out = eval("mfnet", &weights, &[]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(!String::from_utf8_lossy(&out.stderr).contains("warning"));
    // A file without rtf metadata (converted weights): loads with a one-line warning.
    let bytes = std::fs::read(&weights).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    header.as_object_mut().unwrap().remove("__metadata__");
    let mut text_header = serde_json::to_vec(&header).unwrap();
    while text_header.len() & 7 != 0 {
        text_header.push(b' ');
    }
    let converted = tmp.path().join("converted.safetensors");
    let mut out_bytes = (text_header.len() as u64).to_le_bytes().to_vec();
    out_bytes.extend(text_header);
    out_bytes.extend(&bytes[8 + n..]);
    std::fs::write(&converted, out_bytes).unwrap();
    let out = eval("mfnet-h", &converted, &[]);
    assert!(out.status.success(), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("converted.safetensors") && stderr.contains("cannot be checked"),
        "{stderr}"
    );
}
