//! The experiment JSON of DESIGN.md (the report type is the workspace's
//! one, `beliefbus_core::report`) and the progress bar of long runs.

pub use beliefbus_core::report::{ExperimentReport, Row};
use std::io::Write;
use std::time::Instant;

/// A minimal progress bar on stderr (no-op when disabled or when stderr is
/// not wanted, e.g. in tests).
pub struct Progress {
    total: usize,
    done: usize,
    label: String,
    enabled: bool,
    start: Instant,
}

impl Progress {
    /// A bar for `total` steps.
    pub fn new(label: &str, total: usize, enabled: bool) -> Self {
        Self {
            total: total.max(1),
            done: 0,
            label: label.to_string(),
            enabled,
            start: Instant::now(),
        }
    }
    /// Advance by one step.
    pub fn tick(&mut self) {
        self.done += 1;
        if !self.enabled {
            return;
        }
        let frac = self.done as f64 / self.total as f64;
        let filled = (frac * 30.0).round() as usize;
        let el = self.start.elapsed().as_secs_f64();
        let eta = if self.done > 0 {
            el / self.done as f64 * (self.total - self.done.min(self.total)) as f64
        } else {
            0.0
        };
        let mut e = std::io::stderr().lock();
        let _ = write!(
            e,
            "\r{:<18} [{}{}] {}/{} {:.0}s eta {:.0}s",
            self.label,
            "#".repeat(filled),
            ".".repeat(30 - filled.min(30)),
            self.done,
            self.total,
            el,
            eta
        );
        if self.done >= self.total {
            let _ = writeln!(e);
        }
    }
}
