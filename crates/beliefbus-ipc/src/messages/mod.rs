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
//! | `stats`   | [`StageStats`]   | `beliefbus.StageStats.v6`     |

use crate::belief::Gaussian;
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

mod stats;
pub use stats::*;

#[cfg(test)]
mod tests;
