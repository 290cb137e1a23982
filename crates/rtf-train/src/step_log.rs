//! `RUN/steps.jsonl`: one line per optimisation step, `{"epoch", "step", "loss", ...terms}`,
//! the losses each step reported before its update. The epoch records of `log.jsonl` average
//! these; a step-by-step comparison with a reference trainer (issue 27's trajectory parity)
//! needs them one by one. A resume keeps the lines of the steps its checkpoint holds and drops
//! any written after it, so the file always describes one uninterrupted run.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

pub const STEP_LOG_FILE: &str = "steps.jsonl";

/// One line of the step log: a step's total loss and its named terms or metrics.
#[derive(Debug, Clone, Default, PartialEq, serde::Deserialize)]
pub struct StepRecord {
    /// 0-based epoch.
    pub epoch: usize,
    /// 0-based step over the whole run.
    pub step: u64,
    pub loss: f64,
    /// The terms the procedure reported (e.g. `ce_day`), by name.
    #[serde(flatten)]
    pub terms: BTreeMap<String, f64>,
}

/// Reads `run_dir/steps.jsonl`, one record per step. A line that is not a step record is an
/// error naming the file and the line.
pub fn read(run_dir: &Path) -> std::io::Result<Vec<StepRecord>> {
    let path = run_dir.join(STEP_LOG_FILE);
    let text = std::fs::read_to_string(&path)
        .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", path.display())))?;
    text.lines()
        .enumerate()
        .map(|(i, line)| {
            serde_json::from_str(line).map_err(|e| {
                let at = format!("{}: line {}: {e}", path.display(), i + 1);
                std::io::Error::new(std::io::ErrorKind::InvalidData, at)
            })
        })
        .collect()
}

/// The open step log of rank 0 (other ranks write none).
pub struct StepLog {
    file: Option<std::fs::File>,
    /// The step recorded last (on every rank, written or not).
    pub last: StepRecord,
}

impl StepLog {
    /// Opens `run_dir/steps.jsonl` keeping its first `steps_done` lines (0 on a fresh run).
    /// Errors are the file's (the caller names it: [`STEP_LOG_FILE`]).
    pub fn open(run_dir: &Path, is_root: bool, steps_done: u64) -> std::io::Result<Self> {
        if !is_root {
            return Ok(Self {
                file: None,
                last: StepRecord::default(),
            });
        }
        let path = run_dir.join(STEP_LOG_FILE);
        let kept: String = match std::fs::read_to_string(&path) {
            Ok(text) => text
                .lines()
                .take(steps_done as usize)
                .map(|l| format!("{l}\n"))
                .collect(),
            Err(_) => String::new(),
        };
        rtf_core::write_bytes_atomic(&path, kept.as_bytes()).map_err(std::io::Error::other)?;
        let file = std::fs::OpenOptions::new().append(true).open(&path)?;
        Ok(Self {
            file: Some(file),
            last: StepRecord::default(),
        })
    }

    /// Appends step `step` (0-based over the run) of `epoch` (0-based): its total loss and
    /// each named term or metric.
    pub fn record<'a>(
        &mut self,
        epoch: usize,
        step: u64,
        total: f64,
        terms: impl IntoIterator<Item = (&'a String, &'a f64)>,
    ) -> std::io::Result<()> {
        self.last = StepRecord {
            epoch,
            step,
            loss: total,
            terms: terms.into_iter().map(|(k, v)| (k.clone(), *v)).collect(),
        };
        let Some(file) = &mut self.file else {
            return Ok(());
        };
        let mut line = serde_json::json!({"epoch": epoch, "step": step, "loss": total});
        for (name, value) in &self.last.terms {
            line[name] = serde_json::json!(value);
        }
        writeln!(file, "{line}")
    }
}

/// The terms of a step with none but the total (tests).
#[cfg(test)]
fn no_terms() -> std::collections::BTreeMap<String, f64> {
    Default::default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_resume_keeps_the_checkpointed_steps_and_drops_later_ones() {
        let dir = tempfile::tempdir().unwrap();
        let mut log = StepLog::open(dir.path(), true, 0).unwrap();
        for step in 0..3 {
            log.record(0, step, step as f64 + 0.5, &no_terms()).unwrap();
        }
        drop(log);
        let mut log = StepLog::open(dir.path(), true, 2).unwrap();
        log.record(1, 2, 9.0, &no_terms()).unwrap();
        let records = read(dir.path()).unwrap();
        let losses: Vec<f64> = records.iter().map(|r| r.loss).collect();
        assert_eq!(losses, [0.5, 1.5, 9.0]);
        assert_eq!(records[2].epoch, 1, "{records:?}");
        let fresh = StepLog::open(dir.path(), true, 0).unwrap();
        drop(fresh);
        assert!(read(dir.path()).unwrap().is_empty());
    }

    #[test]
    fn terms_read_back_by_name_and_a_bad_line_names_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let mut log = StepLog::open(dir.path(), true, 0).unwrap();
        let terms = BTreeMap::from([("ce_day".to_string(), 0.25)]);
        log.record(0, 0, 0.75, &terms).unwrap();
        drop(log);
        assert_eq!(read(dir.path()).unwrap()[0].terms, terms);
        let path = dir.path().join(STEP_LOG_FILE);
        let mut text = std::fs::read_to_string(&path).unwrap();
        text += "{\"epoch\": 0}\n";
        std::fs::write(&path, text).unwrap();
        let error = read(dir.path()).unwrap_err().to_string();
        assert!(
            error.contains("steps.jsonl: line 2: missing field"),
            "{error}"
        );
    }
}
