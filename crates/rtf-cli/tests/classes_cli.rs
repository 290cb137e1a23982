//! Every network with N classes, end to end (issue 26 §3): a dataset's class set sizes the
//! network, and the weights carry it (with the thermal rule) so that eval, predict, export
//! and bench use it and data with another class set is refused naming both lists. Fixtures:
//! a plain-layout root (dataset.yaml, 3 classes, 16-bit thermal with `range:`), a PST900
//! root (5 classes), an FMB root (15 classes), generated here in their exact layouts.

use std::io::Read;
use std::path::{Path, PathBuf};

use tch::{Device, Kind, Tensor};

mod common;
use common::*;

const W: usize = 64;
const H: usize = 48;

/// How a fixture stores thermal.
#[derive(Clone, Copy)]
enum Thermal {
    Grey8,
    /// Raw counts 21800.. (a plain layout's `range: [21800, 25000]`).
    Raw16,
    /// Grey stored as three equal channels (FMB's release).
    GreyAsRgb,
}

/// `root/{train,test}/{rgb,thermal,labels}/fK.png` (folder names as given), 4 frames per
/// split, `n` classes in horizontal bands, so every class is in every frame.
fn rgbt_root(root: &Path, folders: [&str; 3], n: usize, thermal: Thermal) {
    use rtf_data::pngio::{write_png_u16, write_png_u8};
    for split in ["train", "test"] {
        for k in 0..4u8 {
            let file = |i: usize| root.join(split).join(folders[i]).join(format!("f{k}.png"));
            let rgb: Vec<u8> = (0..W * H * 3).map(|i| (i % 251) as u8 ^ k).collect();
            write_png_u8(&file(0), W, H, 3, &rgb).unwrap();
            match thermal {
                Thermal::Grey8 => {
                    let t: Vec<u8> = (0..W * H).map(|i| (i % 256) as u8).collect();
                    write_png_u8(&file(1), W, H, 1, &t).unwrap();
                }
                Thermal::GreyAsRgb => {
                    let t: Vec<u8> = (0..W * H * 3).map(|i| (i / 3 % 256) as u8).collect();
                    write_png_u8(&file(1), W, H, 3, &t).unwrap();
                }
                Thermal::Raw16 => {
                    let t: Vec<u16> = (0..W * H).map(|i| 21800 + (i % 3200) as u16).collect();
                    write_png_u16(&file(1), W, H, 1, &t).unwrap();
                }
            }
            let ids: Vec<u8> = (0..W * H).map(|i| ((i / W) * n / H) as u8).collect();
            write_png_u8(&file(2), W, H, 1, &ids).unwrap();
        }
    }
}

const PLAIN_YAML: &str = "name: yard
classes:
  - {id: 0, name: background, color: [0, 0, 0]}
  - {id: 1, name: person, color: [220, 20, 60]}
  - {id: 2, name: forklift, color: [250, 170, 30]}
ignore_id: 255
thermal:
  range: [21800, 25000]
";

fn plain_root(root: &Path) {
    rgbt_root(root, ["rgb", "thermal", "labels"], 3, Thermal::Raw16);
    std::fs::write(root.join("dataset.yaml"), PLAIN_YAML).unwrap();
}

fn pst900_root(root: &Path) {
    rgbt_root(root, ["rgb", "thermal", "labels"], 5, Thermal::Grey8);
}

/// One training step of MFNet on `data` into `run`; returns the final weights.
fn train(data: &Path, run: &Path) -> PathBuf {
    let out = rtf(&short_train(data, run, "1", &["--model", "mfnet"]));
    assert!(out.status.success(), "{}", text(&out));
    run.join("final.safetensors")
}

fn metadata(weights: &Path) -> rtf_data::TrainedOn {
    let file = rtf_models::io::weights::read_weights_metadata(weights).unwrap();
    rtf_data::trained_on::from_metadata(&file.metadata, weights)
        .unwrap()
        .expect("rtf train records the class set in the weights")
}

/// eval --json names the per-class IoUs by the class names.
fn eval_by_name(weights: &Path, data: &Path, names: &[&str], dir: &Path) {
    let json = dir.join("eval.json");
    let table = ok(&[
        "eval",
        "--model",
        "mfnet",
        "--weights",
        s(weights),
        "--data",
        s(data),
        "--json",
        s(&json),
    ]);
    let scores = json_file(&json);
    assert_eq!(scores["class_names"], serde_json::json!(names), "{scores}");
    let per_class: Vec<&str> = scores["per_class"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap())
        .collect();
    assert_eq!(per_class, names);
    for name in names {
        assert!(table.contains(name), "{name} in {table}");
    }
}

