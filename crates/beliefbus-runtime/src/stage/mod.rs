//! The loop of each stage as a library function
//! `run(ports, cfg, clock, stop) -> final stats`, testable in one process
//! (tests open the ports on a private prefix and drive them from other
//! threads); `processes/` only parses arguments, applies the rt settings,
//! opens the ports and calls it.
//!
//! Common to every stage ([`Metrics`], [`StatsPort`]): counters of processed,
//! dropped and rejected inputs (by reason), the compute time of every
//! processed message against the stage's budget (with the log of its latest
//! deadline misses), the latency hops that end at the stage (computed from
//! the trace the message carries), and a [`StageStats`] report published at
//! start (so the launcher knows the stage is up), every
//! `run.stats_period_s`, and once more on the way out.

pub mod chain_guard;
pub mod control;
pub mod filter;
pub mod ingest;
pub mod plant;
pub mod refine;
pub mod reorder;
pub mod resume;
pub mod snapshots;

use crate::config::{ConfigError, PipelineConfig};
use crate::ipc::BusConfig;
use crate::ipc::{
    stats_flags, Bus, Hop, HopStats, IpcError, MissStats, Percentiles, Publisher, StageKind,
    StageStats, Trace, STATS_DROP_REASONS, STATS_HOPS, STATS_REASONS,
};
use crate::rt::{Budget, Clock, LatencyHist, RtApplied};
use crate::stage::resume::Resume;
use std::sync::atomic::AtomicBool;

/// Why a stage stopped abnormally.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error(transparent)]
    Ipc(#[from] IpcError),
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The backend could not be built from the config.
    #[error("cannot build {what}: {reason}")]
    Build { what: &'static str, reason: String },
    /// The run cannot go on (e.g. the simulated plant's state became
    /// non-finite): the stage exits with [`FATAL_EXIT`] and the supervisor
    /// ends the run instead of restarting it into the same state.
    #[error("{0}")]
    Fatal(String),
}

/// Exit status of a stage that hit a [`StageError::Fatal`] (sysexits'
/// EX_SOFTWARE; 1 stays "failed, restart me").
pub const FATAL_EXIT: i32 = 70;

impl StageError {
    /// The process exit status for this error.
    pub fn exit_code(&self) -> i32 {
        match self {
            StageError::Fatal(_) => FATAL_EXIT,
            _ => 1,
        }
    }
}

/// Who a stage process is, for its reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StageIdentity {
    pub kind: StageKind,
    pub pid: u32,
    pub core: Option<usize>,
    /// [`stats_flags`] bits (FIFO, MLOCKED).
    pub flags: u32,
    /// Lock memory at the first report, up to this many bytes
    /// ([`crate::rt::sched::lock_current_memory`]).
    pub mlock_cap: Option<u64>,
}

impl StageIdentity {
    /// This process, with what its rt settings achieved.
    pub fn this_process(kind: StageKind, rt: &RtApplied) -> Self {
        let mut flags = 0;
        if rt.fifo {
            flags |= stats_flags::FIFO;
        }
        Self {
            kind,
            pid: std::process::id(),
            core: rt.core,
            flags,
            mlock_cap: rt.mlock_cap,
        }
    }

    /// This process, with no rt settings applied (tests).
    pub fn plain(kind: StageKind) -> Self {
        Self::this_process(kind, &RtApplied::default())
    }
}

/// Why a stage dropped an input (index into `dropped_by_reason`; the
/// accounting of an input stream is `published = processed + dropped +
/// rejected + in flight`, each input in exactly one term).
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::IntoStaticStr, strum::VariantNames)]
#[strum(serialize_all = "snake_case")]
#[repr(usize)]
pub enum DropReason {
    /// Never reached the stage: a gap in the publisher's sequence numbers —
    /// overwritten in a full subscriber queue (iceoryx2's safe overflow
    /// does that silently), not delivered by the publisher, or published
    /// before this subscriber was connected.
    Lost = 0,
    /// Received but skipped as too old (the freshest-wins policy); for the
    /// plant, sample ticks skipped after it fell far behind its period.
    Stale = 1,
    /// Received but replaced by a newer value before it was used (a
    /// latest-value read).
    Superseded = 2,
    /// Still queued when the stage stopped (read off the queue and counted
    /// on the way out, not processed).
    Shutdown = 3,
}

