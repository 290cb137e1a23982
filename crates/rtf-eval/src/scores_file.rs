//! The scores file `rtf eval --json` writes ([`ScoresFile`], schema [`crate::EVAL_SCHEMA`],
//! read back by rtf-report): RTFNet's convention at the top level, the MFNet paper's mIoU
//! beside it, HeatNet's for Freiburg Thermal, the confusion matrix, and the scores with a
//! modality missing. Its own module so that what the file holds is defined once, by the crate
//! that computes the scores, not by the command that prints them.

use std::path::PathBuf;

use serde::Serialize;

use crate::metrics::HEATNET_MIOU_CLASSES;
use crate::{EvalReport, Scores};

/// Scores with one modality missing (`--drop`).
#[derive(Serialize)]
pub struct DroppedScores {
    #[serde(flatten)]
    pub drop: crate::ModalityDrop,
    #[serde(flatten)]
    pub all: Scores,
    pub day: Option<Scores>,
    pub night: Option<Scores>,
}

/// `--json` contents: RTFNet convention at the top level (spec §2), MFNet paper's mIoU beside
/// it; for Freiburg Thermal also HeatNet's convention.
#[derive(Serialize)]
pub struct ScoresFile<'a> {
    pub schema: &'static str,
    pub model: &'a str,
    /// The channels the network saw (its weights' record or --inputs).
    pub inputs: rtf_models::Modality,
    pub weights: &'a PathBuf,
    pub data: &'a PathBuf,
    pub split: &'a str,
    /// How the network was run: mode (whole / sliding, with crop and stride rate), scales,
    /// flip.
    pub inference: &'a crate::InferenceOptions,
    pub frames: usize,
    #[serde(flatten)]
    pub all: &'a Scores,
    pub day: Option<&'a Scores>,
    pub night: Option<&'a Scores>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heatnet: Option<HeatnetScores>,
    /// `--class-map`: the map, the classes it scores and their mean IoU; the scores and the
    /// matrix above are then over the scored classes and "other".
    #[serde(skip_serializing_if = "Option::is_none")]
    pub class_map: Option<crate::ClassMapScores>,
    /// Content hash of the data evaluated (`rtf data fingerprint`).
    pub data_fingerprint: &'a rtf_data::Fingerprint,
    /// Class names, then the split's pixel counts, rows = truth, columns = prediction.
    pub class_names: Vec<&'a str>,
    pub confusion: Vec<Vec<u64>>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub dropped: Vec<DroppedScores>,
}

/// HeatNet's convention (spec §2): mIoU over classes 0–11 with undefined classes skipped;
/// "day/night" is the mean of the day and the night mIoU.
#[derive(Serialize)]
pub struct HeatnetScores {
    pub miou: Option<f64>,
    pub day_miou: Option<f64>,
    pub night_miou: Option<f64>,
    pub day_night_miou: Option<f64>,
}

impl HeatnetScores {
    pub fn of(report: &EvalReport) -> Self {
        let miou = |s: &Scores| s.miou_heatnet(HEATNET_MIOU_CLASSES);
        let day_miou = report.day.as_ref().and_then(miou);
        let night_miou = report.night.as_ref().and_then(miou);
        Self {
            miou: miou(&report.all),
            day_miou,
            night_miou,
            day_night_miou: day_miou.zip(night_miou).map(|(d, n)| (d + n) / 2.0),
        }
    }
}

/// What `--drop` means for a network that sees one modality (None: it sees both).
pub fn single_modality_note(
    dropped: rtf_models::Modality,
    sees: rtf_models::Modality,
) -> Option<String> {
    use rtf_models::Modality::RgbT;
    match sees {
        RgbT => None,
        only if only == dropped => Some(format!(
            "the network sees only {} (its weights' inputs): without it, it sees nothing",
            only.name()
        )),
        only => Some(format!(
            "the network sees only {} (its weights' inputs), never {}: the scores equal the \
             plain ones",
            only.name(),
            dropped.name()
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::single_modality_note;
    use rtf_models::Modality::{Rgb, RgbT, Thermal};

    #[test]
    fn drop_notes_say_what_a_single_modality_network_sees() {
        assert_eq!(single_modality_note(Rgb, RgbT), None);
        let unseen = single_modality_note(Thermal, Rgb).unwrap();
        assert!(
            unseen.contains("never thermal") && unseen.contains("equal"),
            "{unseen}"
        );
        let only = single_modality_note(Thermal, Thermal).unwrap();
        assert!(only.contains("sees nothing"), "{only}");
    }
}
