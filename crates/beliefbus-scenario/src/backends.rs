//! What a scenario's own backends are built from.
//!
//! A system offers backends by name ([`crate::System::filter_backends`],
//! [`crate::System::controller_backends`]); `filter.backend` /
//! `control.backend` select one exactly like a built-in one, validation
//! builds it once before anything starts (so a bad setting is a config
//! error naming the scenario), and the stage builds it again at start.
//! Their settings belong in the scenario's own parameter section (e.g.
//! `[arx.filter]`): the system was built from it and hands them on.

use beliefbus_core::belief::Gaussian;

/// What the filter stage knows when it builds a scenario's filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FilterContext {
    /// Seed of the filter's random stream (already mixed from `run.seed`).
    pub seed: u64,
    /// Sensor sample period (s).
    pub sample_dt: f64,
    /// The belief to start from: the prior, or after a restart the last
    /// published belief (`resumed`).
    pub start: Gaussian,
    pub resumed: bool,
    /// Time of `start` (s).
    pub t0: f64,
}

/// What the control stage knows when it builds a scenario's controller.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlContext {
    /// Seed of the controller's random stream (mixed from `run.seed`).
    pub seed: u64,
    /// Sensor sample period (s).
    pub sample_dt: f64,
}
