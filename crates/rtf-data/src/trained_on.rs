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
use serde::{Deserialize, Serialize};

use crate::description::DatasetDescription;
use crate::thermal::ThermalNormalisation;
use crate::DataError;

/// Metadata key of the weights' [`TrainedOn`] (JSON).
pub const WEIGHTS_KEY: &str = "rtf.data";

/// What to do about weights that do not fit the data's classes.
pub const WEIGHTS_HINT: &str = "evaluate on data with the weights' classes, or fine-tune onto \
     these (rtf train --init WEIGHTS --reset-head)";

/// The class set and thermal rule a network was trained with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainedOn {
    pub classes: ClassSet,
    /// How thermal became [0, 1]; None where the layout fixes it (MF: byte / 255; Freiburg:
    /// its preprocessing's clip).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thermal: Option<ThermalNormalisation>,
}

impl TrainedOn {
    /// A described dataset's class set and thermal rule.
    pub fn of(description: &DatasetDescription) -> Self {
        Self {
            classes: description.class_set.clone(),
            thermal: Some(description.thermal.clone()),
        }
    }

    /// What weights trained on MF record: its 9 classes, thermal as byte / 255.
    pub fn mf() -> Self {
        Self {
            classes: ClassSet::mf(),
            thermal: Some(ThermalNormalisation::Byte),
        }
    }

    /// What weights trained on Freiburg Thermal (or BDD, read with its classes) record: its 13
    /// classes; the thermal rule is the preprocessing's clip.
    pub fn freiburg() -> Self {
        Self {
            classes: ClassSet::freiburg(),
            thermal: None,
        }
    }

    /// The metadata entry for a weights file.
    pub fn metadata_entry(&self) -> (String, String) {
        let json = serde_json::to_string(self).expect("a class set serialises");
        (WEIGHTS_KEY.to_string(), json)
    }

    /// The record in a weights file's metadata; None when it has none (older or converted
    /// weights). `path` names the weights file in the error for a record that does not parse.
    pub fn from_metadata(
        metadata: &HashMap<String, String>,
        path: &Path,
    ) -> Result<Option<Self>, DataError> {
        let Some(json) = metadata.get(WEIGHTS_KEY) else {
            return Ok(None);
        };
        serde_json::from_str(json)
            .map(Some)
            .map_err(|e| DataError::Format {
                path: path.to_path_buf(),
                message: format!(
                    "metadata `{WEIGHTS_KEY}` is not a class set this build reads: {e}"
                ),
            })
    }

    /// Refuses data whose classes differ from the trained ones (ids and names, in order; the
    /// palette and the set's name may differ), naming the file that records them (weights,
    /// a run's config), the data and both lists; `hint` says what to do instead.
    pub fn check_data(
        &self,
        recorded_in: &Path,
        data: &Path,
        classes: &ClassSet,
        hint: &str,
    ) -> Result<(), DataError> {
        if self.classes.names() == classes.names() {
            return Ok(());
        }
        Err(DataError::ClassSetMismatch {
            weights: recorded_in.to_path_buf(),
            data: data.to_path_buf(),
            trained: list(&self.classes),
            found: list(classes),
            hint: hint.to_string(),
        })
    }
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
        assert_eq!(
            TrainedOn::from_metadata(&metadata, path).unwrap(),
            Some(trained)
        );
        assert_eq!(
            TrainedOn::from_metadata(&HashMap::new(), path).unwrap(),
            None
        );
        let bad = HashMap::from([(WEIGHTS_KEY.to_string(), "{\"classes\": 3}".to_string())]);
        let err = TrainedOn::from_metadata(&bad, path)
            .unwrap_err()
            .to_string();
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
        let check = |classes: &ClassSet| trained.check_data(weights, data, classes, WEIGHTS_HINT);
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
