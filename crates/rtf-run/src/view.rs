//! A training's configuration read without its types ([`TrainingView`]): the settings a
//! reader of run folders uses (`rtf report`: the network, its inputs, the dataset and its
//! validation split, the frame size), from either layout of `config.json`: today's sections,
//! or the flat layout of the early builds. The top level is read strictly (a key of neither
//! layout is an error naming it, as rtf-train's typed configuration says); inside the
//! sections only what the view holds is read. The typed configuration is rtf-train's.

use std::path::PathBuf;

use serde::Deserialize;
use serde_json::Value;

/// The sections of today's layout.
pub const SECTIONS: [&str; 5] = ["network", "data", "learning", "schedule", "compute"];

/// The keys of the flat layout written before the sections.
pub const FLAT_KEYS: [&str; 25] = [
    "model",
    "dataset",
    "epochs",
    "batch_size",
    "seed",
    "optimizer",
    "loss",
    "augment",
    "shuffle",
    "resize",
    "max_steps_per_epoch",
    "checkpoint_every",
    "workers",
    "device",
    "backbone_weights",
    "procedure",
    "inputs",
    "init_from",
    "init_reset_head",
    "select_by",
    "tb_images_every",
    "precision",
    "sync_batch_norm",
    "data_fingerprint",
    "world_size",
];

/// What a reader of a run folder sees of one training's configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainingView {
    /// `network.model` as recorded (rtf-models' `ModelConfig` reads it).
    pub model: Value,
    /// `network.inputs` as recorded (None: the default, every channel).
    pub inputs: Option<Value>,
    pub dataset: DatasetView,
    /// `data.resize`: the (width, height) frames were trained at; None: as stored.
    pub resize: Option<(usize, usize)>,
}

/// The dataset a training read.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct DatasetView {
    /// `mf`, `freiburg` or `described`.
    pub format: String,
    pub root: PathBuf,
    /// The split validation read (MF and described roots; Freiburg's validation is its test
    /// layout: None).
    #[serde(default)]
    pub val_split: Option<String>,
}

#[derive(Deserialize)]
struct Network {
    model: Value,
    #[serde(default)]
    inputs: Option<Value>,
}

#[derive(Deserialize)]
struct Data {
    dataset: DatasetView,
    #[serde(default)]
    resize: Option<(usize, usize)>,
}

#[derive(Deserialize)]
struct Sections {
    network: Network,
    data: Data,
}

#[derive(Deserialize)]
struct Flat {
    model: Value,
    #[serde(default)]
    inputs: Option<Value>,
    dataset: DatasetView,
    #[serde(default)]
    resize: Option<(usize, usize)>,
}

/// A key of `document` that `known` does not hold, as serde says it.
fn unknown_key(document: &Value, known: &[&str]) -> Result<(), String> {
    let Some(object) = document.as_object() else {
        return Err("not a JSON object".into());
    };
    match object.keys().find(|k| !known.contains(&k.as_str())) {
        Some(key) => Err(format!(
            "unknown field `{key}`, expected one of {}",
            known
                .iter()
                .map(|k| format!("`{k}`"))
                .collect::<Vec<_>>()
                .join(", ")
        )),
        None => Ok(()),
    }
}

impl TrainingView {
    /// The view of a training's configuration `document` (either layout), or why not.
    pub fn of(document: &Value) -> Result<Self, String> {
        let sectioned = SECTIONS.iter().any(|key| document.get(key).is_some());
        if !sectioned {
            unknown_key(document, &FLAT_KEYS)?;
            let flat = Flat::deserialize(document).map_err(|e| e.to_string())?;
            return Ok(Self {
                model: flat.model,
                inputs: flat.inputs,
                dataset: flat.dataset,
                resize: flat.resize,
            });
        }
        unknown_key(document, &SECTIONS)?;
        if let Some(missing) = SECTIONS.iter().find(|key| document.get(key).is_none()) {
            return Err(format!("missing field `{missing}`"));
        }
        let s = Sections::deserialize(document).map_err(|e| e.to_string())?;
        Ok(Self {
            model: s.network.model,
            inputs: s.network.inputs,
            dataset: s.data.dataset,
            resize: s.data.resize,
        })
    }

    /// The split validation read, unless the dataset is Freiburg Thermal's (its test layout).
    pub fn val_split(&self) -> Option<&str> {
        match self.dataset.format.as_str() {
            "freiburg" => None,
            _ => self.dataset.val_split.as_deref(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_layouts_read_and_a_key_of_neither_is_named() {
        let sections = serde_json::json!({
            "network": {"model": {"name": "mfnet"}, "inputs": "rgb"},
            "data": {"dataset": {"format": "mf", "root": "/d", "train_split": "train",
                                 "val_split": "val"}, "resize": [64, 48], "workers": 2},
            "learning": {}, "schedule": {}, "compute": {}
        });
        let view = TrainingView::of(&sections).unwrap();
        assert_eq!(view.val_split(), Some("val"));
        assert_eq!(
            (view.resize, view.inputs),
            (Some((64, 48)), Some("rgb".into()))
        );
        let flat = serde_json::json!({"model": {"name": "mfnet"}, "epochs": 2,
            "dataset": {"format": "freiburg", "root": "/f", "validate": true}});
        let view = TrainingView::of(&flat).unwrap();
        assert_eq!(view.val_split(), None);
        assert_eq!(view.dataset.root, PathBuf::from("/f"));
        let mut future = sections.clone();
        future["from_the_future"] = serde_json::json!(1);
        let err = TrainingView::of(&future).unwrap_err();
        assert!(err.contains("`from_the_future`"), "{err}");
        let err = TrainingView::of(&serde_json::json!({"network": {"model": 1}})).unwrap_err();
        assert!(err.contains("missing field `data`"), "{err}");
    }
}
