//! One confusion matrix accumulated over a whole split (rows = truth, columns = prediction),
//! and the scores of the papers computed from it (spec §2).

use serde::{Deserialize, Serialize};
use tch::{Kind, Tensor};

/// Pixel counts `counts[truth * n + prediction]`; `update` adds a batch, `compute` reports,
/// `reset` clears. Truth pixels equal to `ignore_id` (or ≥ n) are dropped.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConfusionMatrix {
    num_classes: usize,
    ignore_id: Option<u8>,
    counts: Vec<u64>,
}

/// Acc (recall) and IoU of one class; `None` where the denominator is zero.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassScore {
    pub name: String,
    pub acc: Option<f64>,
    pub iou: Option<f64>,
}

/// Scores of one confusion matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    /// RTFNet convention (eq. 1–2): per class, unlabeled included.
    pub per_class: Vec<ClassScore>,
    /// Mean Acc over all classes, a class without pixels counted as 0 (RTFNet convention).
    pub macc: f64,
    /// Mean IoU over all classes, NaN counted as 0 (RTFNet convention).
    pub miou: f64,
    /// MFNet paper's mIoU: class 0 (unlabeled) removed from the sums and from the mean. Only
    /// for class sets whose class 0 is unlabelled ([`rtf_core::classes::first_is_unlabelled`]);
    /// `None` (JSON null) for others, whose one mIoU is [`Self::miou`].
    #[serde(default)]
    pub miou_mfnet: Option<f64>,
    /// Correct pixels / all counted pixels.
    pub pixel_acc: f64,
    pub pixels: u64,
}

impl ConfusionMatrix {
    pub fn new(num_classes: usize, ignore_id: Option<u8>) -> Self {
        Self {
            num_classes,
            ignore_id,
            counts: vec![0; num_classes * num_classes],
        }
    }

    pub fn num_classes(&self) -> usize {
        self.num_classes
    }

    /// Count of pixels of class `truth` predicted as `prediction`.
    pub fn get(&self, truth: usize, prediction: usize) -> u64 {
        self.counts[truth * self.num_classes + prediction]
    }

    /// The counts as rows (truth) of columns (prediction), as `rtf eval --json` writes them.
    pub fn rows(&self) -> Vec<Vec<u64>> {
        let n = self.num_classes;
        (0..n)
            .map(|t| (0..n).map(|p| self.get(t, p)).collect())
            .collect()
    }

    /// Adds a batch: `truth` and `prediction` hold class ids of the same shape (any integer
    /// kind, any device).
    pub fn update(&mut self, truth: &Tensor, prediction: &Tensor) {
        assert_eq!(
            truth.size(),
            prediction.size(),
            "truth and prediction shapes differ"
        );
        let n = self.num_classes as i64;
        let truth = truth.to_kind(Kind::Int64).flatten(0, -1);
        let prediction = prediction.to_kind(Kind::Int64).flatten(0, -1);
        let mut valid = truth.ge(0).logical_and(&truth.lt(n));
        if let Some(ignore) = self.ignore_id {
            valid = valid.logical_and(&truth.ne(ignore as i64));
        }
        let index = (truth.masked_select(&valid) * n
            + prediction.masked_select(&valid).clamp(0, n - 1))
        .to_device(tch::Device::Cpu);
        let bins = index.bincount::<Tensor>(None, n * n);
        let bins = Vec::<i64>::try_from(&bins).expect("bincount is int64");
        for (c, b) in self.counts.iter_mut().zip(bins) {
            *c += b as u64;
        }
    }

    /// Adds a label map given as bytes (row-major, same length).
    pub fn update_ids(&mut self, truth: &[u8], prediction: &[u8]) {
        assert_eq!(
            truth.len(),
            prediction.len(),
            "truth and prediction lengths differ"
        );
        for (&t, &p) in truth.iter().zip(prediction) {
            if Some(t) == self.ignore_id || t as usize >= self.num_classes {
                continue;
            }
            let p = (p as usize).min(self.num_classes - 1);
            self.counts[t as usize * self.num_classes + p] += 1;
        }
    }

