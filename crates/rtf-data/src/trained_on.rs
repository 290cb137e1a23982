//! What a network was trained on besides its tensors: the class set (ids, names, palette,
//! ignore id) and the thermal rule. A run records it in its config
//! (`DatasetConfig::Described`) and in its weights' safetensors metadata ([`WEIGHTS_KEY`]),
//! so that evaluating, predicting with or exporting those weights uses the same classes and
//! palette, and data with another class set is refused naming both lists rather than
//! scored under the wrong names.
//!
//! Weights without it (converted published weights, runs of older builds) are MF's 9
//! classes unless the user says otherwise, as before.

use std::collections::HashMap;
use std::path::Path;

use rtf_core::ClassSet;

use crate::description::DatasetDescription;
use crate::DataError;

/// What a network was trained on: the schema's (rtf-config), with its weights' metadata key.
pub use rtf_config::data::{TrainedOn, WEIGHTS_KEY};

/// What to do about weights that do not fit the data's classes.
pub const WEIGHTS_HINT: &str = "evaluate on data with the weights' classes, or fine-tune onto \
     these (rtf train --init WEIGHTS --reset-head)";

/// What a described dataset's weights record: its class set and thermal rule.
pub fn of(description: &DatasetDescription) -> TrainedOn {
    TrainedOn {
        classes: description.class_set.clone(),
        thermal: Some(description.thermal.clone()),
    }
}

/// The record in a weights file's metadata; None when it has none (older or converted
/// weights). `path` names the weights file in the error for a record that does not parse.
pub fn from_metadata(
    metadata: &HashMap<String, String>,
    path: &Path,
) -> Result<Option<TrainedOn>, DataError> {
    let Some(json) = metadata.get(WEIGHTS_KEY) else {
        return Ok(None);
    };
    serde_json::from_str(json)
        .map(Some)
        .map_err(|e| DataError::Format {
            path: path.to_path_buf(),
            message: format!("metadata `{WEIGHTS_KEY}` is not a class set this build reads: {e}"),
        })
}

/// Refuses data whose classes differ from those `trained` records (ids and names, in order;
/// the palette and the set's name may differ), naming the file that records them (weights,
/// a run's config), the data and both lists; `hint` says what to do instead.
pub fn check_data(
    trained: &TrainedOn,
    recorded_in: &Path,
    data: &Path,
    classes: &ClassSet,
    hint: &str,
) -> Result<(), DataError> {
    if trained.classes.names() == classes.names() {
        return Ok(());
    }
    Err(DataError::ClassSetMismatch {
        weights: recorded_in.to_path_buf(),
        data: data.to_path_buf(),
        trained: list(&trained.classes),
        found: list(classes),
        hint: hint.to_string(),
    })
}

/// `5 classes (pst900: background, fire_extinguisher, …)`.
pub fn list(classes: &ClassSet) -> String {
    format!(
        "{} classes ({}: {})",
        classes.len(),
        classes.name,
        classes.names().join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::thermal::ThermalNormalisation;

    #[test]
    fn the_record_round_trips_through_weights_metadata() {
        let trained = TrainedOn {
            classes: ClassSet::freiburg(),
            thermal: Some(ThermalNormalisation::Range {
                lo: 21800.0,
                hi: 25000.0,
                map: None,
            }),
        };
        let metadata = HashMap::from([trained.metadata_entry()]);
        let path = Path::new("w.safetensors");
        assert_eq!(from_metadata(&metadata, path).unwrap(), Some(trained));
        assert_eq!(from_metadata(&HashMap::new(), path).unwrap(), None);
        let bad = HashMap::from([(WEIGHTS_KEY.to_string(), "{\"classes\": 3}".to_string())]);
        let err = from_metadata(&bad, path).unwrap_err().to_string();
        assert!(
            err.starts_with("w.safetensors: metadata `rtf.data`"),
            "{err}"
        );
    }

    #[test]
    fn another_class_list_is_refused_naming_both_lists_the_weights_and_the_data() {
        let trained = TrainedOn {
            classes: ClassSet::mf(),
            thermal: None,
        };
        let (weights, data) = (Path::new("run/final.safetensors"), Path::new("data/fr"));
        let mut msrs = ClassSet::mf();
        msrs.name = "msrs".into();
        msrs.classes[1].color = [1, 2, 3];
        let check = |classes: &ClassSet| check_data(&trained, weights, data, classes, WEIGHTS_HINT);
        assert!(check(&msrs).is_ok(), "names decide, not palette");
        let err = check(&ClassSet::freiburg()).unwrap_err().to_string();
        for part in [
            "run/final.safetensors",
            "data/fr",
            "9 classes (mf: unlabeled, car, person",
            "13 classes (freiburg: road, sidewalk",
            "--reset-head",
        ] {
            assert!(err.contains(part), "{part} in {err}");
        }
    }
}
