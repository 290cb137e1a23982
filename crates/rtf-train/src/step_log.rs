//! `RUN/steps.jsonl`: one line per optimisation step, `{"epoch", "step", "loss", ...terms}`,
//! the losses each step reported before its update. The epoch records of `log.jsonl` average
//! these; a step-by-step comparison with a reference trainer (issue 27's trajectory parity)
//! needs them one by one. A resume keeps the lines of the steps its checkpoint holds and drops
//! any written after it, so the file always describes one uninterrupted run.

use std::io::Write;
use std::path::Path;

pub const STEP_LOG_FILE: &str = "steps.jsonl";

/// The open step log of rank 0 (other ranks write none).
pub struct StepLog {
    file: Option<std::fs::File>,
}

impl StepLog {
    /// Opens `run_dir/steps.jsonl` keeping its first `steps_done` lines (0 on a fresh run).
    /// Errors are the file's (the caller names it: [`STEP_LOG_FILE`]).
    pub fn open(run_dir: &Path, is_root: bool, steps_done: u64) -> std::io::Result<Self> {
        if !is_root {
            return Ok(Self { file: None });
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
        Ok(Self { file: Some(file) })
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
        let Some(file) = &mut self.file else {
            return Ok(());
        };
        let mut line = serde_json::json!({"epoch": epoch, "step": step, "loss": total});
        for (name, value) in terms {
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
        let text = std::fs::read_to_string(dir.path().join(STEP_LOG_FILE)).unwrap();
        let losses: Vec<f64> = text
            .lines()
            .map(|l| {
                serde_json::from_str::<serde_json::Value>(l).unwrap()["loss"]
                    .as_f64()
                    .unwrap()
            })
            .collect();
        assert_eq!(losses, [0.5, 1.5, 9.0]);
        assert!(
            text.lines().last().unwrap().contains("\"epoch\":1"),
            "{text}"
        );
        let fresh = StepLog::open(dir.path(), true, 0).unwrap();
        drop(fresh);
        assert!(std::fs::read_to_string(dir.path().join(STEP_LOG_FILE))
            .unwrap()
            .is_empty());
    }
}
