//! The messages of a pipeline instance: fixed-size `#[repr(C)]` payloads with
//! versioned `#[type_name]`s, so that a C, C++ or Python iceoryx2 participant
//! with a structure of the same name, size and alignment can open the same
//! service.
//!
//! Every message starts with a header — sequence number, time of validity and
//! publish time, all CLOCK_MONOTONIC nanoseconds — and everything downstream
//! of ingest carries the [`Trace`] of the sensor sample it derives from, so a
//! sink computes every hop from one message on one clock (DESIGN.md,
//! "Messages and timing").
//!
//! | channel   | payload        | type name                       |
//! |-----------|----------------|---------------------------------|
//! | `sensor`  | [`SensorSample`] | `beliefbus.SensorSample.v1`   |
//! | `obs`     | [`Observation`]  | `beliefbus.Observation.v1`    |
//! | `belief`  | [`Belief`]       | `beliefbus.Belief.v1`         |
//! | `control` | [`Control`]      | `beliefbus.Control.v1`        |
//! | `truth`   | [`Truth`]        | `beliefbus.Truth.v1`          |
//! | `stats`   | [`StageStats`]   | `beliefbus.StageStats.v3`     |

use crate::belief::Gaussian;
use crate::rt::LatencyHist;
use crate::{MAX_CONTROL, MAX_OBS, MAX_STATE};
use iceoryx2::prelude::ZeroCopySend;

/// Values a sensor sample can carry (ABI v1; independent of [`MAX_OBS`] so the
/// wire layout never changes when the library's limits do).
pub const SENSOR_MAX_DIM: usize = 8;
const _: () = assert!(MAX_OBS <= SENSOR_MAX_DIM);

/// Header fields shared by every message.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
pub struct Header {
    /// Per-publisher sequence number, starting at 0, +1 per message.
    pub seq: u64,
    /// When the content is valid (measurement time for a sample or an
    /// observation, belief time for a belief), CLOCK_MONOTONIC ns.
    pub t_valid_ns: u64,
    /// When the message was published, CLOCK_MONOTONIC ns.
    pub t_pub_ns: u64,
}

/// Latency trace carried downstream from the sensor sample. A stamp of 0
/// means "not passed through that point".
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
pub struct Trace {
    /// Sequence number of the originating sensor sample (per channel).
    pub sensor_seq: u64,
    /// Channel of the originating sensor sample.
    pub sensor_channel: u32,
    pub reserved: u32,
    /// Measurement time of the sample.
    pub t_meas_ns: u64,
    /// Publish time of the sample (its measurement time when the publisher
    /// left it 0).
    pub t_sensor_pub_ns: u64,
    pub t_ingest_in_ns: u64,
    pub t_ingest_out_ns: u64,
    pub t_filter_in_ns: u64,
    pub t_filter_out_ns: u64,
    pub t_control_in_ns: u64,
    pub t_control_out_ns: u64,
}

/// The latency hops a trace yields (the report's `hops` keys).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, strum::IntoStaticStr)]
#[repr(u32)]
pub enum Hop {
    /// Sample publish → ingest receives it.
    #[strum(serialize = "sensor->ingest")]
    SensorToIngest = 1,
    /// Ingest publishes the observation → filter receives it.
    #[strum(serialize = "ingest->filter")]
    IngestToFilter = 2,
    /// Filter publishes the belief → control receives it.
    #[strum(serialize = "filter->control")]
    FilterToControl = 3,
    /// Sample publish → belief published.
    #[strum(serialize = "sensor->belief")]
    SensorToBelief = 4,
    /// Sample publish → control published.
    #[strum(serialize = "sensor->control")]
    SensorToControl = 5,
}

impl Hop {
    /// Every hop, in report order.
    pub const ALL: [Hop; 5] = [
        Hop::SensorToIngest,
        Hop::IngestToFilter,
        Hop::FilterToControl,
        Hop::SensorToBelief,
        Hop::SensorToControl,
    ];

