//! The launcher's view of a running pipeline: the latest statistics report
//! of every stage, and the estimation error of every belief against the
//! plant's truth.
//!
//! The monitor polls (no listener, so publishers pay nothing for it) with
//! large buffers. Beliefs are matched to the truth of the sensor sample they
//! were updated with (same channel and sequence number); samples measured
//! in the warm-up are left out. The no-filter reference inverts each raw
//! measurement ([`crate::scenario::System::raw_position`]).
//!
//! ```text
//! rmse_position     = √( mean over beliefs ‖m_pos − x_pos‖² )
//! rmse_state        = √( mean over beliefs ‖m − x‖² )
//! rmse_position_raw = √( mean over samples ‖g⁻¹(y)_pos − x_pos‖² )
//! ```

use crate::ipc::{Belief, Bus, Control, IpcError, StageKind, StageStats, Subscriber, Truth};
use crate::rt::LatencyHist;
use crate::scenario::System;
use crate::MAX_STATE;
use std::sync::Arc;
use std::time::Instant;

/// Truths kept for matching (≥ 4 s at 1 kHz).
const TRUTH_RING: usize = 4096;
/// Beliefs waiting for their truth.
const MAX_PENDING: usize = 1024;
/// Channels whose truths are kept (one ring each: sequence numbers count
/// per channel, so two channels' samples must not share a slot).
const MAX_TRUTH_CHANNELS: usize = 8;

/// Accumulated estimation error.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Accuracy {
    /// The scenario's own figures ([`System::run_metrics`]; `None`: it
    /// has none).
    pub scenario: Option<serde_json::Value>,
    pub rmse_position: Option<f64>,
    pub rmse_state: Option<f64>,
    pub rmse_position_raw: Option<f64>,
    /// Beliefs matched with truth after the warm-up.
    pub beliefs: u64,
    /// Truth samples after the warm-up.
    pub samples: u64,
}

/// Matches beliefs with truth and accumulates squared errors.
#[derive(Debug)]
pub struct AccuracyTracker {
    system: Arc<dyn System>,
    warmup_ns: u64,
    first_ns: Option<u64>,
    latest_ns: u64,
    /// (channel, its truths by sequence number).
    rings: Vec<(u32, Vec<Option<Truth>>)>,
    pending: Vec<Belief>,
    se_pos: f64,
    se_state: f64,
    n: u64,
    se_raw: f64,
    n_raw: u64,
    metrics: ScenarioMetrics,
}

/// The scenario's own accumulator (Debug by name only).
struct ScenarioMetrics(Option<Box<dyn crate::scenario::RunMetrics>>);

impl std::fmt::Debug for ScenarioMetrics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() { "Some(..)" } else { "None" })
    }
}

fn truth_view(t: &Truth, counted: bool) -> crate::scenario::TruthView<'_> {
    let (d, m, c) = (t.dim as usize, t.obs_dim as usize, t.control_dim as usize);
    crate::scenario::TruthView {
        seq: t.header.seq,
        channel: t.channel,
        t_ns: t.header.t_valid_ns,
        counted,
        x: &t.x[..d.min(MAX_STATE)],
        u: &t.u[..c.min(crate::MAX_CONTROL)],
        y: &t.y[..m.min(crate::MAX_OBS)],
    }
}

impl AccuracyTracker {
    pub fn new(system: Arc<dyn System>, warmup_ns: u64) -> Self {
        Self {
            warmup_ns,
            first_ns: None,
            latest_ns: 0,
            rings: Vec::with_capacity(MAX_TRUTH_CHANNELS),
            pending: Vec::with_capacity(MAX_PENDING),
            se_pos: 0.0,
            se_state: 0.0,
            n: 0,
            se_raw: 0.0,
            n_raw: 0,
            metrics: ScenarioMetrics(system.run_metrics()),
            system,
        }
    }

    fn counted(&mut self, t_ns: u64) -> bool {
        let first = *self.first_ns.get_or_insert(t_ns);
        t_ns >= first.saturating_add(self.warmup_ns)
    }