    /// Adds another matrix of the same class count (e.g. day + night).
    pub fn merge(&mut self, other: &ConfusionMatrix) {
        assert_eq!(self.num_classes, other.num_classes, "class counts differ");
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
    }

    pub fn reset(&mut self) {
        self.counts.iter_mut().for_each(|c| *c = 0);
    }

    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Scores in both papers' conventions; `names` labels the classes.
    pub fn compute(&self, names: &[&str]) -> Scores {
        let n = self.num_classes;
        let ratio = |num: u64, den: u64| (den > 0).then(|| num as f64 / den as f64);
        let row_sum = |i: usize, from: usize| (from..n).map(|j| self.get(i, j)).sum::<u64>();
        let col_sum = |i: usize, from: usize| (from..n).map(|j| self.get(j, i)).sum::<u64>();
        let per_class: Vec<ClassScore> = (0..n)
            .map(|c| {
                let tp = self.get(c, c);
                let (truth, predicted) = (row_sum(c, 0), col_sum(c, 0));
                ClassScore {
                    name: names
                        .get(c)
                        .map_or_else(|| format!("class{c}"), |s| s.to_string()),
                    acc: ratio(tp, truth),
                    iou: ratio(tp, truth + predicted - tp),
                }
            })
            .collect();
        let mean_or_zero = |values: Vec<Option<f64>>| {
            let count = values.len().max(1) as f64;
            values.into_iter().map(|v| v.unwrap_or(0.0)).sum::<f64>() / count
        };
        // MFNet eq. 2: sums over classes 2..n (1-based), i.e. row and column 0 dropped.
        let miou_mfnet = rtf_core::classes::first_is_unlabelled(names).then(|| {
            mean_or_zero(
                (1..n)
                    .map(|c| {
                        let tp = self.get(c, c);
                        ratio(tp, row_sum(c, 1) + col_sum(c, 1) - tp)
                    })
                    .collect(),
            )
        });
        let correct: u64 = (0..n).map(|c| self.get(c, c)).sum();
        let pixels = self.total();
        Scores {
            macc: mean_or_zero(per_class.iter().map(|s| s.acc).collect()),
            miou: mean_or_zero(per_class.iter().map(|s| s.iou).collect()),
            miou_mfnet,
            pixel_acc: ratio(correct, pixels).unwrap_or(0.0),
            pixels,
            per_class,
        }
    }
}

impl Scores {
    /// Plain-text table: one row per class with Acc and IoU in percent, then the means.
    pub fn table(&self) -> String {
        let pct = |v: Option<f64>| {
            v.map_or_else(|| "    -".to_string(), |v| format!("{:5.1}", 100.0 * v))
        };
        let mut out = format!("{:<12} {:>6} {:>6}\n", "class", "Acc", "IoU");
        for s in &self.per_class {
            out += &format!("{:<12} {:>6} {:>6}\n", s.name, pct(s.acc), pct(s.iou));
        }
        out += &format!(
            "mAcc {:.1}  mIoU {:.1}  (RTFNet convention, all classes)   pixel acc {:.1}\n",
            100.0 * self.macc,
            100.0 * self.miou,
            100.0 * self.pixel_acc
        );
        out
    }

    /// HeatNet's mIoU (spec §2): the IoUs of the first `classes` classes (Freiburg: 12, so
    /// background is left out while its pixels still count as false positives of the class
    /// they are taken for), averaged over the classes whose IoU is defined. None if none is.
    pub fn miou_heatnet(&self, classes: usize) -> Option<f64> {
        let defined: Vec<f64> = self
            .per_class
            .iter()
            .take(classes)
            .filter_map(|c| c.iou)
            .collect();
        (!defined.is_empty()).then(|| defined.iter().sum::<f64>() / defined.len() as f64)
    }
}

/// Freiburg Thermal classes HeatNet's mIoU averages over (0–11; 12 is background).
pub const HEATNET_MIOU_CLASSES: usize = 12;

#[cfg(test)]
mod tests {
    use super::*;

    fn matrix_from(rows: &[&[u64]]) -> ConfusionMatrix {
        let n = rows.len();
        let mut m = ConfusionMatrix::new(n, None);
        for (t, row) in rows.iter().enumerate() {
            for (p, &count) in row.iter().enumerate() {
                m.counts[t * n + p] = count;
            }
        }
        m
    }

