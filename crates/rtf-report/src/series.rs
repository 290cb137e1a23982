//! The series a report draws, taken from a run's typed epoch records (both log schemas):
//! loss terms, learning rates, validation scores, the last validation's per-class IoU.
//! Non-finite values (JSON's `null`) are left out.

use std::collections::BTreeMap;

use rtf_run::EpochRecord;

/// A class's (name, day or overall IoU, night IoU).
pub(crate) type ClassRow = (String, Option<f64>, Option<f64>);

/// Named series of a run's log: (tag, points).
pub(crate) type Series = Vec<(String, Vec<(f64, f64)>)>;

fn series_of(log: &[EpochRecord], pick: impl Fn(&EpochRecord) -> Vec<(String, f64)>) -> Series {
    let mut map: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    for e in log {
        for (name, v) in pick(e) {
            if v.is_finite() {
                map.entry(name).or_default().push((e.epoch as f64, v));
            }
        }
    }
    map.into_iter().collect()
}

/// The finite values of a map of numbers by name.
fn numbers(map: &BTreeMap<String, f64>) -> Vec<(String, f64)> {
    map.iter()
        .filter(|(_, v)| v.is_finite())
        .map(|(k, v)| (k.clone(), *v))
        .collect()
}

fn finite(v: Option<f64>) -> Option<f64> {
    v.filter(|v| v.is_finite())
}

/// Every loss term, and the total (`train_loss`).
pub(crate) fn loss_series(log: &[EpochRecord]) -> Series {
    series_of(log, |r| {
        let mut out = numbers(&r.losses);
        if let Some(v) = finite(Some(r.train_loss)) {
            out.push(("total".into(), v));
        }
        out
    })
}

/// Every network's learning rate (`lrs`), else the student's (`lr`, the first schema).
pub(crate) fn lr_series(log: &[EpochRecord]) -> Series {
    series_of(log, |r| {
        let mut out = numbers(&r.lrs);
        if out.is_empty() {
            if let Some(v) = finite(Some(r.lr)) {
                out.push(("lr".into(), v));
            }
        }
        out
    })
}

/// Validation mIoU, mAcc, day, night and HeatNet's convention (the nested scores, else the
/// first schema's flat ones), and the training metrics.
pub(crate) fn val_series(log: &[EpochRecord]) -> Series {
    series_of(log, |r| {
        let mut out = Vec::new();
        if let Some(val) = &r.val {
            let scores = [
                ("miou", Some(val.miou)),
                ("macc", Some(val.macc)),
                ("miou_day", val.miou_day),
                ("miou_night", val.miou_night),
                ("miou_heatnet", val.miou_heatnet),
            ];
            for (key, v) in scores {
                if let Some(v) = finite(v) {
                    out.push((key.to_string(), v));
                }
            }
        }
        for (key, flat) in [("miou", r.val_miou), ("macc", r.val_macc)] {
            if !out.iter().any(|(k, _)| k == key) {
                if let Some(v) = finite(flat) {
                    out.push((key.to_string(), v));
                }
            }
        }
        out.extend(numbers(&r.metrics));
        out
    })
}

/// (class, day IoU, night IoU) of the last validation; the IoU over all its frames (no night
/// column) when it had no day frame (a dataset without day and night).
pub(crate) fn last_class_iou(log: &[EpochRecord]) -> Option<Vec<ClassRow>> {
    let val = log.iter().rev().find_map(|e| e.val.as_ref())?;
    if val.per_class_iou_day.is_empty() {
        let all = val.per_class_iou.iter();
        return Some(all.map(|(k, v)| (k.clone(), *v, None)).collect());
    }
    let night = &val.per_class_iou_night;
    Some(
        val.per_class_iou_day
            .iter()
            .map(|(k, v)| (k.clone(), *v, night.get(k).copied().flatten()))
            .collect(),
    )
}

/// The last value of `name`.
pub(crate) fn last(series: &Series, name: &str) -> Option<f64> {
    series
        .iter()
        .find(|(n, _)| n == name)
        .and_then(|(_, p)| p.last().map(|p| p.1))
}

/// The (epoch, value) of the highest point of `name` (the first epoch on a tie).
pub(crate) fn best_point(series: &Series, name: &str) -> Option<(f64, f64)> {
    let (_, points) = series.iter().find(|(n, _)| n == name)?;
    points
        .iter()
        .copied()
        .fold(None, |acc: Option<(f64, f64)>, p| match acc {
            Some(a) if a.1 >= p.1 => Some(a),
            _ => Some(p),
        })
}

pub(crate) fn last_point(series: &Series, name: &str) -> Option<(f64, f64)> {
    let (_, points) = series.iter().find(|(n, _)| n == name)?;
    points.last().copied()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A first-schema record (flat fields) and today's (loss terms, learning rates, nested
    /// scores with day and night per-class IoU).
    fn log() -> Vec<EpochRecord> {
        [
            r#"{"epoch":1,"lr":0.01,"train_loss":2.0,"images":2,"seconds":1.0,"images_per_s":2.0,"data_wait_fraction":0.0,"val_miou":0.1,"val_macc":null}"#,
            r#"{"epoch":2,"lr":0.01,"train_loss":1.0,"images":2,"seconds":1.0,"images_per_s":2.0,"data_wait_fraction":0.0,"val_miou":0.2,"val_macc":0.3,
               "losses":{"ce":0.9,"adv":null},"lrs":{"seg":0.01,"critic":0.001},"metrics":{},
               "val":{"miou":0.2,"macc":0.3,"miou_day":0.3,"miou_night":0.1,"selected_by":"miou","selected":0.2,
                      "per_class_iou":{"car":0.4,"person":null},
                      "per_class_iou_day":{"car":0.5,"person":null},"per_class_iou_night":{"car":0.25}}}"#,
        ]
        .iter()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
    }

    #[test]
    fn both_log_schemas_give_series() {
        let log = log();
        let loss = loss_series(&log);
        assert_eq!(last(&loss, "total"), Some(1.0));
        assert_eq!(last(&loss, "ce"), Some(0.9));
        assert!(
            loss.iter().all(|(n, _)| n != "adv"),
            "null terms are left out"
        );
        let lr = lr_series(&log);
        assert_eq!(
            lr.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>(),
            ["critic", "lr", "seg"],
            "sorted by name; the flat `lr` only where a record has no `lrs`"
        );
        let val = val_series(&log);
        assert_eq!(best_point(&val, "miou"), Some((2.0, 0.2)));
        assert_eq!(last_point(&val, "macc"), Some((2.0, 0.3)));
        assert_eq!(last(&val, "miou_night"), Some(0.1));
        let classes = last_class_iou(&log).unwrap();
        assert_eq!(classes[0], ("car".to_string(), Some(0.5), Some(0.25)));
        assert_eq!(classes[1], ("person".to_string(), None, None));
        assert_eq!(last_class_iou(&log[..1]), None, "no nested scores");
    }

    /// A validation without day frames (PST900, MSRS, …: no day/night split) shows the IoU of
    /// all its frames, not an empty chart.
    #[test]
    fn without_day_frames_the_bars_are_of_all_frames() {
        let mut log = log();
        let val = log[1].val.as_mut().unwrap();
        val.per_class_iou_day.clear();
        val.per_class_iou_night.clear();
        let classes = last_class_iou(&log).unwrap();
        assert_eq!(
            classes,
            [
                ("car".to_string(), Some(0.4), None),
                ("person".to_string(), None, None)
            ]
        );
    }
}