    /// The report key (`"sensor->control"`, ...).
    pub fn key(self) -> &'static str {
        self.into()
    }

    /// Decode a wire id.
    pub fn from_id(id: u32) -> Option<Hop> {
        Hop::ALL.into_iter().find(|h| *h as u32 == id)
    }
}

/// `b − a` when both stamps are set and ordered.
fn span(a: u64, b: u64) -> Option<u64> {
    (a != 0 && b != 0 && b >= a).then(|| b - a)
}

impl Trace {
    /// Duration of `hop` in ns, if both of its stamps are present.
    pub fn hop_ns(&self, hop: Hop) -> Option<u64> {
        match hop {
            Hop::SensorToIngest => span(self.t_sensor_pub_ns, self.t_ingest_in_ns),
            Hop::IngestToFilter => span(self.t_ingest_out_ns, self.t_filter_in_ns),
            Hop::FilterToControl => span(self.t_filter_out_ns, self.t_control_in_ns),
            Hop::SensorToBelief => span(self.t_sensor_pub_ns, self.t_filter_out_ns),
            Hop::SensorToControl => span(self.t_sensor_pub_ns, self.t_control_out_ns),
        }
    }
}

/// `flags` bit of [`SensorSample`]: `noise_std` holds valid per-sample σ.
pub const SENSOR_FLAG_NOISE_STD: u32 = 1;

/// A sensor sample, **ABI v1** (documented field by field in
/// `docs/sensor-abi.md`; layout pinned by a compile-time test below).
///
/// ```text
/// offset size type        field
///    0    8  u64          seq           per-channel sequence number
///    8    8  u64          t_meas_ns     measurement time, CLOCK_MONOTONIC ns
///   16    8  u64          t_pub_ns      publish time, CLOCK_MONOTONIC ns (0: unknown)
///   24    4  u32          channel       sensor channel id
///   28    4  u32          dim           number of valid entries of values (1..=8)
///   32    4  u32          flags         bit 0: noise_std valid
///   36    4  u32          reserved0     0
///   40   64  f64[8]       values        measurement, first `dim` entries
///  104   64  f64[8]       noise_std     per-sample σ of each value (if flag bit 0)
///  168   64  u64[8]       reserved      0
///  size 232, alignment 8
/// ```
/// The first 24 bytes have the layout of [`Header`].
#[derive(Clone, Copy, Debug, PartialEq, ZeroCopySend)]
#[type_name("beliefbus.SensorSample.v1")]
#[repr(C)]
pub struct SensorSample {
    pub seq: u64,
    pub t_meas_ns: u64,
    pub t_pub_ns: u64,
    pub channel: u32,
    pub dim: u32,
    pub flags: u32,
    pub reserved0: u32,
    pub values: [f64; SENSOR_MAX_DIM],
    pub noise_std: [f64; SENSOR_MAX_DIM],
    pub reserved: [u64; 8],
}

impl Default for SensorSample {
    fn default() -> Self {
        Self {
            seq: 0,
            t_meas_ns: 0,
            t_pub_ns: 0,
            channel: 0,
            dim: 0,
            flags: 0,
            reserved0: 0,
            values: [0.0; SENSOR_MAX_DIM],
            noise_std: [0.0; SENSOR_MAX_DIM],
            reserved: [0; 8],
        }
    }
}

impl SensorSample {
    /// A sample of `values` on `channel` measured at `t_meas_ns`.
    ///
    /// `dim` is always `values.len()`: values beyond [`SENSOR_MAX_DIM`] do
    /// not fit and are not copied, but `dim` still says how many there were,
    /// so ingest rejects the sample as a wrong dimension instead of filtering
    /// a silently truncated one. Use [`crate::sensor_api::SensorPublisher`]
    /// for a typed error before sending.
    pub fn new(channel: u32, seq: u64, t_meas_ns: u64, values: &[f64]) -> Self {
        let n = values.len().min(SENSOR_MAX_DIM);
        let mut s = Self {
            seq,
            t_meas_ns,
            channel,
            dim: u32::try_from(values.len()).unwrap_or(u32::MAX),
            ..Self::default()
        };
        s.values[..n].copy_from_slice(&values[..n]);
        s
    }