    /// Add a truth sample (and its raw measurement's error).
    pub fn add_truth(&mut self, t: &Truth) {
        let counted = self.counted(t.header.t_valid_ns);
        if let Some(m) = self.metrics.0.as_mut() {
            m.truth(&truth_view(t, counted));
        }
        if counted {
            let axes = self.system.position_axes();
            let mut raw = [0.0; MAX_STATE];
            if self.system.raw_position(&t.y, &mut raw) {
                for (i, &a) in axes.iter().enumerate() {
                    self.se_raw += (raw[i] - t.x[a]).powi(2);
                }
                self.n_raw += 1;
            }
        }
        self.latest_ns = self.latest_ns.max(t.header.t_valid_ns);
        let i = match self.rings.iter().position(|r| r.0 == t.channel) {
            Some(i) => i,
            None if self.rings.len() < MAX_TRUTH_CHANNELS => {
                self.rings.push((t.channel, vec![None; TRUTH_RING]));
                self.rings.len() - 1
            }
            None => return,
        };
        self.rings[i].1[(t.header.seq as usize) % TRUTH_RING] = Some(*t);
    }

    /// Add a belief; it is scored once its truth is known.
    pub fn add_belief(&mut self, b: &Belief) {
        if !self.score(b) && self.pending.len() < MAX_PENDING {
            self.pending.push(*b);
        }
    }

    /// Retry beliefs whose truth had not arrived (given up after 1 s of
    /// truth without it).
    pub fn retry_pending(&mut self) {
        let pending = std::mem::take(&mut self.pending);
        for b in &pending {
            if !self.score(b) && b.header.t_valid_ns + 1_000_000_000 > self.latest_ns {
                self.pending.push(*b);
            }
        }
    }

    fn score(&mut self, b: &Belief) -> bool {
        let seq = b.trace.sensor_seq;
        let channel = b.trace.sensor_channel;
        let Some(t) = self
            .rings
            .iter()
            .find(|r| r.0 == channel)
            .and_then(|r| r.1[(seq as usize) % TRUTH_RING])
        else {
            return false;
        };
        if t.header.seq != seq || t.channel != b.trace.sensor_channel {
            return false;
        }
        if !self.counted(t.header.t_valid_ns) {
            return true;
        }
        let d = (b.dim as usize).min(t.dim as usize).min(MAX_STATE);
        for &a in self.system.position_axes() {
            self.se_pos += (b.mean[a] - t.x[a]).powi(2);
        }
        for i in 0..d {
            self.se_state += (b.mean[i] - t.x[i]).powi(2);
        }
        self.n += 1;
        if let Some(m) = self.metrics.0.as_mut() {
            let bd = (b.dim as usize).min(MAX_STATE);
            let view = crate::scenario::BeliefView {
                sensor_seq: seq,
                sensor_channel: channel,
                ess: b.ess,
                filter_ns: b
                    .trace
                    .t_filter_out_ns
                    .saturating_sub(b.trace.t_filter_in_ns),
                mean: &b.mean[..bd],
                cov: &b.cov[..bd * bd],
            };
            m.belief(&view, &truth_view(&t, true));
        }
        true
    }

    /// Add a published control (for the scenario's figures).
    pub fn add_control(&mut self, c: &Control) {
        if let Some(m) = self.metrics.0.as_mut() {
            let n = (c.dim as usize).min(crate::MAX_CONTROL);
            m.control(&crate::scenario::ControlView {
                sensor_seq: c.trace.sensor_seq,
                sensor_channel: c.trace.sensor_channel,
                u: &c.u[..n],
                ok: c.status == crate::ipc::control_status::OK,
            });
        }
    }

    /// The figures so far.
    pub fn summary(&self) -> Accuracy {
        let rms = |se: f64, n: u64| (n > 0).then(|| (se / n as f64).sqrt());
        Accuracy {
            rmse_position: rms(self.se_pos, self.n),
            rmse_state: rms(self.se_state, self.n),
            rmse_position_raw: rms(self.se_raw, self.n_raw),
            beliefs: self.n,
            samples: self.n_raw,
            scenario: self.metrics.0.as_ref().map(|m| m.report()),
        }
    }
}

/// An end-to-end output of the pipeline seen by the monitor: a control
/// (or, in estimation-only runs, a belief).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Output {
    /// Publish time of the sensor sample it derives from.
    pub t_sensor_pub_ns: u64,
    /// Its own publish time.
    pub t_pub_ns: u64,
}

