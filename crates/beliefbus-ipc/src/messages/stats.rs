//! The statistics a stage reports to the launcher ([`StageStats`], its
//! percentiles and hop slots) and the stage identities ([`StageKind`]).
//! Fixed-size `#[repr(C)]` like every message (layout pinned in the tests).

use super::{Header, Hop};
use crate::rt::LatencyHist;
use iceoryx2::prelude::ZeroCopySend;

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
/// Miss slots in one [`StageStats`]: the stage's whole miss log.
pub const STATS_MISSES: usize = 32;
const _: () = assert!(STATS_MISSES == crate::rt::miss_log::MISS_LOG_CAPACITY);

/// One deadline miss inside [`StageStats`] (`crate::rt::miss_log::Miss`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
pub struct MissStats {
    /// When the message's work started, CLOCK_MONOTONIC ns.
    pub start_ns: u64,
    /// Its wall-clock time, ns.
    pub wall_ns: u64,
    /// The thread's CPU time over it, ns ([`MISS_UNKNOWN`]: not measured).
    pub cpu_ns: u64,
    /// The thread's context switches over it ([`MISS_UNKNOWN`]: not
    /// measured).
    pub switches: u64,
    /// `crate::rt::budget::MissKind` id (0: slot unused).
    pub kind: u32,
    pub reserved: u32,
    /// The thread's minor and major page faults over it ([`MISS_UNKNOWN`]
    /// both: not measured).
    pub minor_faults: u64,
    pub major_faults: u64,
}

/// [`MissStats`]' value of a figure that was not measured.
pub const MISS_UNKNOWN: u64 = u64::MAX;

impl From<&crate::rt::miss_log::Miss> for MissStats {
    fn from(m: &crate::rt::miss_log::Miss) -> Self {
        MissStats {
            start_ns: m.start_ns,
            wall_ns: m.wall_ns,
            cpu_ns: m.cpu_ns.unwrap_or(MISS_UNKNOWN),
            switches: m.switches.unwrap_or(MISS_UNKNOWN),
            kind: m.kind as u32,
            reserved: 0,
            minor_faults: m.faults.map_or(MISS_UNKNOWN, |f| f.minor),
            major_faults: m.faults.map_or(MISS_UNKNOWN, |f| f.major),
        }
    }
}

impl MissStats {
    /// The miss this slot holds (none: unused or an unknown kind).
    pub fn miss(&self) -> Option<crate::rt::miss_log::Miss> {
        let known = |v: u64| (v != MISS_UNKNOWN).then_some(v);
        Some(crate::rt::miss_log::Miss {
            start_ns: self.start_ns,
            wall_ns: self.wall_ns,
            cpu_ns: known(self.cpu_ns),
            switches: known(self.switches),
            faults: known(self.minor_faults)
                .zip(known(self.major_faults))
                .map(|(minor, major)| crate::rt::miss_log::Faults { minor, major }),
            kind: crate::rt::budget::MissKind::from_id(self.kind)?,
        })
    }
}

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
    /// Filter: the backend counts collapsed steps (`ess_collapses` is
    /// meaningful; a Gaussian filter has no weights to collapse).
    pub const COLLAPSES_COUNTED: u32 = 8;
}

/// Periodic (and final) statistics of a stage (stage → launcher).
#[derive(Clone, Copy, Debug, PartialEq, ZeroCopySend)]
#[type_name("beliefbus.StageStats.v6")]
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
    /// Of `deadline_misses`, those whose own thread CPU time stayed within
    /// the budget: the stage was preempted (by another thread, the kernel
    /// or the host), it did not overrun (see `beliefbus_rt::budget`).
    pub deadline_misses_preempted: u64,
    /// Of `deadline_misses_preempted`, those during which the stage's
    /// thread was never switched out: interrupts or the hypervisor took
    /// the time (`beliefbus_rt::budget::MissKind::Host`).
    pub deadline_misses_host: u64,
    /// Control: of the stale drops, those published while the stage was
    /// waiting for work: its own backlog did not delay them, the core was
    /// not given to it in time (interrupts, the host, a higher-priority
    /// thread) or the wake-up came late.
    pub dropped_stale_idle: u64,
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
    /// Filter (PF or chain backend, flag `COLLAPSES_COUNTED`): updates that
    /// kept less than the collapse fraction of their effective support or
    /// whose weights all vanished.
    pub ess_collapses: u64,
    /// Refine: moving-frame versions built, their rows, the rows meeting
    /// their matched moment equations exactly and the rows fitted by least
    /// squares (`chain::diagnostics::row_report`), and versions published
    /// again as new lineages (steady placement).
    pub chain_built: u64,
    pub chain_rows: u64,
    pub chain_rows_exact: u64,
    pub chain_rows_least_squares: u64,
    pub chain_recentred: u64,
    /// The stage's most recent deadline misses, oldest first, in slots
    /// `0..` (an unused slot has kind 0; `beliefbus_rt::miss_log`).
    pub miss_log: [MissStats; STATS_MISSES],
    /// Misses no longer in `miss_log` (pushed out by newer ones):
    /// `deadline_misses` = listed + this.
    pub miss_log_overwritten: u64,
    /// Of `deadline_misses`, those that started in the warm-up: the first
    /// `miss_warmup_ns` after the stage's first message
    /// (`beliefbus_rt::budget::Budget::warmup_misses`); the rest are the
    /// steady state's.
    pub deadline_misses_warmup: u64,
    pub miss_warmup_ns: u64,
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
            deadline_misses_preempted: 0,
            deadline_misses_host: 0,
            dropped_stale_idle: 0,
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
            ess_collapses: 0,
            chain_built: 0,
            chain_rows: 0,
            chain_rows_exact: 0,
            chain_rows_least_squares: 0,
            chain_recentred: 0,
            miss_log: [MissStats::default(); STATS_MISSES],
            miss_log_overwritten: 0,
            deadline_misses_warmup: 0,
            miss_warmup_ns: 0,
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

    /// The misses of `miss_log`, oldest first.
    pub fn misses(&self) -> impl Iterator<Item = crate::rt::miss_log::Miss> + '_ {
        self.miss_log.iter().map_while(MissStats::miss)
    }
}