    #[test]
    fn heatnet_miou_skips_undefined_classes_and_background() {
        // 0: IoU 8/11; 1: 3/7 (one background pixel predicted as 1); 2: absent -> skipped;
        // 3 (background) is beyond `classes` and not averaged.
        let m = matrix_from(&[&[8, 2, 0, 0], &[1, 3, 0, 0], &[0, 0, 0, 0], &[0, 1, 0, 5]]);
        let s = m.compute(&["a", "b", "c", "background"]);
        let expected = (8.0 / 11.0 + 3.0 / 7.0) / 2.0;
        assert!((s.miou_heatnet(3).unwrap() - expected).abs() < 1e-12);
        let empty = matrix_from(&[&[0, 0], &[0, 0]]).compute(&["a", "b"]);
        assert_eq!(empty.miou_heatnet(1), None);
    }

    #[test]
    fn scores_by_hand() {
        // truth 0: 8 right, 2 as class 1; truth 1: 3 right, 1 as class 0; class 2: absent.
        let m = matrix_from(&[&[8, 2, 0], &[1, 3, 0], &[0, 0, 0]]);
        let s = m.compute(&["unlabeled", "car", "person"]);
        assert_eq!(s.per_class[0].acc, Some(0.8));
        assert_eq!(s.per_class[1].acc, Some(0.75));
        assert_eq!(s.per_class[2].acc, None);
        assert_eq!(s.per_class[0].iou, Some(8.0 / 11.0));
        assert_eq!(s.per_class[1].iou, Some(3.0 / 6.0));
        assert!((s.macc - (0.8 + 0.75) / 3.0).abs() < 1e-12);
        assert!((s.miou - (8.0 / 11.0 + 0.5) / 3.0).abs() < 1e-12);
        // MFNet: class 1 with row/col 0 removed: 3 / (3 + 3 - 3) = 1; class 2 none -> 0.
        assert!((s.miou_mfnet.unwrap() - 0.5).abs() < 1e-12);
        // A set whose class 0 is a class (road): no MFNet-convention score, only the mIoU.
        let road = m.compute(&["road", "car", "person"]);
        assert_eq!(road.miou_mfnet, None);
        assert_eq!(road.miou, s.miou);
        let json = serde_json::to_value(&road).unwrap();
        assert!(json["miou_mfnet"].is_null(), "{json}");
        assert_eq!(s.pixels, 14);
        assert!((s.pixel_acc - 11.0 / 14.0).abs() < 1e-12);
    }

    #[test]
    fn tensor_and_byte_updates_agree_and_ignore_is_dropped() {
        let truth: Vec<u8> = vec![0, 1, 2, 13, 1, 1, 0, 2];
        let pred: Vec<u8> = vec![0, 1, 1, 0, 2, 1, 0, 2];
        let mut a = ConfusionMatrix::new(3, Some(13));
        let mut b = ConfusionMatrix::new(3, Some(13));
        a.update(
            &Tensor::from_slice(&truth).view([2, 4]),
            &Tensor::from_slice(&pred).view([2, 4]),
        );
        b.update_ids(&truth, &pred);
        assert_eq!(a, b);
        assert_eq!(a.total(), 7);
        assert_eq!(a.get(1, 2), 1);
        a.reset();
        assert_eq!(a.total(), 0);
    }

    #[test]
    fn merge_adds_counts() {
        let mut a = matrix_from(&[&[1, 0], &[0, 1]]);
        a.merge(&matrix_from(&[&[0, 2], &[0, 0]]));
        assert_eq!(a.get(0, 1), 2);
        assert_eq!(a.total(), 4);
    }

    #[test]
    fn perfect_prediction_scores_one() {
        let m = matrix_from(&[&[5, 0], &[0, 5]]);
        let s = m.compute(&["void", "b"]);
        assert_eq!((s.macc, s.miou, s.miou_mfnet), (1.0, 1.0, Some(1.0)));
        assert!(s.table().contains("100.0"));
    }
}