    /// Attach per-sample σ, one per value (entries beyond [`SENSOR_MAX_DIM`]
    /// are not copied; a σ left at 0 makes ingest reject the sample).
    pub fn with_noise_std(mut self, std: &[f64]) -> Self {
        let n = std.len().min(SENSOR_MAX_DIM);
        self.noise_std[..n].copy_from_slice(&std[..n]);
        self.flags |= SENSOR_FLAG_NOISE_STD;
        self
    }

    /// Whether the per-sample σ is valid.
    pub fn has_noise_std(&self) -> bool {
        self.flags & SENSOR_FLAG_NOISE_STD != 0
    }

    /// The header view of the first 24 bytes.
    pub fn header(&self) -> Header {
        Header {
            seq: self.seq,
            t_valid_ns: self.t_meas_ns,
            t_pub_ns: self.t_pub_ns,
        }
    }
}

/// A validated observation on the time-ordered `obs` stream (ingest → filter).
#[derive(Clone, Copy, Debug, PartialEq, ZeroCopySend)]
#[type_name("beliefbus.Observation.v1")]
#[repr(C)]
pub struct Observation {
    /// seq: ingest's output count; t_valid: measurement time.
    pub header: Header,
    pub trace: Trace,
    /// Sensor channel it came from.
    pub channel: u32,
    /// Components of the model's observation vector it carries (ObsMask bits).
    pub mask: u32,
    /// The model's observation dimension m (`y` has m valid entries, of
    /// which those in `mask` are meaningful).
    pub dim: u32,
    /// 1 when `std` holds per-sample σ for the masked components.
    pub has_std: u32,
    pub y: [f64; MAX_OBS],
    pub std: [f64; MAX_OBS],
}

impl Default for Observation {
    fn default() -> Self {
        Self {
            header: Header::default(),
            trace: Trace::default(),
            channel: 0,
            mask: 0,
            dim: 0,
            has_std: 0,
            y: [0.0; MAX_OBS],
            std: [0.0; MAX_OBS],
        }
    }
}

/// `status` bits of a [`Belief`].
pub mod belief_status {
    /// The update for this observation was refused (belief is the prediction).
    pub const UPDATE_REFUSED: u32 = 1;
    /// The update resampled the particles.
    pub const RESAMPLED: u32 = 2;
    /// Chain backend: the chain was stale and this belief is its Gaussian
    /// fallback's (`stage::chain_guard`).
    pub const CHAIN_FALLBACK: u32 = 4;
}

/// A Gaussian summary of the filter's belief (filter → control, refine).
#[derive(Clone, Copy, Debug, PartialEq, ZeroCopySend)]
#[type_name("beliefbus.Belief.v1")]
#[repr(C)]
pub struct Belief {
    /// seq: filter step; t_valid: the belief's time (the measurement time).
    pub header: Header,
    pub trace: Trace,
    /// State dimension d.
    pub dim: u32,
    /// [`belief_status`] bits.
    pub status: u32,
    /// Effective sample size of the update (1 for Gaussian filters).
    pub ess: f64,
    /// Approximate log p(y_k | y_{1:k−1}).
    pub log_evidence: f64,
    pub mean: [f64; MAX_STATE],
    /// Covariance, column-major d × d in the first d² entries (stride d, as
    /// in [`Gaussian`]).
    pub cov: [f64; MAX_STATE * MAX_STATE],
}

impl Default for Belief {
    fn default() -> Self {
        Self {
            header: Header::default(),
            trace: Trace::default(),
            dim: 0,
            status: 0,
            ess: 0.0,
            log_evidence: 0.0,
            mean: [0.0; MAX_STATE],
            cov: [0.0; MAX_STATE * MAX_STATE],
        }
    }
}

impl Belief {
    /// Copy a Gaussian into the message.
    pub fn set_gaussian(&mut self, g: &Gaussian) {
        self.dim = g.dim as u32;
        self.mean = g.mean;
        self.cov = g.cov;
    }

