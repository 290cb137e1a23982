//! Validation's record and selection: the default selection metric of a dataset and the
//! epoch's [`ValRecord`] from an evaluation report.
use std::collections::BTreeMap;

use rtf_eval::EvalReport;
use rtf_run::ValRecord;

use crate::config::SelectMetric;

/// The default selection metric of a dataset: HeatNet's day/night mIoU where validation
/// scores HeatNet's convention (Freiburg Thermal), mIoU elsewhere.
pub fn default_select_metric(dataset: &rtf_data::Dataset) -> SelectMetric {
    match dataset.scores_heatnet() {
        true => SelectMetric::HeatnetMiou,
        false => SelectMetric::Miou,
    }
}

fn per_class(scores: &rtf_eval::metrics::Scores) -> BTreeMap<String, Option<f64>> {
    scores
        .per_class
        .iter()
        .map(|c| (c.name.clone(), c.iou))
        .collect()
}

fn mean_of(values: &[Option<f64>]) -> Option<f64> {
    let v: Vec<f64> = values.iter().flatten().copied().collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The epoch's validation record from an evaluation report.
pub fn val_record(report: &EvalReport, freiburg: bool, select: SelectMetric) -> ValRecord {
    let classes = rtf_eval::metrics::HEATNET_MIOU_CLASSES;
    let heatnet = |s: &Option<rtf_eval::metrics::Scores>| {
        s.as_ref()
            .filter(|_| freiburg)
            .and_then(|s| s.miou_heatnet(classes))
    };
    let (miou_day, miou_night) = (
        report.day.as_ref().map(|s| s.miou),
        report.night.as_ref().map(|s| s.miou),
    );
    let (h_day, h_night) = (heatnet(&report.day), heatnet(&report.night));
    let miou_heatnet = mean_of(&[h_day, h_night]);
    let selected = match select {
        SelectMetric::Miou => Some(report.all.miou),
        SelectMetric::DayNightMiou => mean_of(&[miou_day, miou_night]),
        SelectMetric::HeatnetMiou => miou_heatnet,
        SelectMetric::DayMiou => miou_day,
        SelectMetric::NightMiou => miou_night,
    };
    ValRecord {
        miou: report.all.miou,
        macc: report.all.macc,
        miou_day,
        miou_night,
        miou_heatnet_day: h_day,
        miou_heatnet_night: h_night,
        miou_heatnet,
        per_class_iou: per_class(&report.all),
        per_class_iou_day: report.day.as_ref().map(per_class).unwrap_or_default(),
        per_class_iou_night: report.night.as_ref().map(per_class).unwrap_or_default(),
        selected_by: select.name().to_string(),
        // A metric the validation frames cannot give (no night frame) falls back to mIoU.
        selected: selected.unwrap_or(report.all.miou),
    }
}