impl DropReason {
    /// Every reason, in index order.
    pub const ALL: [DropReason; 4] = [
        DropReason::Lost,
        DropReason::Stale,
        DropReason::Superseded,
        DropReason::Shutdown,
    ];

    /// Report name (`stages.<name>.dropped_by_reason.<reason>`).
    pub fn name(self) -> &'static str {
        self.into()
    }
}
const _: () = assert!(DropReason::ALL.len() <= STATS_DROP_REASONS);

/// Tracks a per-publisher sequence number and counts the gaps (samples lost
/// or superseded before this reader saw them).
#[derive(Clone, Copy, Debug, Default)]
pub struct SeqTracker {
    last: Option<u64>,
    /// The first message seen is measured against sequence number 0.
    from_zero: bool,
}

impl SeqTracker {
    /// A tracker for a publisher that numbers from 0 (every beliefbus
    /// publisher, [`crate::ipc::Header::seq`]): a first message with
    /// sequence number n reveals n messages lost before it (published
    /// before this reader connected, or overwritten before its first
    /// read). `default()` instead starts counting at the first message
    /// seen (a reader that resumes mid-stream).
    pub fn from_zero() -> Self {
        Self {
            last: None,
            from_zero: true,
        }
    }

    /// Observe `seq`; returns how many sequence numbers were skipped. A
    /// sequence number at or below the last one (a restarted publisher)
    /// restarts the tracking without counting a gap.
    pub fn observe(&mut self, seq: u64) -> u64 {
        let gap = match self.last {
            Some(l) if seq > l => seq - l - 1,
            None if self.from_zero => seq,
            _ => 0,
        };
        self.last = Some(seq);
        self.from_zero = false;
        gap
    }
}

/// Counters and histograms of one stage.
#[derive(Debug)]
pub struct Metrics {
    pub processed: u64,
    /// Total drops; [`Self::count_drop`] also classifies them.
    pub dropped: u64,
    pub dropped_by_reason: [u64; STATS_DROP_REASONS],
    pub rejected_by_reason: [u64; STATS_REASONS],
    pub budget: Budget,
    hops: Vec<(Hop, LatencyHist)>,
    warmup_ns: u64,
    first_meas_ns: Option<u64>,
    /// Plant only (see [`StageStats`]).
    pub controls_received: u64,
    pub processed_after_warmup: u64,
    pub goal_distance_sum: f64,
    pub goal_distance_count: u64,
    pub waypoints_reached: u64,
    /// Control only: ∫[q(x̂) + w‖u‖²]dt and T after the warm-up.
    pub cost_integral: f64,
    pub cost_time: f64,
    /// Chain figures (filter with the chain backend, refine).
    pub chain: ChainMetrics,
    /// Filter: collapsed steps of a weighted filter (PF, chain; None for a
    /// Gaussian filter; see `filter::regularise`).
    pub ess_collapses: Option<u64>,
    /// Control: stale drops of inputs published while the stage was
    /// waiting (see [`StageStats::dropped_stale_idle`]).
    pub stale_while_idle: u64,
}

/// Chain figures of a stage (see the `chain_*` fields of [`StageStats`]).
#[derive(Debug, Default)]
pub struct ChainMetrics {
    pub versions: u64,
    pub states: u64,
    pub delta_s: f64,
    pub swap: LatencyHist,
    pub mass_lost_max: f64,
    /// The stale-chain fallback's counts (filter).
    pub guard: chain_guard::GuardCounts,
    /// The fallback's predict + update time per observation (filter).
    pub fallback_cost: LatencyHist,
    /// Refine: row diagnostics of the versions built, and versions
    /// published again as new lineages (steady placement).
    pub rows: refine::placement::RowCounts,
    pub recentred: u64,
}

