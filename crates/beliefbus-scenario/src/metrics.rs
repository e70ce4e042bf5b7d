//! A scenario's own report figures ([`RunMetrics`]): the launcher feeds it
//! every truth sample, every belief matched with the truth of the sample
//! it was updated with, and every control, in arrival order, then writes
//! [`RunMetrics::report`] as `scenario_metrics.<scenario>` in the run
//! report. Views are plain slices, so the scenario layer needs no IPC.

/// The plant's truth at one sensor sample.
#[derive(Clone, Copy, Debug)]
pub struct TruthView<'a> {
    /// The sample's sequence number on its channel (a discrete-time
    /// system's step − 1).
    pub seq: u64,
    /// The sensor channel id the sample was published on.
    pub channel: u32,
    /// Measurement time (ns, monotonic clock).
    pub t_ns: u64,
    /// Measured after `run.warmup_s` (figures count only these).
    pub counted: bool,
    /// True state, control in force, published measurement.
    pub x: &'a [f64],
    pub u: &'a [f64],
    pub y: &'a [f64],
}

/// A belief (mean, column-major covariance) and the sample it used.
#[derive(Clone, Copy, Debug)]
pub struct BeliefView<'a> {
    pub sensor_seq: u64,
    /// The channel of that sample.
    pub sensor_channel: u32,
    /// The filter's effective sample size after the update (0 for a
    /// Gaussian filter).
    pub ess: f64,
    /// The filter stage's time on this observation (ns, from receiving it
    /// to publishing the belief; 0 when unknown).
    pub filter_ns: u64,
    pub mean: &'a [f64],
    pub cov: &'a [f64],
}

/// A control the controller published.
#[derive(Clone, Copy, Debug)]
pub struct ControlView<'a> {
    /// The sensor sample whose belief it was computed from.
    pub sensor_seq: u64,
    /// That sample's channel.
    pub sensor_channel: u32,
    pub u: &'a [f64],
    /// Computed (false: the stage's fallback to the last good control).
    pub ok: bool,
}

/// Accumulates a scenario's figures over a run.
pub trait RunMetrics: Send {
    /// A truth sample, in sequence order (a gap means samples were lost).
    fn truth(&mut self, t: &TruthView);
    /// A belief with the truth of its sample (after the warm-up only).
    fn belief(&mut self, b: &BeliefView, t: &TruthView);
    /// A published control.
    fn control(&mut self, _c: &ControlView) {}
    /// The section written in the report (a JSON object).
    fn report(&self) -> serde_json::Value;
}
