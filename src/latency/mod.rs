//! Latency and jitter testing toolkit: measure every hop against
//! the machine's own floor, in the same run.
//!
//! **Latency** (`beliefbus latency`, [`run::run`]): two processes ping-pong
//! through beliefbus's own ports for each message type (observation,
//! belief, control) and for chain slices of 64 B … 16 MiB (written and read
//! in place), and — interleaved slot by slot in the same run, with the same
//! settings — through minimal iceoryx2 code (the baseline, [`wire`]).
//! One-way latency is half the round trip, timed by the pinging process on
//! CLOCK_MONOTONIC; each path reports count, p50, p90, p99, p99.9 and max
//! for ours and bare and the ratio ours / bare at each quantile
//! ([`stats`]). Interleaving (ours and bare alternate in slots of ~100 ms,
//! the order flipping every round) means a change in the machine's load
//! hits both alike, so the ratio stays meaningful on a busy machine even
//! when the absolute values move.
//!
//! **Jitter** (`beliefbus jitter`, [`jitter`]): a cyclictest-style timer
//! baseline on every core — absolute `clock_nanosleep(TIMER_ABSTIME)`
//! wake-ups at a fixed rate under SCHED_FIFO when permitted; wake-up
//! latency `t_wake − t_deadline` and period jitter `|Δt_wake − T|` — under
//! optional CPU and memory-bandwidth stress ([`stress`]).
//!
//! Every run lives under its own iceoryx2 prefix, removed at the end (also
//! after Ctrl-C or a crashed peer; a run killed outright is swept by the
//! next one). Results go to JSON ([`report`]), SVG plots ([`plot`]) and
//! HdrHistogram interval logs ([`hdr`]).

pub mod cli;
pub mod drive;
pub mod hdr;
pub mod jitter;
pub mod load;
pub mod paths;
pub mod pipeline;
pub mod plot;
pub mod pong;
pub mod report;
pub mod run;
pub mod stats;
pub mod stress;
pub mod wire;

pub use paths::{Mode, PathKind};
pub use report::{LatencyReport, PathReport};
pub use run::{run, LatencyConfig, LatencyRun};
pub use stats::PctBlock;

use crate::ipc::IpcError;

/// Why a latency or jitter measurement failed.
#[derive(Debug, thiserror::Error)]
pub enum LatencyError {
    /// A command-line value that cannot be used.
    #[error("{0}")]
    BadArg(String),
    /// beliefbus's ports failed.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// The bare iceoryx2 baseline failed.
    #[error("bare iceoryx2: {0}")]
    Bare(String),
    /// The peer broke the ping-pong protocol or stopped answering.
    #[error("ping-pong protocol: {0}")]
    Protocol(String),
    /// The peer process died.
    #[error("the pong process died")]
    PeerDied,
    /// Starting or reaping the pong process failed.
    #[error("pong process: {0}")]
    Spawn(String),
    /// Writing an output file failed.
    #[error("writing {path}: {reason}")]
    Output { path: String, reason: String },
}
