//! `log.jsonl`: one JSON line per finished epoch ([`EpochRecord`]), appended by the trainer.
//! Blank lines are skipped; any other line that is not an epoch record is an error naming the
//! file and the line.

use std::path::Path;

use crate::error::RunError;
use crate::record::{EpochOnly, EpochRecord};

/// The records of the log at `path`.
pub fn read(path: &Path) -> Result<Vec<EpochRecord>, RunError> {
    let text = std::fs::read_to_string(path).map_err(|source| RunError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse(&text, path)
}

/// The records of a log's `text` (`path` names it in errors).
pub fn parse(text: &str, path: &Path) -> Result<Vec<EpochRecord>, RunError> {
    parse_where(text, path, |_| true)
}

/// The records of a log's `text` from epoch `first` on: the lines of earlier epochs (which
/// may be an older build's schema) and lines without an epoch are skipped unread.
pub fn parse_from(text: &str, path: &Path, first: usize) -> Result<Vec<EpochRecord>, RunError> {
    parse_where(text, path, |line| {
        line_epoch(line).is_some_and(|e| e >= first)
    })
}

/// The records of the non-blank lines of `text` that `keep` keeps, each read whole: a kept
/// line that is not an epoch record is an error naming the file and the line.
fn parse_where(
    text: &str,
    path: &Path,
    keep: impl Fn(&str) -> bool,
) -> Result<Vec<EpochRecord>, RunError> {
    let mut records = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() || !keep(line) {
            continue;
        }
        let record = serde_json::from_str(line).map_err(|e| RunError::Log {
            path: path.to_path_buf(),
            line: i + 1,
            message: format!("not an epoch record of rtf's log: {e}"),
        })?;
        records.push(record);
    }
    Ok(records)
}

/// The epoch a log line records (None: not JSON, or no epoch).
pub fn line_epoch(line: &str) -> Option<usize> {
    serde_json::from_str::<EpochOnly>(line)
        .ok()
        .map(|r| r.epoch)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(epoch: usize) -> String {
        format!(
            r#"{{"epoch":{epoch},"lr":0.01,"train_loss":1.0,"images":2,"seconds":1.0,"images_per_s":2.0,"data_wait_fraction":0.0,"val_miou":null,"val_macc":null}}"#
        )
    }

    #[test]
    fn records_read_in_order_and_a_bad_line_is_named() {
        let path = Path::new("run/log.jsonl");
        let text = format!("{}\n\n{}\n", line(0), line(1));
        let epochs: Vec<usize> = parse(&text, path)
            .unwrap()
            .iter()
            .map(|r| r.epoch)
            .collect();
        assert_eq!(epochs, [0, 1]);
        let err = parse(&format!("{}\nnot json\n", line(0)), path).unwrap_err();
        assert!(err.to_string().starts_with("run/log.jsonl:2: "), "{err}");
        let renamed = line(0).replace("\"epoch\"", "\"epoch_index\"");
        let err = parse(&renamed, path).unwrap_err().to_string();
        assert!(
            err.contains("log.jsonl:1") && err.contains("`epoch`"),
            "{err}"
        );
    }

    #[test]
    fn records_from_an_epoch_skip_the_earlier_lines_unread() {
        let path = Path::new("run/log.jsonl");
        let text = format!(
            "{{\"epoch\":0,\"old\":true}}\n{}\nnot json\n{}\n",
            line(1),
            line(2)
        );
        let epochs: Vec<usize> = parse_from(&text, path, 1)
            .unwrap()
            .iter()
            .map(|r| r.epoch)
            .collect();
        assert_eq!(epochs, [1, 2]);
        let bad = format!("{}\n{{\"epoch\":3}}\n", line(2));
        let err = parse_from(&bad, path, 2).unwrap_err().to_string();
        assert!(err.starts_with("run/log.jsonl:2: "), "{err}");
    }

    #[test]
    fn the_epoch_of_a_line() {
        assert_eq!(line_epoch(&line(7)), Some(7));
        assert_eq!(line_epoch(r#"{"epoch": 2}"#), Some(2));
        assert_eq!(line_epoch("{not json"), None);
        assert_eq!(line_epoch(r#"{"train_loss": 1.0}"#), None);
    }
}
