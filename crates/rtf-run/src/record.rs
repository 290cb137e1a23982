//! The records of `log.jsonl`: one [`EpochRecord`] per finished epoch, with the epoch's
//! validation scores ([`ValRecord`]) when the run validates.
//!
//! Two schemas have been written: the first builds' flat record (`epoch`, `lr`, `train_loss`,
//! `images`, `seconds`, `images_per_s`, `data_wait_fraction`, `val_miou`, `val_macc`), and
//! today's, which adds the loss terms, every network's learning rate, training metrics and the
//! nested validation scores. Both read as [`EpochRecord`] (the later fields default to
//! empty). JSON has no NaN: a non-finite number is written as `null`, and a `null` where a
//! number belongs reads back as NaN (readers skip non-finite values).

use std::collections::BTreeMap;

use serde::{Deserialize, Deserializer, Serialize};

/// Validation scores of one epoch (percent-free fractions like every score of rtf-eval).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ValRecord {
    #[serde(deserialize_with = "number")]
    pub miou: f64,
    #[serde(deserialize_with = "number")]
    pub macc: f64,
    #[serde(default)]
    pub miou_day: Option<f64>,
    #[serde(default)]
    pub miou_night: Option<f64>,
    /// HeatNet's convention (Freiburg only): day, night and their mean.
    #[serde(default)]
    pub miou_heatnet_day: Option<f64>,
    #[serde(default)]
    pub miou_heatnet_night: Option<f64>,
    #[serde(default)]
    pub miou_heatnet: Option<f64>,
    #[serde(default)]
    pub per_class_iou: BTreeMap<String, Option<f64>>,
    #[serde(default)]
    pub per_class_iou_day: BTreeMap<String, Option<f64>>,
    #[serde(default)]
    pub per_class_iou_night: BTreeMap<String, Option<f64>>,
    /// The score that picks `best.safetensors`, and its value.
    pub selected_by: String,
    #[serde(deserialize_with = "number")]
    pub selected: f64,
}

/// What one epoch did (a line of `log.jsonl`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochRecord {
    pub epoch: usize,
    /// The student's learning rate (at the epoch's first step).
    #[serde(deserialize_with = "number")]
    pub lr: f64,
    /// Mean of the student's objective over the epoch's steps.
    #[serde(deserialize_with = "number")]
    pub train_loss: f64,
    pub images: usize,
    #[serde(deserialize_with = "number")]
    pub seconds: f64,
    #[serde(deserialize_with = "number")]
    pub images_per_s: f64,
    /// Share of the epoch's time spent waiting for the data pipeline.
    #[serde(deserialize_with = "number")]
    pub data_wait_fraction: f64,
    pub val_miou: Option<f64>,
    pub val_macc: Option<f64>,
    /// Every loss term by name, mean over the epoch's steps.
    #[serde(default, deserialize_with = "numbers")]
    pub losses: BTreeMap<String, f64>,
    /// Learning rate of every trained network, by role.
    #[serde(default, deserialize_with = "numbers")]
    pub lrs: BTreeMap<String, f64>,
    /// Training metrics (the critic's day / night accuracy), mean over the epoch's steps.
    #[serde(default, deserialize_with = "numbers")]
    pub metrics: BTreeMap<String, f64>,
    #[serde(default)]
    pub val: Option<ValRecord>,
}

/// A number, or `null` (how serde_json writes a non-finite one) as NaN.
fn number<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// A map of numbers, `null` values as NaN.
fn numbers<'de, D: Deserializer<'de>>(d: D) -> Result<BTreeMap<String, f64>, D::Error> {
    let map = BTreeMap::<String, Option<f64>>::deserialize(d)?;
    Ok(map
        .into_iter()
        .map(|(k, v)| (k, v.unwrap_or(f64::NAN)))
        .collect())
}

/// Only the epoch of a log line (a line of any schema that has one).
#[derive(Deserialize)]
pub(crate) struct EpochOnly {
    pub epoch: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A line of the first builds' log (tests/fixtures-style flat record) reads with the
    /// later fields empty.
    #[test]
    fn the_first_schema_reads_with_the_later_fields_empty() {
        let line = r#"{"epoch":0,"lr":0.01,"train_loss":2.3,"images":4,"seconds":1.5,"images_per_s":2.5,"data_wait_fraction":0.1,"val_miou":0.05,"val_macc":null}"#;
        let r: EpochRecord = serde_json::from_str(line).unwrap();
        assert_eq!((r.epoch, r.val_miou, r.val_macc), (0, Some(0.05), None));
        assert!(r.losses.is_empty() && r.lrs.is_empty() && r.metrics.is_empty());
        assert!(r.val.is_none());
    }

    /// What serde_json writes for a non-finite number (null) reads back as NaN, and a record
    /// is written back byte for byte as it was read.
    #[test]
    fn null_numbers_read_as_nan_and_records_round_trip() {
        let record = EpochRecord {
            epoch: 3,
            lr: 0.01,
            train_loss: f64::NAN,
            images: 8,
            seconds: 2.0,
            images_per_s: 4.0,
            data_wait_fraction: 0.25,
            val_miou: None,
            val_macc: None,
            losses: BTreeMap::from([("ce".to_string(), f64::INFINITY)]),
            lrs: BTreeMap::from([("student".to_string(), 0.01)]),
            metrics: BTreeMap::new(),
            val: Some(ValRecord {
                miou: 0.5,
                selected_by: "miou".into(),
                selected: 0.5,
                ..ValRecord::default()
            }),
        };
        let line = serde_json::to_string(&record).unwrap();
        assert!(line.contains(r#""train_loss":null"#) && line.contains(r#""ce":null"#));
        let back: EpochRecord = serde_json::from_str(&line).unwrap();
        assert!(back.train_loss.is_nan() && back.losses["ce"].is_nan());
        assert_eq!(serde_json::to_string(&back).unwrap(), line);
        assert_eq!(back.val, record.val);
    }
}