    /// The Gaussian it carries (`dim` clamped to [`MAX_STATE`]).
    pub fn gaussian(&self) -> Gaussian {
        let dim = (self.dim as usize).min(MAX_STATE);
        let mut g = Gaussian::zeros(dim);
        g.mean = self.mean;
        g.cov = self.cov;
        g
    }
}

/// `status` values of a [`Control`].
pub mod control_status {
    /// Computed by the controller.
    pub const OK: u32 = 0;
    /// The controller failed; `u` is the safe fallback (the last good control
    /// or zero).
    pub const FALLBACK: u32 = 1;
}

/// A control to apply (control → plant / actuators).
#[derive(Clone, Copy, Debug, PartialEq, ZeroCopySend)]
#[type_name("beliefbus.Control.v1")]
#[repr(C)]
pub struct Control {
    /// seq: control step; t_valid: the belief time it was computed for.
    pub header: Header,
    pub trace: Trace,
    /// Control dimension.
    pub dim: u32,
    /// [`control_status`] value.
    pub status: u32,
    pub u: [f64; MAX_CONTROL],
    /// The optimiser's cost estimate.
    pub cost: f64,
    /// The active waypoint (x, y).
    pub goal: [f64; 2],
    /// Index of the active waypoint in the route.
    pub waypoint_index: u32,
    pub reserved: u32,
    /// Waypoints reached so far (by the believed position).
    pub waypoints_reached: u64,
}

impl Default for Control {
    fn default() -> Self {
        Self {
            header: Header::default(),
            trace: Trace::default(),
            dim: 0,
            status: 0,
            u: [0.0; MAX_CONTROL],
            cost: 0.0,
            goal: [0.0; 2],
            waypoint_index: 0,
            reserved: 0,
            waypoints_reached: 0,
        }
    }
}

/// What the simulated plant really did, for evaluation only (no stage but
/// the launcher's monitor reads it).
#[derive(Clone, Copy, Debug, PartialEq, ZeroCopySend)]
#[type_name("beliefbus.Truth.v1")]
#[repr(C)]
pub struct Truth {
    /// seq: the sensor sample's seq; t_valid: its measurement time.
    pub header: Header,
    /// Sensor channel of the sample published with it.
    pub channel: u32,
    /// State dimension.
    pub dim: u32,
    /// Observation dimension of `y`.
    pub obs_dim: u32,
    /// Control dimension of `u`.
    pub control_dim: u32,
    /// The true state at the measurement time.
    pub x: [f64; MAX_STATE],
    /// The control applied when the sample was taken.
    pub u: [f64; MAX_CONTROL],
    /// The measurement published with this seq.
    pub y: [f64; MAX_OBS],
}

impl Default for Truth {
    fn default() -> Self {
        Self {
            header: Header::default(),
            channel: 0,
            dim: 0,
            obs_dim: 0,
            control_dim: 0,
            x: [0.0; MAX_STATE],
            u: [0.0; MAX_CONTROL],
            y: [0.0; MAX_OBS],
        }
    }
}

/// Percentiles of a latency or compute-time histogram, in ns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
pub struct Percentiles {
    pub count: u64,
    pub p50_ns: u64,
    pub p90_ns: u64,
    pub p99_ns: u64,
    pub p999_ns: u64,
    pub max_ns: u64,
}

impl From<&LatencyHist> for Percentiles {
    /// Count, p50, p90, p99, p99.9 and max of `h` (all 0 when empty).
    fn from(h: &LatencyHist) -> Self {
        Percentiles {
            count: h.count(),
            p50_ns: h.quantile(0.5),
            p90_ns: h.quantile(0.9),
            p99_ns: h.quantile(0.99),
            p999_ns: h.quantile(0.999),
            max_ns: h.max(),
        }
    }
}

/// One hop's percentiles inside [`StageStats`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
pub struct HopStats {
    /// [`Hop`] id (0: slot unused).
    pub hop: u32,
    pub reserved: u32,
    pub pct: Percentiles,
}

/// Hop slots in one [`StageStats`].
pub const STATS_HOPS: usize = 4;
/// Rejection-reason slots in one [`StageStats`].
pub const STATS_REASONS: usize = 12;
/// Drop-reason slots in one [`StageStats`] (`crate::stage::DropReason`).
pub const STATS_DROP_REASONS: usize = 4;