/// The launcher's subscriptions.
pub struct Monitor {
    stats: Subscriber<StageStats>,
    belief: Subscriber<Belief>,
    truth: Subscriber<Truth>,
    control: Subscriber<Control>,
    latest: [Option<StageStats>; 5],
    /// (pid, when) of each stage's latest report: the heartbeat.
    seen: [Option<(u32, Instant)>; 5],
    accuracy: AccuracyTracker,
    last_belief: Option<Belief>,
    last_control: Option<Control>,
    last_truth: Option<Truth>,
    /// Controls are the outputs (false: beliefs, estimation only).
    controls_are_output: bool,
    /// Outputs received by the last poll.
    outputs: Vec<Output>,
    /// Sensor → output latency since the last [`Monitor::take_window`].
    window: LatencyHist,
}

fn slot(kind: StageKind) -> usize {
    kind as usize - 1
}

impl Monitor {
    /// Subscribe on `bus`.
    pub fn open(bus: &Bus, system: Arc<dyn System>, warmup_ns: u64) -> Result<Self, IpcError> {
        Ok(Self {
            stats: bus.subscriber_with(64, false)?,
            belief: bus.subscriber_with(256, false)?,
            truth: bus.subscriber_with(512, false)?,
            control: bus.subscriber_with(256, false)?,
            latest: [None; 5],
            seen: [None; 5],
            accuracy: AccuracyTracker::new(system, warmup_ns),
            last_belief: None,
            last_control: None,
            last_truth: None,
            controls_are_output: true,
            outputs: Vec::with_capacity(512),
            window: LatencyHist::new(),
        })
    }

    /// Take beliefs instead of controls as the pipeline's output
    /// (estimation-only runs).
    pub fn beliefs_are_output(mut self) -> Self {
        self.controls_are_output = false;
        self
    }

    fn output(&mut self, t_sensor_pub_ns: u64, t_pub_ns: u64) {
        if t_sensor_pub_ns != 0 && t_pub_ns >= t_sensor_pub_ns {
            self.window.record(t_pub_ns - t_sensor_pub_ns);
        }
        if self.outputs.len() < self.outputs.capacity() {
            self.outputs.push(Output {
                t_sensor_pub_ns,
                t_pub_ns,
            });
        }
    }

    /// Drain everything that arrived.
    pub fn poll(&mut self) -> Result<(), IpcError> {
        self.outputs.clear();
        let now = Instant::now();
        while let Some(s) = self.stats.receive()? {
            if let Some(k) = StageKind::from_id(s.stage) {
                self.latest[slot(k)] = Some(s);
                self.seen[slot(k)] = Some((s.pid, now));
            }
        }
        while let Some(t) = self.truth.receive()? {
            self.accuracy.add_truth(&t);
            self.last_truth = Some(t);
        }
        self.accuracy.retry_pending();
        while let Some(b) = self.belief.receive()? {
            self.accuracy.add_belief(&b);
            if !self.controls_are_output {
                self.output(b.trace.t_sensor_pub_ns, b.header.t_pub_ns);
            }
            self.last_belief = Some(b);
        }
        while let Some(c) = self.control.receive()? {
            self.accuracy.add_control(&c);
            if self.controls_are_output {
                self.output(c.trace.t_sensor_pub_ns, c.header.t_pub_ns);
            }
            self.last_control = Some(c);
        }
        Ok(())
    }

    /// When the stage last reported from process `pid` (None: not since
    /// that process started).
    pub fn last_seen(&self, kind: StageKind, pid: u32) -> Option<Instant> {
        self.seen[slot(kind)]
            .filter(|(p, _)| *p == pid)
            .map(|(_, t)| t)
    }

    /// Forget a stage's latest report (its process was replaced).
    pub fn forget(&mut self, kind: StageKind) {
        self.latest[slot(kind)] = None;
        self.seen[slot(kind)] = None;
    }

    /// The outputs (controls, or beliefs) received by the last poll.
    pub fn outputs(&self) -> &[Output] {
        &self.outputs
    }

    /// Sensor → output latency percentiles since the previous call (and
    /// reset).
    pub fn take_window(&mut self) -> crate::ipc::Percentiles {
        let p = crate::ipc::Percentiles::from(&self.window);
        self.window.reset();
        p
    }

    /// The last belief, control and truth seen.
    pub fn last_belief(&self) -> Option<&Belief> {
        self.last_belief.as_ref()
    }
    pub fn last_control(&self) -> Option<&Control> {
        self.last_control.as_ref()
    }
    pub fn last_truth(&self) -> Option<&Truth> {
        self.last_truth.as_ref()
    }

