//! The experiment JSON of DESIGN.md (the report type is the workspace's
//! one, `beliefbus_core::report`) and the progress of long runs.

pub use beliefbus_core::report::{ExperimentReport, Row};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::time::{Duration, Instant};

/// How often a run whose stderr is not a terminal logs its progress.
const LOG_EVERY: Duration = Duration::from_secs(60);

/// Progress of a run in units of work: a bar with an ETA when stderr is a
/// terminal, otherwise one plain line a minute at most (logs stay short).
/// Steps of unequal cost are counted with [`Progress::inc`] by their cost,
/// so that the ETA (remaining work at the average rate so far) holds.
pub struct Progress {
    total: u64,
    done: u64,
    label: String,
    out: Out,
}

enum Out {
    Off,
    Bar(ProgressBar),
    Log { start: Instant, last: Instant },
}

impl Progress {
    /// Progress over `total` units (no output when `enabled` is false,
    /// e.g. `--quiet` or in tests).
    pub fn new(label: &str, total: usize, enabled: bool) -> Self {
        let total = total.max(1) as u64;
        let out = if !enabled {
            Out::Off
        } else if std::io::stderr().is_terminal() {
            let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
            let style = ProgressStyle::with_template(
                "{prefix:<18} [{bar:30}] {pos}/{len} {elapsed} eta {eta}",
            )
            .map(|s| s.progress_chars("#>."));
            if let Ok(s) = style {
                bar.set_style(s);
            }
            bar.set_prefix(label.to_string());
            Out::Bar(bar)
        } else {
            let now = Instant::now();
            Out::Log {
                start: now,
                last: now,
            }
        };
        Self {
            total,
            done: 0,
            label: label.to_string(),
            out,
        }
    }

    /// One unit done.
    pub fn tick(&mut self) {
        self.inc(1);
    }

    /// `units` done.
    pub fn inc(&mut self, units: usize) {
        self.done = (self.done + units as u64).min(self.total);
        let finished = self.done >= self.total;
        match &mut self.out {
            Out::Off => {}
            Out::Bar(bar) => {
                bar.set_position(self.done);
                if finished {
                    bar.finish();
                }
            }
            Out::Log { start, last } => {
                if finished || last.elapsed() >= LOG_EVERY {
                    *last = Instant::now();
                    let el = start.elapsed().as_secs_f64();
                    eprintln!(
                        "{}: {}/{} after {:.0} s, eta {:.0} s",
                        self.label,
                        self.done,
                        self.total,
                        el,
                        eta_s(el, self.done, self.total)
                    );
                }
            }
        }
    }
}

/// Remaining time at the average rate so far.
fn eta_s(elapsed_s: f64, done: u64, total: u64) -> f64 {
    if done == 0 {
        return f64::NAN;
    }
    elapsed_s / done as f64 * total.saturating_sub(done) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eta_is_the_remaining_work_at_the_average_rate() {
        assert_eq!(eta_s(10.0, 1, 4), 30.0);
        assert_eq!(eta_s(10.0, 4, 4), 0.0);
        assert!(eta_s(1.0, 0, 4).is_nan());
    }

    #[test]
    fn counting_saturates_at_the_total() {
        let mut p = Progress::new("t", 3, false);
        p.inc(2);
        p.inc(5);
        assert_eq!(p.done, 3);
    }
}
