//! An epoch's progress: its sums so far (carried over from a mid-epoch checkpoint on resume)
//! and time ([`EpochProgress`]), and the progress bar rank 0 draws.
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

use crate::checkpoint::PartialEpoch;

/// An epoch's sums so far (carried over from a mid-epoch checkpoint on resume) and its time.
pub(super) struct EpochProgress {
    pub(super) first: usize,
    pub(super) loss_sum: f64,
    pub(super) images: usize,
    pub(super) waited: Duration,
    pub(super) term_sums: BTreeMap<String, f64>,
    /// Time of the epoch before a resume, and when this process took it up.
    pub(super) before: Duration,
    pub(super) started: Instant,
}

impl EpochProgress {
    pub(super) fn from_checkpoint(partial: Option<PartialEpoch>, steps_per_epoch: usize) -> Self {
        let done = partial.unwrap_or(PartialEpoch {
            batches: 0,
            loss_sum: 0.0,
            images: 0,
            seconds: 0.0,
            wait_seconds: 0.0,
            term_sums: BTreeMap::new(),
        });
        Self {
            first: done.batches.min(steps_per_epoch),
            loss_sum: done.loss_sum,
            images: done.images,
            waited: Duration::from_secs_f64(done.wait_seconds),
            term_sums: done.term_sums,
            before: Duration::from_secs_f64(done.seconds),
            started: Instant::now(),
        }
    }

    pub(super) fn elapsed(&self) -> Duration {
        self.before + self.started.elapsed()
    }

    /// A mid-epoch checkpoint's progress after `batches` batches.
    pub(super) fn partial(&self, batches: usize) -> PartialEpoch {
        PartialEpoch {
            batches,
            loss_sum: self.loss_sum,
            images: self.images,
            seconds: self.elapsed().as_secs_f64(),
            wait_seconds: self.waited.as_secs_f64(),
            term_sums: self.term_sums.clone(),
        }
    }
}

pub(super) fn progress_bar(steps: usize, epoch: usize, epochs: usize) -> ProgressBar {
    let bar = ProgressBar::new(steps as u64);
    let style =
        ProgressStyle::with_template("epoch {prefix} [{bar:30}] {pos}/{len} {msg} ETA {eta}")
            .expect("valid template")
            .progress_chars("=> ");
    bar.set_style(style);
    bar.set_prefix(format!("{}/{}", epoch + 1, epochs));
    bar
}