    /// The latest report of a stage.
    pub fn stats(&self, kind: StageKind) -> Option<&StageStats> {
        self.latest[slot(kind)].as_ref()
    }

    /// Accuracy so far.
    pub fn accuracy(&self) -> Accuracy {
        self.accuracy.summary()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::{BuildContext, Registry};

    fn ship() -> Arc<dyn System> {
        Registry::builtin()
            .get("ship")
            .unwrap()
            .build(None, &BuildContext { sample_dt: 0.01 })
            .unwrap()
    }

    fn truth(seq: u64, t: u64, x: [f64; 4]) -> Truth {
        let mut tr = Truth {
            dim: 4,
            obs_dim: 2,
            ..Truth::default()
        };
        tr.header.seq = seq;
        tr.header.t_valid_ns = t;
        tr.x[..4].copy_from_slice(&x);
        // A measurement 1 unit off in range: raw position error 1.
        let r = x[0].hypot(x[1]) + 1.0;
        tr.y[0] = r;
        tr.y[1] = x[1].atan2(x[0]);
        tr
    }

    fn belief(seq: u64, mean: [f64; 4]) -> Belief {
        let mut b = Belief {
            dim: 4,
            ..Belief::default()
        };
        b.trace.sensor_seq = seq;
        b.mean[..4].copy_from_slice(&mean);
        b
    }

    #[test]
    fn matches_beliefs_to_truth_by_sequence_and_skips_the_warmup() {
        let mut a = AccuracyTracker::new(ship(), 5);
        // Sample 0 at t = 0 is in the warm-up; samples 1, 2 count.
        a.add_truth(&truth(0, 0, [3.0, 4.0, 0.0, 0.0]));
        a.add_belief(&belief(0, [100.0, 0.0, 0.0, 0.0]));
        // Belief before its truth: kept pending, scored on retry.
        a.add_belief(&belief(1, [3.0, 4.0, 1.0, 0.0]));
        a.add_truth(&truth(1, 10, [3.0, 4.0, 0.0, 0.0]));
        a.retry_pending();
        a.add_truth(&truth(2, 20, [0.0, 5.0, 0.0, 0.0]));
        a.add_belief(&belief(2, [0.0, 2.0, 0.0, 0.0]));
        let s = a.summary();
        assert_eq!(s.beliefs, 2);
        assert_eq!(s.samples, 2);
        // Position errors 0 and 3: √((0 + 9)/2).
        assert!((s.rmse_position.unwrap() - (4.5f64).sqrt()).abs() < 1e-12);
        // State errors: 1 (velocity) and 3: √((1 + 9)/2).
        assert!((s.rmse_state.unwrap() - 5f64.sqrt()).abs() < 1e-12);
        assert!((s.rmse_position_raw.unwrap() - 1.0).abs() < 1e-9);
    }

    /// Two channels number their samples independently: a belief is
    /// scored against the truth of its own channel, not the other
    /// channel's sample with the same number.
    #[test]
    fn channels_with_equal_sequence_numbers_keep_their_own_truth() {
        let mut a = AccuracyTracker::new(ship(), 0);
        let mut t0 = truth(7, 10, [3.0, 4.0, 0.0, 0.0]);
        t0.channel = 0;
        let mut t1 = truth(7, 20, [0.0, 5.0, 0.0, 0.0]);
        t1.channel = 1;
        a.add_truth(&t0);
        a.add_truth(&t1);
        let mut b0 = belief(7, [3.0, 4.0, 0.0, 0.0]);
        b0.trace.sensor_channel = 0;
        let mut b1 = belief(7, [0.0, 2.0, 0.0, 0.0]);
        b1.trace.sensor_channel = 1;
        a.add_belief(&b0);
        a.add_belief(&b1);
        let s = a.summary();
        assert_eq!(s.beliefs, 2);
        // Errors 0 (channel 0) and 3 (channel 1).
        assert!((s.rmse_position.unwrap() - (4.5f64).sqrt()).abs() < 1e-12);
        // A belief of a channel without truth waits.
        let mut b2 = belief(7, [0.0; 4]);
        b2.trace.sensor_channel = 2;
        a.add_belief(&b2);
        assert_eq!(a.summary().beliefs, 2);
    }

    #[test]
    fn nothing_scored_is_none() {
        let a = AccuracyTracker::new(ship(), 0);
        assert_eq!(a.summary(), Accuracy::default());
    }
}