/// predict without --classes: the weights' classes and palette, N-channel logits.
fn predict_in_the_weights_palette(weights: &Path, data: &Path, n: usize, dir: &Path) -> String {
    let predicted = dir.join("pred");
    let rgb = data.join("test").join(rgb_folder(data)).join("f0.png");
    let thermal = data.join("test").join(thermal_folder(data)).join("f0.png");
    let out = rtf(&[
        "predict",
        "--model",
        "mfnet",
        "--weights",
        s(weights),
        "--out",
        s(&predicted),
        "--rgb",
        s(&rgb),
        "--thermal",
        s(&thermal),
        "--logits",
    ]);
    let printed = text(&out);
    assert!(out.status.success(), "{printed}");
    assert!(
        printed.contains(&format!("classes: the weights' {n} classes")),
        "{printed}"
    );
    let logits = std::fs::read(predicted.join("f0.npy")).unwrap();
    let header = String::from_utf8_lossy(&logits[..128]).into_owned();
    assert!(
        header.contains(&format!("'shape': ({n}, {H}, {W})")),
        "{header}"
    );
    let palette: Vec<[u8; 3]> = metadata(weights)
        .classes
        .classes
        .iter()
        .map(|c| c.color)
        .collect();
    let ids = u8_samples(&predicted.join("f0.png"));
    let colors = u8_samples(&predicted.join("f0_color.png"));
    for (pixel, &id) in colors.chunks_exact(3).zip(&ids) {
        assert!((id as usize) < n);
        assert_eq!(pixel, palette[id as usize], "the weights' palette");
    }
    printed
}

fn rgb_folder(data: &Path) -> &'static str {
    match data.join("train/Visible").is_dir() {
        true => "Visible",
        false => "rgb",
    }
}

fn thermal_folder(data: &Path) -> &'static str {
    match data.join("train/Infrared").is_dir() {
        true => "Infrared",
        false => "thermal",
    }
}

fn u8_samples(path: &Path) -> Vec<u8> {
    match rtf_data::pngio::read_png(path).unwrap().samples {
        rtf_data::pngio::Samples::U8(v) => v,
        _ => panic!("{}: 8-bit", path.display()),
    }
}

/// export --format torchscript: N outputs, the class names and colours in its metadata.
fn export_with_n_outputs(weights: &Path, names: &[&str], dir: &Path) -> serde_json::Value {
    let module = dir.join("net.pt");
    ok(&[
        "export",
        "--model",
        "mfnet",
        "--weights",
        s(weights),
        "--out",
        s(&module),
        "--format",
        "torchscript",
        "--size",
        "48x64",
    ]);
    let m = tch::CModule::load(&module).unwrap();
    let y =
        tch::no_grad(|| m.forward_ts(&[Tensor::rand([1, 4, 48, 64], (Kind::Float, Device::Cpu))]))
            .unwrap();
    assert_eq!(y.size(), [1, names.len() as i64, 48, 64]);
    let mut zip = zip::ZipArchive::new(std::fs::File::open(&module).unwrap()).unwrap();
    let name = zip
        .file_names()
        .find(|n| n.ends_with("extra/rtf.json"))
        .map(str::to_string)
        .expect("extra/rtf.json");
    let mut json = String::new();
    zip.by_name(&name)
        .unwrap()
        .read_to_string(&mut json)
        .unwrap();
    let meta: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(meta["num_classes"], names.len(), "{meta}");
    assert_eq!(meta["class_names"], serde_json::json!(names), "{meta}");
    assert_eq!(meta["output"]["shape"][1], names.len(), "{meta}");
    let err = fails(&[
        "export",
        "--model",
        "mfnet",
        "--weights",
        s(weights),
        "--out",
        s(&dir.join("x.pt")),
        "--format",
        "torchscript",
        "--classes",
        "9",
    ]);
    assert!(
        err.contains("--classes 9 does not fit") && err.contains(names[1]),
        "{err}"
    );
    meta
}

