//! beliefbus: real-time estimation and control over zero-copy shared memory.
//!
//! This package is the top layer of the workspace: the command line
//! ([`cli`]), the paper reproductions ([`experiments`]) and the latency and
//! jitter tools ([`latency`]). The layers below are re-exported under the
//! paths they had when they were one crate:
//! - `beliefbus-core`: models ([`model`]), Markov-chain approximations
//!   ([`chain`]), Bayes filters ([`filter`]), controllers ([`control`]),
//!   [`belief`], [`rng`];
//! - `beliefbus-scenario`: the scenario plug-in API and its registry
//!   ([`scenario`]);
//! - `beliefbus-ipc`: all iceoryx2 code ([`ipc`]); `beliefbus-rt`:
//!   real-time plumbing ([`rt`]);
//! - `beliefbus-runtime`: the pipeline configuration ([`config`]), the
//!   stage loops ([`stage`]), launcher/supervisor/report ([`pipeline`]).

pub use beliefbus_core::{belief, chain, control, filter, model, rng};
pub use beliefbus_core::{MAX_CONTROL, MAX_NOISE, MAX_OBS, MAX_STATE};
pub use beliefbus_ipc as ipc;
pub use beliefbus_rt as rt;
pub use beliefbus_runtime::{config, pipeline, stage};
pub use beliefbus_scenario as scenario;

pub mod cli;
pub mod experiments;
pub mod latency;