impl Metrics {
    /// Metrics with a budget, the hops this stage measures (at most
    /// [`STATS_HOPS`]) and the warm-up excluded from them.
    pub fn new(budget_ns: u64, hops: &[Hop], warmup_ns: u64) -> Self {
        assert!(hops.len() <= STATS_HOPS);
        Self {
            processed: 0,
            dropped: 0,
            dropped_by_reason: [0; STATS_DROP_REASONS],
            rejected_by_reason: [0; STATS_REASONS],
            // The misses of the first `warmup_ns` are also counted apart.
            budget: Budget::with_warmup(budget_ns, warmup_ns),
            hops: hops.iter().map(|&h| (h, LatencyHist::new())).collect(),
            warmup_ns,
            first_meas_ns: None,
            controls_received: 0,
            processed_after_warmup: 0,
            goal_distance_sum: 0.0,
            goal_distance_count: 0,
            waypoints_reached: 0,
            cost_integral: 0.0,
            cost_time: 0.0,
            chain: ChainMetrics::default(),
            ess_collapses: None,
            stale_while_idle: 0,
        }
    }

    /// Count `n` dropped inputs.
    pub fn count_drop(&mut self, reason: DropReason, n: u64) {
        self.dropped += n;
        self.dropped_by_reason[reason as usize] += n;
    }

    /// Count a rejection.
    pub fn reject(&mut self, reason: usize) {
        self.rejected_by_reason[reason.min(STATS_REASONS - 1)] += 1;
    }

    /// Total rejections.
    pub fn rejected(&self) -> u64 {
        self.rejected_by_reason.iter().sum()
    }

    /// Whether a sample measured at `t_meas_ns` is past the warm-up (the
    /// warm-up starts at the first measurement this stage sees).
    pub fn past_warmup(&mut self, t_meas_ns: u64) -> bool {
        let first = *self.first_meas_ns.get_or_insert(t_meas_ns);
        t_meas_ns >= first.saturating_add(self.warmup_ns)
    }

    /// Record every hop of this stage that `trace` completes (after the
    /// warm-up).
    pub fn record_hops(&mut self, trace: &Trace) {
        if !self.past_warmup(trace.t_meas_ns) {
            return;
        }
        for (hop, h) in self.hops.iter_mut() {
            if let Some(ns) = trace.hop_ns(*hop) {
                h.record(ns);
            }
        }
    }

    /// The histogram of `hop`, if this stage measures it.
    pub fn hop(&self, hop: Hop) -> Option<&LatencyHist> {
        self.hops.iter().find(|(h, _)| *h == hop).map(|(_, h)| h)
    }

