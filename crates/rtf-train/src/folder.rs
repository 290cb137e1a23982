//! Run folders as rtf-train reads them: rtf-run's reader ([`RunFolder`], [`TrainedRun`] with
//! its configuration checked), the class set a run trained on ([`class_set`]), and what an
//! export records of the weights a run folder holds ([`export_labels`]).

use std::path::Path;

use rtf_core::ClassSet;

pub use rtf_run::{read_config, EpochRecord, RunFolder, TrainedRun, Weights};

/// The class set `run`'s final network was trained on: the one its configuration records (a
/// described dataset's, since it was recorded), else its dataset's as it reads now; None when
/// neither can be read.
pub fn class_set(run: &TrainedRun) -> Option<ClassSet> {
    let dataset = &run.last_training().data.dataset;
    if let Some(recorded) = dataset.recorded() {
        return Some(recorded.classes.clone());
    }
    rtf_data::Dataset::open_recorded(dataset.root(), dataset.choice().kind)
        .ok()
        .map(|d| d.class_set())
}

/// What weights were trained on, for an export's metadata: the weights' `record` (class set
/// and thermal rule), else the class set of the run folder they sit in, else MF's or
/// Freiburg's names when `classes` is their count (said as an assumption).
pub fn export_labels(
    record: Option<rtf_data::TrainedOn>,
    weights: &Path,
    classes: i64,
) -> rtf_models::io::export::Labels {
    let thermal = record
        .as_ref()
        .and_then(|t| t.thermal.as_ref())
        .map(|t| t.describe());
    let (classes, from) = match record {
        Some(t) => (Some(t.classes), "the weights' record".to_string()),
        None => match class_set_of_run(weights, classes) {
            Some((set, from)) => (Some(set), from),
            None => (None, "unknown".to_string()),
        },
    };
    rtf_models::io::export::Labels {
        classes,
        from,
        thermal,
    }
}

/// The class set of weights without a record, and where it comes from: the dataset of the run
/// folder the weights sit in (the classes its config.json records, else its dataset's: a
/// dataset.yaml's own names), else MF's or Freiburg's names when the class count is theirs
/// (said as an assumption), else none.
fn class_set_of_run(weights: &Path, classes: i64) -> Option<(ClassSet, String)> {
    let dir = weights.parent()?;
    // `--weights final.safetensors` inside the run folder: the folder is the current one.
    let folder = match dir.as_os_str().is_empty() {
        true => Path::new("."),
        false => dir,
    };
    let run_classes = TrainedRun::open(folder)
        .ok()
        .and_then(|run| class_set(&run));
    if let Some(set) = run_classes.filter(|set| set.len() as i64 == classes) {
        let config_path = dir.join(rtf_run::CONFIG_FILE);
        return Some((
            set,
            format!("the run's dataset ({})", config_path.display()),
        ));
    }
    [ClassSet::mf(), ClassSet::freiburg()]
        .into_iter()
        .find(|set| set.len() as i64 == classes)
        .map(|set| {
            let from = format!(
                "assumed from the class count: {}'s {classes} classes",
                set.name
            );
            (set, from)
        })
}