/// The stages of a pipeline (`stage` field of [`StageStats`]).
#[derive(
    Clone,
    Copy,
    Debug,
    PartialEq,
    Eq,
    Hash,
    PartialOrd,
    Ord,
    strum::IntoStaticStr,
    strum::EnumString,
    strum::VariantNames,
)]
#[strum(serialize_all = "lowercase")]
#[repr(u32)]
pub enum StageKind {
    Ingest = 1,
    Filter = 2,
    Control = 3,
    Refine = 4,
    Plant = 5,
}

impl StageKind {
    /// Every stage, in report order.
    pub const ALL: [StageKind; 5] = [
        StageKind::Ingest,
        StageKind::Filter,
        StageKind::Control,
        StageKind::Refine,
        StageKind::Plant,
    ];

    /// Lower-case name (`ingest`, ...), the report key and the executable
    /// suffix (`beliefbus-<name>`).
    pub fn name(self) -> &'static str {
        self.into()
    }

    /// Decode a wire id.
    pub fn from_id(id: u32) -> Option<StageKind> {
        StageKind::ALL.into_iter().find(|s| *s as u32 == id)
    }

    /// Parse a name.
    pub fn from_name(name: &str) -> Option<StageKind> {
        name.parse().ok()
    }
}

/// `flags` bits of [`StageStats`].
pub mod stats_flags {
    /// The stage's last report before it exits.
    pub const FINAL: u32 = 1;
    /// Runs under SCHED_FIFO.
    pub const FIFO: u32 = 2;
    /// Its memory is locked (mlockall).
    pub const MLOCKED: u32 = 4;
}

/// Periodic (and final) statistics of a stage (stage → launcher).
#[derive(Clone, Copy, Debug, PartialEq, ZeroCopySend)]
#[type_name("beliefbus.StageStats.v3")]
#[repr(C)]
pub struct StageStats {
    /// seq: report number; t_valid = t_pub: when the report was made.
    pub header: Header,
    /// [`StageKind`] id.
    pub stage: u32,
    pub pid: u32,
    /// Core the stage is pinned to, −1 when not pinned.
    pub core: i32,
    /// [`stats_flags`] bits.
    pub flags: u32,
    /// Messages processed (ingest: samples accepted; filter: observations
    /// filtered; control: controls computed; refine: beliefs seen; plant:
    /// sensor samples published).
    pub processed: u64,
    /// Inputs lost or superseded before processing (queue overflow or a
    /// newer latest value).
    pub dropped: u64,
    /// Inputs refused by validation (sum of `rejected_by_reason`).
    pub rejected: u64,
    /// Rejections per reason (meaning per stage; ingest:
    /// [`crate::stage::ingest::Reason`]).
    pub rejected_by_reason: [u64; STATS_REASONS],
    /// Messages whose compute time exceeded the budget.
    pub deadline_misses: u64,
    pub budget_ns: u64,
    /// Compute time per processed message.
    pub compute: Percentiles,
    /// Hops measured by this stage (the sink of the trace).
    pub hops: [HopStats; STATS_HOPS],
    /// Plant only: controls received.
    pub controls_received: u64,
    /// Plant only: processed samples after the warm-up period.
    pub processed_after_warmup: u64,
    /// Plant only: mean distance of the true position to the active waypoint.
    pub mean_goal_distance: f64,
    /// Plant only: waypoints reached (as last reported by control).
    pub waypoints_reached: u64,
    /// Messages finished later than release + budget (positive lateness;
    /// see [`crate::rt::budget`]).
    pub late: u64,
    /// Response time (input published → processed): p50, p99, max in ns.
    /// Lateness = response − budget.
    pub response_p50_ns: u64,
    pub response_p99_ns: u64,
    pub response_max_ns: u64,
    /// Control only: mean closed-loop running cost per second after the
    /// warm-up, (1/T)∫[q(x̂) + w‖u‖²]dt at the belief mean x̂, over T =
    /// `control_cost_time_s` (0: no data).
    pub control_cost: f64,
    pub control_cost_time_s: f64,
    /// Chain. Filter: versions installed; refine: published.
    pub chain_versions: u64,
    /// Chain states (filter: of the active version; refine: current size).
    pub chain_states: u64,
    /// δ of the active (filter) or last published (refine) chain, s.
    pub chain_delta_s: f64,
    /// Filter: duration of a version swap, p50 and p99, ns.
    pub chain_swap_p50_ns: u64,
    pub chain_swap_p99_ns: u64,
    /// Filter: largest belief mass lost in a remap (before renormalisation).
    pub chain_mass_lost_max: f64,
    /// `dropped` by reason (`crate::stage::DropReason`: lost in transport,
    /// stale, superseded, unread at the stop). Ingest, filter and control classify every drop,
    /// so these sum to `dropped`; refine and plant (skipped periods) leave
    /// them 0.
    pub dropped_by_reason: [u64; STATS_DROP_REASONS],
    /// Filter (chain backend): the stale-chain fallback
    /// (`stage::chain_guard`): steps published from the fallback, stale
    /// episodes by cause (degenerate, age, evidence), chain beliefs
    /// re-initialised from the fallback, largest version age at a step (ns).
    pub chain_fallback_steps: u64,
    pub chain_fallback_episodes: [u64; 3],
    pub chain_fallback_reinits: u64,
    pub chain_stale_max_ns: u64,
    /// Filter: the fallback's predict + update time per observation (its
    /// extra cost), p50 and p99, ns.
    pub chain_fallback_p50_ns: u64,
    pub chain_fallback_p99_ns: u64,
    /// Filter: installs that left the fallback untethered (the chain was
    /// doubtful).
    pub chain_fallback_untethered: u64,
}

