//! CMX through the commands (issue 39): a cmx-mit-b0 student trains from SegFormer-named
//! ImageNet MiT weights (`--backbone-weights`, both encoders, the log says what loaded), then
//! evaluates and predicts; the `cmx-mf` recipe trains with the official augmentation.

use std::path::Path;

use tch::{nn, Device, Kind, Tensor};

mod common;
use common::*;

/// A SegFormer `mit_b0`-named state_dict (patch_embedN, blockN, normN, the ImageNet head).
fn segformer_b0(file: &Path) {
    let vs = nn::VarStore::new(Device::Cpu);
    let cfg = rtf_models::ModelConfig::from_name("cmx-mit-b0", 9).unwrap();
    rtf_models::build(&vs.root(), &cfg).unwrap();
    let mut named = rtf_models::io::mit_pretrained::segformer_state_dict(&vs);
    named.push((
        "head.weight".into(),
        Tensor::zeros([1000, 256], (Kind::Float, Device::Cpu)),
    ));
    named.push((
        "head.bias".into(),
        Tensor::zeros([1000], (Kind::Float, Device::Cpu)),
    ));
    rtf_models::io::weights::save_named(&named, file).unwrap();
}

#[test]
fn a_cmx_student_trains_from_imagenet_mit_weights_then_evaluates_and_predicts() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("mf");
    synth_mf(&data, "6", "1", "64x64");
    let mit = tmp.path().join("mit_b0.safetensors");
    segformer_b0(&mit);
    let run = tmp.path().join("run");
    let extra = [
        "--model",
        "cmx-mit-b0",
        "--backbone-weights",
        s(&mit),
        "--val-split",
        "none",
    ];
    let out = rtf(&short_train(&data, &run, "1", &extra));
    let printed = text(&out);
    assert!(out.status.success(), "{printed}");
    assert!(
        printed.contains("backbone weights")
            && printed.contains("into the RGB and the thermal encoder"),
        "{printed}"
    );
    let weights = run.join("final.safetensors");
    let json = tmp.path().join("eval.json");
    ok(&[
        "eval",
        "--model",
        "cmx-mit-b0",
        "--weights",
        s(&weights),
        "--data",
        s(&data),
        "--json",
        s(&json),
    ]);
    let scores = json_file(&json);
    assert!(
        scores["class_names"]
            .as_array()
            .is_some_and(|c| c.len() == 9),
        "{scores}"
    );
    let image = std::fs::read_dir(data.join("images"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let pred = tmp.path().join("pred");
    ok(&[
        "predict",
        "--model",
        "cmx-mit-b0",
        "--weights",
        s(&weights),
        "--out",
        s(&pred),
        s(&image),
    ]);
    assert!(pred.join(image.file_name().unwrap()).is_file());
}

/// `rtf train --recipe cmx-mf`: config.json holds the official recipe (AdamW with its decay
/// scope and warm-up-then-poly schedule, the scale set with the network's normalised zero as
/// padding, the decoder's eps), flags still override it (batch 2), and steps run with the scale
/// and crop on (finite losses: padded labels are not counted). Without --model it says so.
#[test]
fn the_cmx_mf_recipe_trains_with_the_official_augmentation() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("mf");
    synth_mf(&data, "12", "2", "64x64");
    let run = tmp.path().join("run");
    let recipe = [
        "--recipe",
        "cmx-mf",
        "--val-split",
        "none",
        "--workers",
        "1",
    ];
    let out = rtf(&short_train(&data, &run, "3", &recipe));
    assert!(
        !out.status.success() && text(&out).contains("--model"),
        "{}",
        text(&out)
    );
    let extra = [&recipe[..], &["--model", "cmx-mit-b0"]].concat();
    ok(&short_train(&data, &run, "3", &extra));
    let cfg = json_file(&run.join("config.json"));
    let optimizer = &cfg["learning"]["optimizer"];
    assert_eq!(optimizer["kind"], "adamw", "{cfg}");
    assert_eq!(optimizer["decay_scope"], "conv_and_linear_weights");
    assert_eq!(optimizer["schedule"]["warmup_epochs"], 10);
    assert_eq!(
        cfg["schedule"]["batch_size"], 2,
        "--batch-size over the recipe's 8"
    );
    assert_eq!(cfg["network"]["model"]["decoder_bn_eps"], 1e-3);
    let scale_crop = &cfg["data"]["augment"]["scale_crop"];
    assert_eq!(
        scale_crop["scales"],
        serde_json::json!([0.5, 0.75, 1.0, 1.25, 1.5, 1.75])
    );
    let fill: Vec<f64> = scale_crop["fill"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let expected = [0.406, 0.456, 0.485, 0.4486];
    assert!(
        fill.iter().zip(expected).all(|(a, b)| (a - b).abs() < 1e-3),
        "{fill:?}"
    );
    let steps = rtf_train::step_log::read(&run).unwrap();
    let losses: Vec<f64> = steps.iter().map(|s| s.loss).collect();
    assert!(
        losses.len() == 3 && losses.iter().all(|l| l.is_finite() && *l > 0.0),
        "{losses:?}"
    );
}
