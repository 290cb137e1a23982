//! `rtf train` as users drive it: recipes, configs, the run folder's guarantees (no mixed runs,
//! SIGTERM like Ctrl-C, resumable from anywhere) and every value checked before anything runs.

mod common;

use std::process::Command;

use common::*;

#[test]
fn recipes_list_as_json_with_what_each_sets() {
    let recipes = json_out(&["recipes", "--json"]);
    let names: Vec<&str> = recipes
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["name"].as_str().unwrap())
        .collect();
    for name in [
        "mfnet-paper",
        "rtfnet-code",
        "heatnet-teacher-rgb",
        "heatnet-teacher-ir",
        "heatnet-v1",
        "heatnet-v6",
        "heatnet-distill",
        "cmx-mf",
    ] {
        assert!(names.contains(&name), "{name} in {names:?}");
    }
    for r in recipes.as_array().unwrap() {
        assert!(
            r["procedure"].is_string() && r["description"].is_string(),
            "{r}"
        );
        assert!(!r["stages"].as_array().unwrap().is_empty(), "{r}");
    }
    assert!(ok(&["recipes"]).contains("heatnet-v5"));
}

#[test]
fn a_heatnet_recipe_trains_its_teacher_then_the_student_and_resumes_as_a_whole() {
    let dir = tempfile::tempdir().unwrap();
    let (data, run) = (dir.path().join("fr"), dir.path().join("run"));
    ok(&[
        "synth",
        "--format",
        "freiburg",
        "--out",
        s(&data),
        "--count",
        "12",
        "--size",
        "64x32",
    ]);
    let args = [
        "train",
        "--recipe",
        "heatnet-v5",
        "--model",
        "mfnet",
        "--data",
        s(&data),
        "--out",
        s(&run),
        "--epochs",
        "1",
        "--batch-size",
        "2",
        "--max-steps",
        "1",
        "--resize",
        "64x32",
        "--workers",
        "1",
        "--tb-images-every",
        "1",
    ];
    let stdout = ok(&args);
    assert!(stdout.trim().ends_with("final.safetensors"), "{stdout}");
    for stage in ["teacher-rgb", "v5"] {
        assert!(
            run.join(stage).join("final.safetensors").is_file(),
            "{stage}"
        );
    }
    let config = json_file(&run.join("config.json"));
    assert_eq!(config["recipe"], "heatnet-v5");
    // The resolved data path: absolute, so the run resumes from any directory.
    let root = config["stages"][0]["config"]["data"]["dataset"]["root"]
        .as_str()
        .unwrap();
    assert!(std::path::Path::new(root).is_absolute(), "{root}");
    let record = &rtf_run::log::read(&run.join("v5/log.jsonl")).unwrap()[0];
    for term in ["ce_day", "adv", "critic"] {
        assert!(record.losses[term].is_finite(), "{term}: {record:?}");
    }
    assert!(record.metrics["critic_acc_night"].is_finite(), "{record:?}");
    // TensorBoard events beside the log, and the data's fingerprint in each stage's config.
    tensorboard_matches_log(&run.join("v5"));
    let stage = json_file(&run.join("v5/config.json"));
    assert!(stage["data"]["fingerprint"]["hash"].is_string(), "{stage}");
    // The same folder again without --resume: refused. With it: nothing left to do.
    let err = fails(&args);
    assert!(err.contains("--resume"), "{err}");
    let out = Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args(["train", "--resume", s(&run)])
        .current_dir(dir.path().join("fr"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(
        said.contains("nothing to do: finished at epoch 1 of 1"),
        "{said}"
    );
    // More epochs extend the finished run's last stage (the teacher stays as it is), and the
    // run's weights are the extended stage's.
    let stdout = ok(&["train", "--resume", s(&run), "--epochs", "2"]);
    assert!(stdout.trim().ends_with("final.safetensors"), "{stdout}");
    let lines = |stage: &str| {
        std::fs::read_to_string(run.join(stage).join("log.jsonl"))
            .unwrap()
            .lines()
            .count()
    };
    assert_eq!((lines("teacher-rgb"), lines("v5")), (1, 2));
    assert_eq!(
        std::fs::read(run.join("final.safetensors")).unwrap(),
        std::fs::read(run.join("v5/final.safetensors")).unwrap()
    );
    let out = rtf(&["train", "--resume", s(&run), "--epochs", "2"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        text(&out).contains("nothing to do: finished at epoch 2 of 2"),
        "{}",
        text(&out)
    );
    let err = fails(&["train", "--resume", s(&run), "--epochs", "1"]);
    assert!(err.contains("--epochs 1"), "{err}");
}

#[test]
fn bad_recipes_configs_and_values_fail_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    synth_mf(&data, "6", "1", "32x32");
    let run = dir.path().join("run");
    let err = fails(&[
        "train",
        "--recipe",
        "heatnet-v9",
        "--data",
        s(&data),
        "--out",
        s(&run),
    ]);
    assert!(
        err.contains("heatnet-v9") && err.contains("heatnet-v6"),
        "{err}"
    );
    for (flag, value, field) in [
        ("--lr", "-1", "lr"),
        ("--momentum", "5", "momentum"),
        ("--lr-decay", "0", "lr_decay"),
        ("--weight-decay", "-0.1", "weight_decay"),
        ("--max-steps", "0", "max_steps"),
        ("--warmup-epochs", "2", "--warmup-epochs"),
        ("--optimizer", "adam", "adamw"),
    ] {
        let arg = format!("{flag}={value}");
        let err = fails(&["train", "--data", s(&data), "--out", s(&run), &arg]);
        assert!(err.contains(field), "{flag} {value}: {err}");
    }
    let config = dir.path().join("run.yaml");
    std::fs::write(
        &config,
        "model: {network: mfnet, num_classes: 9}\nepochz: 3\n",
    )
    .unwrap();
    let err = fails(&["train", "--config", s(&config), "--out", s(&run)]);
    assert!(err.contains("run.yaml") && err.contains("epochz"), "{err}");
    // A teacher file without its network, and a missing teacher.
    let weights = dir.path().join("t.safetensors");
    std::fs::write(&weights, b"x").unwrap();
    let err = fails(&[
        "train",
        "--recipe",
        "heatnet-v3",
        "--data",
        s(&data),
        "--out",
        s(&run),
        "--teacher",
        s(&weights),
    ]);
    assert!(err.contains("--teacher-model"), "{err}");
    let err = fails(&[
        "train",
        "--recipe",
        "heatnet-v3",
        "--data",
        s(&data),
        "--out",
        s(&run),
        "--teacher",
        s(&dir.path().join("nope")),
    ]);
    assert!(err.contains("nope"), "{err}");
    assert!(!run.exists(), "nothing written");
}

#[test]
fn a_finished_run_is_never_overwritten_and_odd_sizes_train() {
    let dir = tempfile::tempdir().unwrap();
    let (data, run) = (dir.path().join("data"), dir.path().join("run"));
    // 97×61 is no multiple of MFNet's stride (16): training pads and crops as eval does.
    synth_mf(&data, "6", "2", "97x61");
    ok(&short_train(&data, &run, "1", &["--workers", "1"]));
    std::fs::remove_file(run.join("checkpoint.safetensors")).unwrap();
    let err = fails(&short_train(&data, &run, "1", &[]));
    assert!(err.contains("already holds a run"), "{err}");
    ok(&short_train(
        &data,
        &dir.path().join("r2"),
        "1",
        &["--resize", "33x17"],
    ));
}

#[test]
fn sigterm_checkpoints_like_ctrl_c() {
    let dir = tempfile::tempdir().unwrap();
    let (data, run) = (dir.path().join("data"), dir.path().join("run"));
    synth_mf(&data, "12", "4", "32x32");
    let out = train_then_signal(&data, &run, libc::SIGTERM);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{stderr}");
    assert!(run.join("checkpoint.safetensors").exists());
    assert!(
        !run.join("run.lock").exists(),
        "the lock goes with the process"
    );
    // A resume may extend the run, never cut it below what is done.
    let log = std::fs::read_to_string(run.join("log.jsonl")).unwrap_or_default();
    if log.lines().count() >= 2 {
        let err = fails(&["train", "--resume", s(&run), "--epochs", "1"]);
        assert!(err.contains("--epochs"), "{err}");
    }
    ok(&[
        "train",
        "--resume",
        s(&run),
        "--epochs",
        &(log.lines().count() + 1).to_string(),
    ]);
    assert!(run.join("final.safetensors").exists());
}

/// A real run's TensorBoard files, read with TensorBoard's own reader (`scripts/tb_read.py`
/// in the .venv), hold every scalar of its log.jsonl at the record's epoch, and the
/// validation prediction grid.
fn tensorboard_matches_log(run: &std::path::Path) {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let out = Command::new(root.join(".venv/bin/python"))
        .arg(root.join("scripts/tb_read.py"))
        .arg(run.join("tb"))
        .output()
        .expect(".venv/bin/python (run `cargo xtask setup`)");
    assert!(out.status.success(), "{}", text(&out));
    let read: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let log = std::fs::read_to_string(run.join("log.jsonl")).unwrap();
    let mut checked = 0;
    for line in log.lines() {
        let record: serde_json::Value = serde_json::from_str(line).unwrap();
        let epoch = record["epoch"].as_i64().unwrap();
        for (tag, value) in rtf_train::tensorboard::record_scalars(&record) {
            let points = read["scalars"][&tag]
                .as_array()
                .unwrap_or_else(|| panic!("tag `{tag}` missing from TensorBoard: {read}"));
            let at = points
                .iter()
                .find(|p| p[0].as_i64() == Some(epoch))
                .unwrap_or_else(|| panic!("{tag}: no point at epoch {epoch}"));
            let got = at[1].as_f64().unwrap();
            assert!(
                (got - value).abs() <= 1e-6 * value.abs().max(1.0),
                "{tag}@{epoch}: TensorBoard {got}, log {value}"
            );
            checked += 1;
        }
    }
    // Loss terms, learning rates, speed, the critic's accuracy and validation scores.
    for tag in [
        "loss/ce_day",
        "loss/adv",
        "lr/student",
        "lr/critic",
        "train/images_per_s",
        "train/data_wait_fraction",
        "train/critic_acc_night",
    ] {
        assert!(read["scalars"][tag].is_array(), "{tag}: {read}");
    }
    assert!(checked >= 10, "only {checked} scalars checked: {read}");
    let images = read["images"].as_object().unwrap();
    assert!(
        images.values().any(|v| !v.as_array().unwrap().is_empty()),
        "a prediction grid image: {read}"
    );
}

/// An RGB-only network carries its inputs in its weights: `rtf eval` and `rtf predict` mask
/// the thermal channel without being told, and an `--inputs` that contradicts the file is
/// refused rather than scored.
#[test]
fn a_network_trained_on_one_modality_is_evaluated_on_it_without_a_flag() {
    let dir = tempfile::tempdir().unwrap();
    let (data, run) = (dir.path().join("data"), dir.path().join("rgb"));
    synth_mf(&data, "8", "3", "64x48");
    ok(&short_train(&data, &run, "2", &["--inputs", "rgb"]));
    let weights = run.join("final.safetensors");
    let eval = |extra: &[&str], json: &str| -> serde_json::Value {
        let path = dir.path().join(json);
        let mut args = vec![
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
            s(&path),
        ];
        args.extend_from_slice(extra);
        ok(&args);
        json_file(&path)
    };
    let implicit = eval(&[], "implicit.json");
    let explicit = eval(&["--inputs", "rgb"], "explicit.json");
    assert_eq!(implicit["inputs"], "rgb");
    assert_eq!(implicit["miou"], explicit["miou"]);
    assert_eq!(implicit["confusion"], explicit["confusion"]);
    // Forced onto all four channels it is another (wrong) measurement: refused by default.
    let err = fails(&[
        "eval",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--data",
        s(&data),
        "--inputs",
        "rgb_t",
    ]);
    assert!(
        err.contains("final.safetensors") && err.contains("trained on `rgb` inputs"),
        "{err}"
    );
    // Changing the thermal channel does not change an RGB-only network's prediction.
    let frame = std::fs::read_dir(data.join("images"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .min()
        .unwrap();
    let mut image = image::open(&frame).unwrap().to_rgba8();
    let predict = |input: &std::path::Path, out: &str| -> Vec<u8> {
        let out = dir.path().join(out);
        ok(&[
            "predict",
            "--model",
            "mfnet",
            "--weights",
            s(&weights),
            "--out",
            s(&out),
            s(input),
        ]);
        // Every file predict wrote (class ids, colours), in name order.
        let mut files: Vec<_> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        files
            .iter()
            .flat_map(|p| image::open(p).unwrap().into_bytes())
            .collect()
    };
    let first = predict(&frame, "pred-a");
    for px in image.pixels_mut() {
        px.0[3] = 255 - px.0[3];
    }
    let flipped = dir.path().join("flipped.png");
    image.save(&flipped).unwrap();
    assert!(
        first == predict(&flipped, "pred-b"),
        "the thermal channel changed an RGB-only network's prediction"
    );
}

/// The parity controls (issue 27): `--init` starts from a weights file (checked before a run
/// folder exists: the error names the tensors that do not fit), `--no-shuffle` and
/// `--no-augment` are recorded in config.json and a resume keeps all three; each step's loss
/// lands in steps.jsonl.
#[test]
fn init_no_shuffle_and_no_augment_are_recorded_and_resumed() {
    let dir = tempfile::tempdir().unwrap();
    let (data, first, run) = (
        dir.path().join("data"),
        dir.path().join("first"),
        dir.path().join("run"),
    );
    synth_mf(&data, "12", "3", "32x32");
    let weights = ok(&short_train(&data, &first, "1", &[]));
    let weights = weights.trim();

    let wrong = dir.path().join("wrong");
    let err = fails(&short_train(
        &data,
        &wrong,
        "1",
        &["--model", "mfnet-paper", "--init", weights],
    ));
    assert!(
        err.contains("final.safetensors: weights do not match"),
        "{err}"
    );
    assert!(
        err.contains("decode4.conv.weight (network [64, 128, 3, 3], file [64, 132, 3, 3])"),
        "{err}"
    );
    assert!(
        !wrong.exists(),
        "nothing written for weights that do not fit"
    );

    let controls = [
        "--init",
        weights,
        "--no-shuffle",
        "--no-augment",
        "--val-split",
        "none",
    ];
    ok(&short_train(&data, &run, "2", &controls));
    let config = json_file(&run.join("config.json"));
    assert_eq!(config["data"]["shuffle"], false, "{config}");
    assert!(config["network"]["init_from"]["file"]
        .as_str()
        .unwrap()
        .ends_with("final.safetensors"));
    let augment = config["data"]["augment"].as_object().unwrap();
    assert!(
        augment.values().all(|v| v.is_null() || v == false),
        "every augmentation off: {config}"
    );
    let before = std::fs::read_to_string(run.join("config.json")).unwrap();
    ok(&["train", "--resume", s(&run), "--epochs", "2"]);
    let after = json_file(&run.join("config.json"));
    assert_eq!(after["data"]["shuffle"], false);
    assert_eq!(after["data"]["augment"], config["data"]["augment"]);
    assert_eq!(
        after["network"]["init_from"], config["network"]["init_from"],
        "{before}"
    );
    let steps = rtf_train::step_log::read(&run).unwrap();
    let epochs: Vec<usize> = steps.iter().map(|s| s.epoch).collect();
    assert_eq!(epochs, [0, 0, 1, 1], "{steps:?}");

    let err = fails(&["train", "--resume", s(&run), "--no-shuffle"]);
    assert!(err.contains("--no-shuffle"), "{err}");
}