impl Default for StageStats {
    fn default() -> Self {
        Self {
            header: Header::default(),
            stage: 0,
            pid: 0,
            core: -1,
            flags: 0,
            processed: 0,
            dropped: 0,
            rejected: 0,
            rejected_by_reason: [0; STATS_REASONS],
            deadline_misses: 0,
            budget_ns: 0,
            compute: Percentiles::default(),
            hops: [HopStats::default(); STATS_HOPS],
            controls_received: 0,
            processed_after_warmup: 0,
            mean_goal_distance: 0.0,
            waypoints_reached: 0,
            late: 0,
            response_p50_ns: 0,
            response_p99_ns: 0,
            response_max_ns: 0,
            control_cost: 0.0,
            control_cost_time_s: 0.0,
            chain_versions: 0,
            chain_states: 0,
            chain_delta_s: 0.0,
            chain_swap_p50_ns: 0,
            chain_swap_p99_ns: 0,
            chain_mass_lost_max: 0.0,
            dropped_by_reason: [0; STATS_DROP_REASONS],
            chain_fallback_steps: 0,
            chain_fallback_episodes: [0; 3],
            chain_fallback_reinits: 0,
            chain_stale_max_ns: 0,
            chain_fallback_p50_ns: 0,
            chain_fallback_p99_ns: 0,
            chain_fallback_untethered: 0,
        }
    }
}