    /// The stats message (header left for the publisher).
    pub fn to_stats(&self, id: &StageIdentity) -> StageStats {
        let mut s = StageStats {
            stage: id.kind as u32,
            pid: id.pid,
            core: id.core.map(|c| c as i32).unwrap_or(-1),
            flags: id.flags
                | if self.ess_collapses.is_some() {
                    crate::ipc::stats_flags::COLLAPSES_COUNTED
                } else {
                    0
                },
            processed: self.processed,
            ess_collapses: self.ess_collapses.unwrap_or(0),
            dropped: self.dropped,
            rejected: self.rejected(),
            rejected_by_reason: self.rejected_by_reason,
            deadline_misses: self.budget.misses(),
            deadline_misses_preempted: self.budget.preempted(),
            deadline_misses_host: self.budget.host(),
            deadline_misses_warmup: self.budget.warmup_misses(),
            miss_warmup_ns: self.budget.warmup_ns(),
            dropped_stale_idle: self.stale_while_idle,
            budget_ns: self.budget.budget_ns(),
            compute: Percentiles::from(self.budget.compute()),
            controls_received: self.controls_received,
            processed_after_warmup: self.processed_after_warmup,
            mean_goal_distance: if self.goal_distance_count > 0 {
                self.goal_distance_sum / self.goal_distance_count as f64
            } else {
                0.0
            },
            waypoints_reached: self.waypoints_reached,
            late: self.budget.late(),
            response_p50_ns: self.budget.response().quantile(0.5),
            response_p99_ns: self.budget.response().quantile(0.99),
            response_max_ns: self.budget.response().max(),
            control_cost: if self.cost_time > 0.0 {
                self.cost_integral / self.cost_time
            } else {
                0.0
            },
            control_cost_time_s: self.cost_time,
            chain_versions: self.chain.versions,
            chain_states: self.chain.states,
            chain_delta_s: self.chain.delta_s,
            chain_swap_p50_ns: self.chain.swap.quantile(0.5),
            chain_swap_p99_ns: self.chain.swap.quantile(0.99),
            chain_mass_lost_max: self.chain.mass_lost_max,
            chain_fallback_steps: self.chain.guard.fallback_steps,
            chain_fallback_episodes: self.chain.guard.by_cause,
            chain_fallback_reinits: self.chain.guard.reinits,
            chain_stale_max_ns: self.chain.guard.stale_max_ns,
            chain_fallback_p50_ns: self.chain.fallback_cost.quantile(0.5),
            chain_fallback_p99_ns: self.chain.fallback_cost.quantile(0.99),
            chain_fallback_untethered: self.chain.guard.untethered,
            chain_built: self.chain.rows.versions,
            chain_rows: self.chain.rows.rows,
            chain_rows_exact: self.chain.rows.exact,
            chain_rows_least_squares: self.chain.rows.least_squares,
            chain_recentred: self.chain.recentred,
            dropped_by_reason: self.dropped_by_reason,
            ..StageStats::default()
        };
        let log = self.budget.miss_log();
        for (slot, m) in s.miss_log.iter_mut().zip(log.iter()) {
            *slot = MissStats::from(m);
        }
        s.miss_log_overwritten = log.overwritten();
        for (slot, (hop, h)) in s.hops.iter_mut().zip(&self.hops) {
            *slot = HopStats {
                hop: *hop as u32,
                reserved: 0,
                pct: Percentiles::from(h),
            };
        }
        s
    }
}

/// Publishes a stage's [`StageStats`] periodically.
pub struct StatsPort {
    publisher: Publisher<StageStats>,
    id: StageIdentity,
    seq: u64,
    period_ns: u64,
    next_ns: u64,
}

impl std::fmt::Debug for StatsPort {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StatsPort")
            .field("id", &self.id)
            .field("seq", &self.seq)
            .finish()
    }
}

impl StatsPort {
    /// A stats publisher for `id`, reporting every `period_s`.
    pub fn open(bus: &Bus, id: StageIdentity, period_s: f64) -> Result<Self, IpcError> {
        Ok(Self {
            publisher: bus.publisher()?,
            id,
            seq: 0,
            period_ns: (period_s * 1e9).max(1e6) as u64,
            next_ns: 0,
        })
    }

    /// The stage's identity.
    pub fn id(&self) -> &StageIdentity {
        &self.id
    }

