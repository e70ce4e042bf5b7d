//! Real-time plumbing: the CLOCK_MONOTONIC clock every process shares,
//! allocation-free latency/compute histograms, per-stage budgets and
//! deadline-miss accounting (with a log of the latest misses: `miss_log`),
//! core affinity, scheduling priority and memory locking (each with a
//! one-line warning and a fallback when not permitted), idle-class
//! spinners that keep the pipeline's cores awake (`keep_warm`), the time
//! the machine took from each core (`host`: steal, interrupts), a probe of
//! the stalls the host inflicts on a spinning core (`stall`), whether a set
//! of events sits on a periodic grid (`grid`), and the rules
//! for every file a run writes (`files`).

pub mod budget;
pub mod clock;
pub mod files;
pub mod grid;
pub mod hist;
pub mod host;
pub mod keep_warm;
pub mod miss_log;
pub mod sched;
pub mod stall;

pub use budget::Budget;
pub use clock::{Clock, MonotonicClock, SimClock};
pub use hist::LatencyHist;
pub use keep_warm::KeepWarm;
pub use sched::{apply as apply_rt, RtApplied, RtSettings};