impl StageStats {
    /// The percentiles of `hop`, if this report carries it.
    pub fn hop(&self, hop: Hop) -> Option<&Percentiles> {
        self.hops
            .iter()
            .find(|h| h.hop == hop as u32)
            .map(|h| &h.pct)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{align_of, offset_of, size_of};

    #[test]
    fn percentiles_of_a_histogram() {
        assert_eq!(
            Percentiles::from(&LatencyHist::new()),
            Percentiles::default()
        );
        let mut h = LatencyHist::new();
        for v in 1..=10_000u64 {
            h.record(v * 1_000); // 1 µs … 10 ms
        }
        let p = Percentiles::from(&h);
        assert_eq!(p.count, 10_000);
        // 3 significant digits: relative error ≤ 0.1 %.
        for (got, want) in [
            (p.p50_ns, 5_000_000.0),
            (p.p90_ns, 9_000_000.0),
            (p.p99_ns, 9_900_000.0),
            (p.p999_ns, 9_990_000.0),
            (p.max_ns, 10_000_000.0),
        ] {
            assert!((got as f64 - want).abs() / want < 1e-3, "{got} vs {want}");
        }
    }

    // Sensor ABI v1 is a published contract: these fail at compile time if the
    // layout drifts.
    const _: () = {
        assert!(size_of::<SensorSample>() == 232);
        assert!(align_of::<SensorSample>() == 8);
        assert!(offset_of!(SensorSample, seq) == 0);
        assert!(offset_of!(SensorSample, t_meas_ns) == 8);
        assert!(offset_of!(SensorSample, t_pub_ns) == 16);
        assert!(offset_of!(SensorSample, channel) == 24);
        assert!(offset_of!(SensorSample, dim) == 28);
        assert!(offset_of!(SensorSample, flags) == 32);
        assert!(offset_of!(SensorSample, reserved0) == 36);
        assert!(offset_of!(SensorSample, values) == 40);
        assert!(offset_of!(SensorSample, noise_std) == 104);
        assert!(offset_of!(SensorSample, reserved) == 168);
        assert!(size_of::<Header>() == 24);
    };

    #[test]
    fn sensor_abi_v1_layout_and_name() {
        assert_eq!(size_of::<SensorSample>(), 232);
        assert_eq!(offset_of!(SensorSample, noise_std), 104);
        // SAFETY: type_name is unsafe only because implementers must keep it
        // unique; reading it is harmless.
        let name = unsafe { <SensorSample as ZeroCopySend>::type_name() };
        assert_eq!(name, "beliefbus.SensorSample.v1");
    }

    #[test]
    fn message_type_names_are_versioned() {
        let names = unsafe {
            [
                <Observation as ZeroCopySend>::type_name(),
                <Belief as ZeroCopySend>::type_name(),
                <Control as ZeroCopySend>::type_name(),
                <Truth as ZeroCopySend>::type_name(),
                <StageStats as ZeroCopySend>::type_name(),
            ]
        };
        for n in names {
            let version = n.rsplit_once(".v").map(|(_, v)| v).unwrap_or("");
            assert!(
                n.starts_with("beliefbus.")
                    && !version.is_empty()
                    && version.bytes().all(|b| b.is_ascii_digit()),
                "{n}"
            );
        }
    }

    #[test]
    fn trace_hops_need_both_stamps_in_order() {
        let t = Trace {
            t_sensor_pub_ns: 1_000,
            t_ingest_in_ns: 1_500,
            t_ingest_out_ns: 1_700,
            t_filter_in_ns: 2_000,
            t_filter_out_ns: 3_000,
            ..Trace::default()
        };
        assert_eq!(t.hop_ns(Hop::SensorToIngest), Some(500));
        assert_eq!(t.hop_ns(Hop::IngestToFilter), Some(300));
        assert_eq!(t.hop_ns(Hop::SensorToBelief), Some(2_000));
        assert_eq!(t.hop_ns(Hop::FilterToControl), None);
        assert_eq!(t.hop_ns(Hop::SensorToControl), None);
        let backwards = Trace {
            t_sensor_pub_ns: 5,
            t_ingest_in_ns: 4,
            ..Trace::default()
        };
        assert_eq!(backwards.hop_ns(Hop::SensorToIngest), None);
    }

    #[test]
    fn belief_round_trips_a_gaussian() {
        let g = Gaussian::diagonal(&[1.0, -2.0, 0.5], &[0.1, 0.2, 0.3]);
        let mut b = Belief::default();
        b.set_gaussian(&g);
        assert_eq!(b.gaussian(), g);
    }

    #[test]
    fn ids_round_trip() {
        for h in Hop::ALL {
            assert_eq!(Hop::from_id(h as u32), Some(h));
        }
        for s in StageKind::ALL {
            assert_eq!(StageKind::from_id(s as u32), Some(s));
            assert_eq!(StageKind::from_name(s.name()), Some(s));
        }
        assert_eq!(Hop::from_id(0), None);
    }
}