    /// Publish now; `last` marks the final report. The first report says
    /// the stage is set up: its memory is locked then, if asked for. After
    /// the final one the calling thread leaves real-time scheduling.
    pub fn publish(
        &mut self,
        m: &Metrics,
        now_ns: u64,
        last: bool,
    ) -> Result<StageStats, IpcError> {
        if let Some(cap) = self.id.mlock_cap.take() {
            match crate::rt::sched::lock_current_memory(cap) {
                Ok(_) => self.id.flags |= stats_flags::MLOCKED,
                Err(e) => eprintln!(
                    "warning: {}: memory not locked ({e}); it may page",
                    self.id.kind.name()
                ),
            }
        }
        let mut s = m.to_stats(&self.id);
        s.header.seq = self.seq;
        s.header.t_valid_ns = now_ns;
        s.header.t_pub_ns = now_ns;
        if last {
            s.flags |= stats_flags::FINAL;
        }
        self.seq += 1;
        self.next_ns = now_ns + self.period_ns;
        self.publisher.publish(&s)?;
        if last {
            // Only teardown follows: closing the ports and the process's
            // exit (unmapping its locked memory, ms of kernel work) must
            // not preempt the lower-priority stages on this core that are
            // still finishing their last messages (the plant stops first:
            // at FIFO 80 its exit delayed control's last message by
            // ~0.8 ms).
            crate::rt::sched::leave_real_time();
        }
        Ok(s)
    }

    /// Publish if a period has passed since the last report.
    pub fn tick(&mut self, m: &Metrics, now_ns: u64) -> Result<(), IpcError> {
        if now_ns >= self.next_ns {
            self.publish(m, now_ns, false)?;
        }
        Ok(())
    }
}

/// Seconds since `epoch_ns` (algorithms run on f64 seconds; keeping the
/// epoch near the run start keeps the resolution at nanoseconds).
pub fn secs_since(epoch_ns: u64, t_ns: u64) -> f64 {
    (t_ns as i128 - epoch_ns as i128) as f64 * 1e-9
}

/// Join the pipeline on `bus` as `id.kind`, open that stage's ports and run
/// its loop until `stop` (what a stage executable does after applying its
/// rt settings; tests call it on threads).
pub fn run_stage(
    bus: &BusConfig,
    cfg: &PipelineConfig,
    id: StageIdentity,
    clock: &dyn Clock,
    stop: &AtomicBool,
) -> Result<StageStats, StageError> {
    run_stage_with(bus, cfg, id, clock, stop, &Resume::default())
}

/// [`run_stage`] resuming from `resume` (a restart by the supervisor; see
/// [`resume`]).
pub fn run_stage_with(
    bus: &BusConfig,
    cfg: &PipelineConfig,
    id: StageIdentity,
    clock: &dyn Clock,
    stop: &AtomicBool,
    resume: &Resume,
) -> Result<StageStats, StageError> {
    let b = Bus::open(bus, id.kind.name())?;
    match id.kind {
        StageKind::Ingest => ingest::run(ingest::IngestPorts::open(&b, id, cfg)?, cfg, clock, stop),
        StageKind::Filter => {
            let ports = filter::FilterPorts::open(&b, id, cfg)?;
            filter::run_with(ports, cfg, clock, stop, resume.belief.as_ref())
        }
        StageKind::Control => {
            let ports = control::ControlPorts::open(&b, id, cfg)?;
            control::run_with(ports, cfg, clock, stop, resume.control.as_ref())
        }
        // Refine checkpoints its chain snapshots and resumes from the last.
        StageKind::Refine => {
            let ports = refine::RefinePorts::open(&b, id, cfg)?;
            refine::run_with(ports, cfg, clock, stop, resume)
        }
        StageKind::Plant => {
            let ports = plant::PlantPorts::open(&b, id, cfg)?;
            plant::run_resumed(ports, cfg, clock, stop, None, resume)
        }
    }
}

/// Run one step of a loop body; an error is stored in `err` and ends the
/// loop.
pub fn guarded(
    err: &mut Option<StageError>,
    step: impl FnOnce() -> Result<(), StageError>,
) -> std::ops::ControlFlow<()> {
    match step() {
        Ok(()) => std::ops::ControlFlow::Continue(()),
        Err(e) => {
            *err = Some(e);
            std::ops::ControlFlow::Break(())
        }
    }
}

/// Read the stop flag.
pub fn stopped(stop: &AtomicBool) -> bool {
    stop.load(std::sync::atomic::Ordering::Relaxed)
}

#[cfg(test)]
mod tests;
