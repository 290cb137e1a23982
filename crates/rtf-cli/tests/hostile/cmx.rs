//! CMX weights that do not fit (issue 39, "Bad input"): a checkpoint of another MiT size, of
//! another class count, of CMX given for another network, and SegFormer ImageNet weights of
//! the wrong size. Each is refused before anything runs, naming the file, the tensors and
//! both shapes (or both networks, where the file records its own).
//!
//! The files are made here from rtf's own CMX modules: with rtf's metadata (as `rtf train`
//! writes them) and without (as `cargo xtask convert-pth` turns an official `.pth` into).

use std::path::{Path, PathBuf};

use tch::{nn, Device, Kind, Tensor};

use crate::common::*;
use crate::verdict::{case, Case};
use crate::Fixture;

/// A freshly initialised `model` of `classes` classes, as named tensors.
fn cmx(model: &str, classes: i64) -> (nn::VarStore, rtf_models::ModelConfig) {
    let vs = nn::VarStore::new(Device::Cpu);
    let cfg = rtf_models::ModelConfig::from_name(model, classes).unwrap();
    rtf_models::build(&vs.root(), &cfg).unwrap();
    (vs, cfg)
}

/// CMX MiT-B0 weights of `classes` classes, with rtf's record of the network or bare.
fn cmx_b0(path: &Path, classes: i64, with_record: bool) -> PathBuf {
    let (vs, cfg) = cmx("cmx-mit-b0", classes);
    if with_record {
        let inputs = rtf_models::Modality::RgbT;
        rtf_models::io::weights::save_safetensors(&vs, &cfg, inputs, path).unwrap();
    } else {
        rtf_models::io::weights::save_named(&rtf_models::io::weights::state_dict(&vs), path)
            .unwrap();
    }
    path.to_path_buf()
}

/// SegFormer's ImageNet `mit_b1` file (encoder names, the classifier head).
fn segformer_b1(path: &Path) -> PathBuf {
    let (vs, _) = cmx("cmx-mit-b1", 9);
    let mut named = rtf_models::io::mit_pretrained::segformer_state_dict(&vs);
    let zeros = |shape: &[i64]| Tensor::zeros(shape, (Kind::Float, Device::Cpu));
    named.push(("head.weight".into(), zeros(&[1000, 512])));
    named.push(("head.bias".into(), zeros(&[1000])));
    rtf_models::io::weights::save_named(&named, path).unwrap();
    path.to_path_buf()
}

fn predict(name: &str, model: &str, weights: &Path, f: &Fixture, must: &[&str]) -> Case {
    let out = f.t.join(format!("cmx_out_{}", name.len()));
    let args = [
        "predict",
        "--model",
        model,
        "--weights",
        s(weights),
        "--out",
        s(&out),
        s(&f.good_image),
    ];
    case(&format!("cmx weights: {name}"), &args, must).intact(move || !out.exists())
}

pub fn cases(f: &Fixture) -> Vec<Case> {
    let p = |name: &str| f.t.join(name);
    let recorded = cmx_b0(&p("cmx_b0.safetensors"), 9, true);
    let bare = cmx_b0(&p("cmx_b0_official.safetensors"), 9, false);
    let bare41 = cmx_b0(&p("cmx_b0_nyu41.safetensors"), 41, false);
    let mit_b1 = segformer_b1(&p("mit_b1.safetensors"));
    let file = |path: &Path| path.file_name().unwrap().to_str().unwrap().to_string();
    let (recorded_name, bare_name, bare41_name, mit_name) =
        (file(&recorded), file(&bare), file(&bare41), file(&mit_b1));
    let eval_out = p("cmx_eval.json");
    let kept = eval_out.clone();
    vec![
        // rtf's record names both networks (variants share tensor names).
        predict(
            "rtf's MiT-B0 file asked as cmx-mit-b2",
            "cmx-mit-b2",
            &recorded,
            f,
            &[&recorded_name, "cmx-mit-b0", "cmx-mit-b2"],
        ),
        // An official checkpoint has no record: the tensors and both shapes are named.
        predict(
            "an official MiT-B0 checkpoint asked as cmx-mit-b2",
            "cmx-mit-b2",
            &bare,
            f,
            &[
                &bare_name,
                "backbone.block1.0.attn.q.weight",
                "network [64, 64]",
                "file [32, 32]",
            ],
        ),
        predict(
            "a CMX checkpoint given for rtfnet50",
            "rtfnet50",
            &bare,
            f,
            &[&bare_name, "missing", "unexpected", "backbone.FFMs.0"],
        ),
        case(
            "cmx weights: an official 41-class checkpoint evaluated on MF's 9 classes",
            &[
                "eval",
                "--model",
                "cmx-mit-b0",
                "--weights",
                s(&bare41),
                "--data",
                s(&f.data),
                "--json",
                s(&eval_out),
            ],
            &[
                &bare41_name,
                "decode_head.linear_pred.weight",
                "network [9, 512, 1, 1]",
                "file [41, 512, 1, 1]",
            ],
        )
        .intact(move || !kept.exists()),
        case(
            "cmx weights: SegFormer ImageNet mit_b1 as cmx-mit-b0's --backbone-weights",
            &short_train(
                &f.data,
                &p("cmx_run"),
                "1",
                &["--model", "cmx-mit-b0", "--backbone-weights", s(&mit_b1)],
            ),
            &[&mit_name, "block1.0.attn.q.weight", "[32, 32]", "[64, 64]"],
        ),
    ]
}