/// The whole chain for one root: train, weights' record, eval by name, predict, report,
/// export, bench.
fn end_to_end(data: &Path, names: &[&str], dir: &Path) -> PathBuf {
    let n = names.len();
    let run = dir.join("run");
    let weights = train(data, &run);
    let config = json_file(&run.join("config.json"));
    assert_eq!(config["network"]["model"]["num_classes"], n, "{config}");
    let recorded = &config["data"]["dataset"]["trained_on"]["classes"]["classes"];
    assert_eq!(recorded.as_array().map(Vec::len), Some(n), "{config}");
    assert_eq!(metadata(&weights).classes.names(), names);
    eval_by_name(&weights, data, names, dir);
    predict_in_the_weights_palette(&weights, data, n, dir);
    let page = dir.join("report.html");
    ok(&["report", s(&run), "--out", s(&page), "--frames", "2"]);
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.contains(names[n - 1]), "the report names the classes");
    export_with_n_outputs(&weights, names, dir);
    let bench = json_out(&[
        "bench",
        "model",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--size",
        "64x48",
        "--warmup",
        "0",
        "--iterations",
        "1",
        "--json",
    ]);
    assert_eq!(bench["num_classes"], n, "{bench}");
    weights
}

/// A plain layout with 3 classes and 16-bit thermal: the weights record the range, and
/// predict applies it to a 16-bit thermal file (said on stderr).
#[test]
fn a_three_class_plain_root_with_16_bit_thermal_goes_end_to_end() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("yard");
    plain_root(&data);
    let weights = end_to_end(&data, &["background", "person", "forklift"], tmp.path());
    let trained = metadata(&weights);
    assert_eq!(trained.classes.name, "yard");
    let rule = trained.thermal.expect("the thermal rule").describe();
    assert_eq!(rule, "range [21800, 25000] counts, clipped");
    let printed = predict_in_the_weights_palette(&weights, &data, 3, tmp.path());
    assert!(
        printed.contains("thermal: the weights' rule, range [21800, 25000]"),
        "{printed}"
    );
    // Given as its dataset.yaml, the root is its folder: the run records the folder.
    let by_file = tmp.path().join("run-by-file");
    train(&data.join("dataset.yaml"), &by_file);
    let root = |run: &Path| json_file(&run.join("config.json"))["data"]["dataset"]["root"].clone();
    assert_eq!(root(&by_file), root(&tmp.path().join("run")));
    assert_eq!(root(&by_file), s(&data));
}

/// PST900's 5 classes end to end; then the 5-class weights meet the 3-class root: eval and
/// predict refuse it naming the weights, the root and both class lists; predict with MF's
/// set too.
#[test]
fn a_five_class_pst900_root_goes_end_to_end_and_its_weights_refuse_other_classes() {
    let tmp = tempfile::tempdir().unwrap();
    let (pst, yard) = (tmp.path().join("pst900"), tmp.path().join("yard"));
    pst900_root(&pst);
    plain_root(&yard);
    let names = [
        "background",
        "fire_extinguisher",
        "backpack",
        "hand_drill",
        "survivor",
    ];
    let weights = end_to_end(&pst, &names, tmp.path());
    let err = fails(&[
        "eval",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--data",
        s(&yard),
    ]);
    for part in [
        s(&weights),
        s(&yard),
        "trained on 5 classes (pst900: background, fire_extinguisher, backpack, hand_drill, survivor)",
        "3 classes (yard: background, person, forklift)",
    ] {
        assert!(err.contains(part), "{part} in {err}");
    }
    let rgb = pst.join("test/rgb/f0.png");
    let thermal = pst.join("test/thermal/f0.png");
    for classes in [s(&yard), "mf"] {
        let out = tmp.path().join("refused");
        let err = fails(&[
            "predict",
            "--model",
            "mfnet",
            "--weights",
            s(&weights),
            "--out",
            s(&out),
            "--rgb",
            s(&rgb),
            "--thermal",
            s(&thermal),
            "--classes",
            classes,
        ]);
        assert!(err.contains("trained on 5 classes (pst900"), "{err}");
        assert!(!out.exists(), "nothing written");
    }
}

/// FMB's 15 classes (grey thermal stored as RGB, as the release does) train, evaluate and
/// predict from FMB's own files (predict reads them by the datasets' readers).
#[test]
fn a_fifteen_class_fmb_root_trains_evaluates_and_predicts_from_its_own_files() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("fmb");
    rgbt_root(
        &data,
        ["Visible", "Infrared", "Label"],
        15,
        Thermal::GreyAsRgb,
    );
    let weights = train(&data, &tmp.path().join("run"));
    let names = rtf_data::layouts::fmb::CLASSES.map(|(name, _)| name);
    assert_eq!(metadata(&weights).classes.names(), names);
    eval_by_name(&weights, &data, &names, tmp.path());
    predict_in_the_weights_palette(&weights, &data, names.len(), tmp.path());
}

