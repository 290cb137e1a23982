//! CMX through the commands (issue 39): a cmx-mit-b0 student trains from SegFormer-named
//! ImageNet MiT weights (`--backbone-weights`, both encoders, the log says what loaded), then
//! evaluates and predicts.

use std::path::Path;

use tch::{nn, Device, Kind, Tensor};

mod common;
use common::*;

/// A SegFormer `mit_b0`-named state_dict (patch_embedN, blockN, normN, the ImageNet head).
fn segformer_b0(file: &Path) {
    let vs = nn::VarStore::new(Device::Cpu);
    let cfg = rtf_models::ModelConfig::from_name("cmx-mit-b0", 9).unwrap();
    rtf_models::build(&vs.root(), &cfg).unwrap();
    let mut named = rtf_models::mit_pretrained::segformer_state_dict(&vs);
    named.push((
        "head.weight".into(),
        Tensor::zeros([1000, 256], (Kind::Float, Device::Cpu)),
    ));
    named.push((
        "head.bias".into(),
        Tensor::zeros([1000], (Kind::Float, Device::Cpu)),
    ));
    rtf_models::weights::save_named(&named, file).unwrap();
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
