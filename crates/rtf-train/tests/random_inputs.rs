//! Stable-Rust randomised run of the readers of a run's files: `config.json` (what `--resume`
//! reads) and safetensors weights (what predict, eval and `--init` read), on seeded mutations
//! of a valid file and random bytes ([`rtf_data::fuzzing::mutations`]): a value or an error
//! naming the file, never a panic.

use rtf_data::fuzzing::check_reader;
use rtf_models::io::weights::{load_checked, read_weights_file, read_weights_metadata};
use rtf_models::{Modality, ModelConfig};
use rtf_train::config::{RunConfig, TrainConfig};
use tch::{nn::VarStore, Device, Kind, Tensor};

#[test]
fn config_json_never_panics() {
    let dir = tempfile::tempdir().unwrap();
    let config = RunConfig::Single(Box::new(TrainConfig::mfnet_paper("data".into())));
    let valid = serde_json::to_string_pretty(&config).unwrap();
    let path = dir.path().join(rtf_train::trainer::CONFIG_FILE);
    let outcome = check_reader(
        "config.json",
        valid.as_bytes(),
        11,
        800,
        "config.json",
        |b| {
            std::fs::write(&path, b).unwrap();
            rtf_train::trainer::read_config(dir.path())
        },
    );
    assert!(outcome.refused > 400, "{outcome:?}");
}

#[test]
fn safetensors_weights_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.safetensors");
    // A small file of several dtypes with rtf's metadata: the header parser and conversion.
    let cfg = ModelConfig::from_name("mfnet", 9).unwrap();
    let named = vec![
        (
            "a.weight".to_string(),
            Tensor::arange(24, (Kind::Float, Device::Cpu)).view([2, 3, 4]),
        ),
        (
            "a.bias".to_string(),
            Tensor::ones([5], (Kind::BFloat16, Device::Cpu)),
        ),
        ("steps".to_string(), Tensor::from(7i64)),
    ];
    let metadata = rtf_models::io::weights::model_metadata(&cfg, Modality::RgbT);
    rtf_models::io::weights::save_named_with_metadata(&named, Some(metadata), &path).unwrap();
    let small = std::fs::read(&path).unwrap();
    let outcome = check_reader("safetensors", &small, 12, 600, "w.safetensors", |b| {
        std::fs::write(&path, b).unwrap();
        read_weights_metadata(&path)?;
        let file = read_weights_file(&path)?;
        file.saved_config(&path)?;
        file.saved_inputs(&path)
    });
    assert!(outcome.refused > 150, "{outcome:?}");
    // A whole network's weights, loaded with the name, shape and value checks.
    let vs = VarStore::new(Device::Cpu);
    rtf_models::build(&vs.root(), &cfg).unwrap();
    rtf_models::io::weights::save_safetensors(&vs, &cfg, Modality::RgbT, &path).unwrap();
    let network = std::fs::read(&path).unwrap();
    let vs = std::cell::RefCell::new(vs);
    let outcome = check_reader("mfnet weights", &network, 13, 30, "w.safetensors", |b| {
        std::fs::write(&path, b).unwrap();
        load_checked(&mut vs.borrow_mut(), &cfg, &path, false)
    });
    assert!(outcome.refused > 8, "{outcome:?}");
}
