//! beliefbus-runtime: the pipeline configuration ([`config`], validated
//! before anything starts), the stage loops as library functions
//! ([`stage`]) and the launcher, supervisor, monitor and report
//! ([`pipeline`]).

pub mod config;
pub mod pipeline;
pub mod stage;

// The lower layers under the names the modules use (`crate::model::…`).
use beliefbus_core::{belief, chain, control, filter, model, rng};
use beliefbus_core::{MAX_CONTROL, MAX_OBS, MAX_STATE};
use beliefbus_ipc as ipc;
use beliefbus_rt as rt;
use beliefbus_scenario as scenario;