/// A run records its classes; resuming it on a root whose classes changed is refused.
#[test]
fn resuming_a_run_whose_dataset_changed_its_classes_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("yard");
    plain_root(&data);
    let run = tmp.path().join("run");
    train(&data, &run);
    std::fs::write(
        data.join("dataset.yaml"),
        PLAIN_YAML.replace("forklift", "cart"),
    )
    .unwrap();
    let err = fails(&["train", "--resume", s(&run), "--epochs", "2"]);
    assert!(
        err.contains("3 classes (yard: background, person, forklift)")
            && err.contains("3 classes (yard: background, person, cart)")
            && err.contains("changed since the run started"),
        "{err}"
    );
}

/// ONNX of 3-class weights: 3 outputs in onnxruntime, the class names in `metadata_props`.
/// Slow (the PyTorch exporter, about a minute on two cores): RTF_TEST_ONNX=1.
#[test]
fn onnx_export_of_three_class_weights_has_three_outputs() {
    if std::env::var_os("RTF_TEST_ONNX").is_none() {
        eprintln!("skipped: set RTF_TEST_ONNX=1 to run the ONNX export check");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("yard");
    plain_root(&data);
    let weights = train(&data, &tmp.path().join("run"));
    let onnx = tmp.path().join("net.onnx");
    ok(&[
        "export",
        "--model",
        "mfnet",
        "--weights",
        s(&weights),
        "--out",
        s(&onnx),
        "--format",
        "onnx",
        "--size",
        "48x64",
    ]);
    let script = r#"
import json, sys
import numpy as np, onnx, onnxruntime as ort
model = onnx.load(sys.argv[1])
meta = {p.key: p.value for p in model.metadata_props}
s = ort.InferenceSession(sys.argv[1], providers=["CPUExecutionProvider"])
y = s.run(None, {"input": np.random.rand(1, 4, 48, 64).astype(np.float32)})[0]
print(json.dumps({"shape": list(y.shape), "meta": meta}))
"#;
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    let res = std::process::Command::new(python)
        .arg("-c")
        .arg(script)
        .arg(&onnx)
        .output()
        .unwrap();
    assert!(res.status.success(), "{}", text(&res));
    let v: serde_json::Value = serde_json::from_slice(&res.stdout).unwrap();
    assert_eq!(v["shape"], serde_json::json!([1, 3, 48, 64]), "{v}");
    let names: serde_json::Value =
        serde_json::from_str(v["meta"]["class_names"].as_str().unwrap()).unwrap();
    assert_eq!(
        names,
        serde_json::json!(["background", "person", "forklift"])
    );
}

/// Bad frames stop `rtf train` before a run folder is written, naming the file: a label id
/// outside the class list, partners of different sizes, an RGB without its thermal partner.
#[test]
fn bad_frames_stop_training_before_a_run_folder_is_written() {
    use rtf_data::pngio::write_png_u8;
    let tmp = tempfile::tempdir().unwrap();
    // (what, how the dataset is broken, what the error says)
    type Case<'a> = (&'a str, &'a dyn Fn(&Path), &'a str);
    let cases: [Case; 3] = [
        (
            "label id",
            &|d| write_png_u8(&d.join("train/labels/f2.png"), W, H, 1, &[3; W * H]).unwrap(),
            "train/labels/f2.png: label id 3 at (x 0, y 0) is not a class id",
        ),
        (
            "size",
            &|d| write_png_u8(&d.join("train/rgb/f1.png"), 32, 16, 3, &[0; 32 * 16 * 3]).unwrap(),
            "but its partner",
        ),
        (
            "partner",
            &|d| std::fs::remove_file(d.join("train/thermal/f3.png")).unwrap(),
            "train/thermal/f3.png",
        ),
    ];
    for (case, corrupt, expected) in cases {
        let data = tmp.path().join(case);
        plain_root(&data);
        corrupt(&data);
        let run = tmp.path().join(format!("{case}-run"));
        let err = fails(&short_train(&data, &run, "1", &["--model", "mfnet"]));
        assert!(err.contains(expected), "{case}: {err}");
        assert!(!run.exists(), "{case}: no run folder for bad data");
    }
}
