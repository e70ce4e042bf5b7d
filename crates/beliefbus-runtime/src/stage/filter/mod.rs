//! Filter: one Bayes-filter step per observation (thesis eq. 3.6) —
//! predict the belief to the measurement time under the latest control
//! (held constant since the previous observation), update it with the
//! measurement, publish the Gaussian summary with the trace extended by the
//! filter's in/out stamps. The backend comes from `filter.backend`.
//!
//! Time: the filter runs on seconds since the first observation it sees
//! (which it takes as the time of the prior). A step the filter refuses is
//! counted by reason: a refused prediction publishes nothing, a refused
//! update publishes the prediction flagged `UPDATE_REFUSED`.
//!
//! The `chain` backend runs [`LiveChainFilter`] on the snapshots
//! of the refine stage's `chain` slice channel: after each belief is
//! published (off the sensor→belief path), a received version is prepared
//! for at most `filter.chain.prepare_budget_us` and swapped in when ready;
//! the swap durations, versions, size, δ and the largest mass lost in a
//! remap go into the stage's `chain_*` stats. An EKF answers until the first
//! snapshot arrives; if refine stops, filtering goes on with the last one.
//! Beside the chain, a second EKF filters every observation ([`GuardedChain`])
//! and its belief is published, flagged `CHAIN_FALLBACK`, while the chain is
//! stale — refine starved, stopped or dead, or the chain explaining the data
//! worse than the EKF; the next version then starts from the EKF's Gaussian
//! (criteria, counts and why: [`super::chain_guard`]). Its cost is one EKF
//! step per observation (predict + update of a 4-state model, a few µs)
//! plus an O(d²) reset per version, allocation-free.

use super::chain_guard::{Install, StaleGuard};
use super::resume::ResumeBelief;
use super::snapshots::{chain_qos, CHAIN_CHANNEL};
use super::{
    guarded, secs_since, stopped, DropReason, Metrics, SeqTracker, StageError, StageIdentity,
    StatsPort,
};
use crate::belief::Gaussian;
use crate::config::{FilterBackend, PipelineConfig};
use crate::filter::ekf::Ekf;
use crate::filter::live_chain::{LiveChainFilter, SwapInfo};
use crate::filter::pf::Pf;
use crate::filter::ukf::Ukf;
use crate::filter::{BayesFilter, FilterError};
use crate::ipc::{
    belief_status, run_loop, Belief, Bus, Control, Hop, Observation, Publisher, PublisherGate,
    SliceSample, SliceSubscriber, StageKind, StageStats, Subscriber, Wake, Wakeable,
};
use crate::model::{Measurement, ObsMask, SdeModel};
use crate::rt::Clock;
use crate::scenario::DynModel;
use crate::MAX_CONTROL;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

mod backend;
use backend::chain_work;
pub use backend::{Backend, GuardedChain};

/// Why the filter refused a step (index into `rejected_by_reason`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::IntoStaticStr, strum::VariantNames)]
#[strum(serialize_all = "snake_case")]
#[repr(usize)]
pub enum Reason {
    TimeBackwards = 0,
    Dimension = 1,
    NonFinite = 2,
    /// Every particle/hypothesis has zero likelihood.
    Degenerate = 3,
    Numerical = 4,
    /// A chain snapshot that failed validation (chain backend).
    Snapshot = 5,
    /// A measurement time far off the stage's clock (a rogue publisher on
    /// the internal channel; see [`time_out_of_range`]).
    #[strum(serialize = "time_out_of_range")]
    TimeRange = 6,
    /// Published by a process that is not the run's ingest
    /// ([`crate::ipc::PublisherGate`]). Not part of the observation books:
    /// ingest never published it.
    #[strum(serialize = "foreign_publisher")]
    Foreign = 7,
}

impl Reason {
    /// Every reason, in index order.
    pub const ALL: [Reason; 8] = [
        Reason::TimeBackwards,
        Reason::Dimension,
        Reason::NonFinite,
        Reason::Degenerate,
        Reason::Numerical,
        Reason::Snapshot,
        Reason::TimeRange,
        Reason::Foreign,
    ];

    /// Report name.
    pub fn name(self) -> &'static str {
        self.into()
    }

    fn of(e: &FilterError) -> Reason {
        match e {
            FilterError::TimeBackwards { .. } => Reason::TimeBackwards,
            FilterError::Dimension { .. } => Reason::Dimension,
            FilterError::NonFinite(_) => Reason::NonFinite,
            FilterError::Degenerate => Reason::Degenerate,
            FilterError::Numerical(_) => Reason::Numerical,
        }
    }
}

/// How far before the stage's clock the first observation (the filter's
/// time origin) may have been measured.
pub const MAX_EPOCH_AGE_NS: u64 = 60_000_000_000;

/// Whether an observation's measurement time `t_ns` is absurd at `now_ns`
/// (the guard in front of `predict`): unset (0), more than `ahead_ns` in
/// the future — the window ingest enforces on sensors (`ingest.max_age_s`)
/// — or, for the observation that would fix the time origin
/// (`sets_epoch`), more than [`MAX_EPOCH_AGE_NS`] in the past. Without it
/// one rogue sample on the internal channel could make the filter predict
/// over years (a stall: the work grows with the horizon) or, as an origin,
/// turn every later observation into such a prediction. Within the window a
/// sample ahead of the clock can only hold the next ones back as
/// `time_backwards` for at most `ahead_ns`.
pub fn time_out_of_range(t_ns: u64, now_ns: u64, ahead_ns: u64, sets_epoch: bool) -> bool {
    t_ns == 0
        || t_ns > now_ns.saturating_add(ahead_ns)
        || (sets_epoch && t_ns.saturating_add(MAX_EPOCH_AGE_NS) < now_ns)
}

/// The ports of the filter stage.
pub struct FilterPorts {
    pub obs: Subscriber<Observation>,
    /// Latest control (no wake-up: it is read when an observation arrives).
    pub control: Subscriber<Control>,
    pub belief: Publisher<Belief>,
    pub stats: StatsPort,
    /// Chain snapshots (chain backend only).
    pub chain: Option<SliceSubscriber<u64>>,
}

impl FilterPorts {
    /// Open them on `bus`.
    pub fn open(bus: &Bus, id: StageIdentity, cfg: &PipelineConfig) -> Result<Self, StageError> {
        Ok(Self {
            obs: bus.subscriber_with(cfg.plant.burst_queue::<Observation>(), true)?,
            control: bus.subscriber_with(1, false)?,
            belief: bus.publisher()?,
            stats: StatsPort::open(bus, id, cfg.run.stats_period_s)?,
            chain: if cfg.filter.backend == FilterBackend::Chain {
                let dim = cfg.model()?.dims().state;
                Some(bus.slice_subscriber(CHAIN_CHANNEL, &chain_qos(cfg, dim), true)?)
            } else {
                None
            },
        })
    }
}

/// Build the configured backend at time `t0` from the prior. The filter's
/// random stream is seeded from `run.seed` mixed with `filter.pf.seed`.
pub fn make_filter(cfg: &PipelineConfig, t0: f64) -> Result<Box<dyn BayesFilter>, StageError> {
    make_filter_from(cfg, &cfg.prior(), t0)
}

/// [`make_filter`] from an explicit prior (a restart resumes from the last
/// published belief).
pub fn make_filter_from(
    cfg: &PipelineConfig,
    prior: &Gaussian,
    t0: f64,
) -> Result<Box<dyn BayesFilter>, StageError> {
    let prior = *prior;
    let build = |e: &dyn std::fmt::Display| StageError::Build {
        what: "filter",
        reason: e.to_string(),
    };
    // Built-in backends need the SDE model (validation refused them on a
    // discrete-time scenario).
    let model = cfg.model();
    // The scenario's own backend; a discrete-time system supplies
    // `projection-pf` on its own model under that name.
    let own = match &cfg.filter.backend {
        FilterBackend::Scenario(name) => Some(name.as_str()),
        FilterBackend::ProjectionPf if cfg.system().sde_model().is_none() => Some("projection-pf"),
        _ => None,
    };
    if let Some(name) = own {
        // On its own stream id ("FILT").
        let ctx = crate::scenario::FilterContext {
            seed: crate::rng::splitmix64(cfg.run.seed ^ crate::rng::splitmix64(0x4649_4C54)),
            sample_dt: cfg.sample_dt(),
            start: prior,
            resumed: prior != cfg.prior(),
            t0,
        };
        return match cfg.system().filter_backend(name, &ctx) {
            Some(r) => r.map_err(|e| build(&e)),
            None => Err(build(&format!("the scenario offers no filter {name:?}"))),
        };
    }
    Ok(match &cfg.filter.backend {
        FilterBackend::Scenario(name) => {
            return Err(build(&format!("the scenario offers no filter {name:?}")))
        }
        FilterBackend::Pf => {
            let mut pf = cfg.filter.pf.clone();
            pf.seed = crate::rng::splitmix64(cfg.run.seed ^ crate::rng::splitmix64(pf.seed));
            Box::new(Pf::new(model?, &pf, &prior, t0).map_err(|e| build(&e))?)
        }
        FilterBackend::ProjectionPf => {
            let mut pf = cfg.filter.pf.clone();
            pf.seed = crate::rng::splitmix64(cfg.run.seed ^ crate::rng::splitmix64(pf.seed));
            Box::new(
                beliefbus_projection::SdeProjectionPf::new(model?, &pf, &prior, t0)
                    .map_err(|e| build(&e))?,
            )
        }
        // The chain backend's fallback until its first snapshot.
        FilterBackend::Ekf | FilterBackend::Chain => {
            Box::new(Ekf::new(model?, &cfg.filter.ekf, &prior, t0).map_err(|e| build(&e))?)
        }
        FilterBackend::Ukf => {
            Box::new(Ukf::new(model?, &cfg.filter.ukf, &prior, t0).map_err(|e| build(&e))?)
        }
    })
}

/// Run the filter until `stop`; returns its final stats.
pub fn run(
    ports: FilterPorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
) -> Result<StageStats, StageError> {
    run_with(ports, cfg, clock, stop, None)
}

/// [`run`] resuming from the last published belief (after a restart): the
/// filter starts from that Gaussian at its time of validity, which becomes
/// its time origin, and continues the belief numbering.
///
/// Overload (`filter.max_obs_age_us` > 0): an observation that waited
/// longer than that while a newer one is queued is skipped and counted as
/// dropped — the freshest data wins, so latency stays bounded by about one
/// filter step plus that age when the sensor outpaces the filter.
pub fn run_with(
    mut ports: FilterPorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
    resume: Option<&ResumeBelief>,
) -> Result<StageStats, StageError> {
    // Long on purpose: the stage's loop — set-up, then the per-message
    // body handed to `run_loop` — reads top to bottom in the order a
    // message takes on the latency path, and its preallocated state lives in
    // this function's locals, borrowed by the loop body.
    let rt = cfg.stages.get(StageKind::Filter);
    let mut m = Metrics::new(
        rt.budget_ns(),
        &[Hop::IngestToFilter, Hop::SensorToBelief],
        (cfg.run.warmup_s * 1e9) as u64,
    );
    // A restart resumes from the last published belief (the chain backend
    // spreads it over the first snapshot it receives).
    let resumed = resume.and_then(|b| b.gaussian().map(|g| (b, g)));
    let start = resumed.as_ref().map_or_else(|| cfg.prior(), |(_, g)| *g);
    let mut filter = Backend::new(cfg, &start, 0.0)?;
    let prepare = Duration::from_secs_f64(cfg.filter.chain.prepare_budget_us * 1e-6);
    let dims = filter.dims();
    let model_std = {
        let mut s = [0.0; crate::MAX_OBS];
        cfg.dynamics()?.obs_std(&mut s[..dims.obs]);
        s
    };
    let mut u = [0.0; MAX_CONTROL];
    let mut epoch: Option<u64> = resumed.as_ref().map(|(b, _)| b.t_valid_ns);
    // Ingest numbers from 0: a fresh filter counts what it never saw.
    let mut seq = match resumed {
        Some(_) => SeqTracker::default(),
        None => SeqTracker::from_zero(),
    };
    let mut out = Belief::default();
    let mut out_seq = resumed.as_ref().map(|(b, _)| b.seq + 1).unwrap_or(0);
    let max_age_ns = (cfg.filter.max_obs_age_us * 1e3) as u64;
    let ahead_ns = (cfg.ingest.max_age_s * 1e9) as u64;
    let mut err = None;
    ports.stats.publish(&m, clock.now_ns(), false)?;
    let tick = Duration::from_secs_f64(cfg.run.stats_period_s.min(0.1));
    // Observations only from the run's ingest, controls only from its
    // controller and inside its limits: anyone can open these services.
    let mut obs_gate = PublisherGate::from_env();
    let mut control_gate = PublisherGate::from_env();
    let limits = cfg.control_limits()?;

    let obs_sub = &ports.obs;
    let control = &ports.control;
    let belief = &mut ports.belief;
    let stats = &mut ports.stats;
    let chain_sub = ports.chain.as_ref();
    let mut inputs: Vec<&dyn Wakeable> = vec![obs_sub];
    if let Some(c) = chain_sub {
        inputs.push(c);
    }
    run_loop(&inputs, rt.wake_mode(), tick, stop, |w| {
        guarded(&mut err, || {
            if w == Wake::Data {
                while let Some((o, origin)) = obs_sub.receive_from()? {
                    // An endless backlog must not starve the report (the
                    // supervisor's heartbeat). Before the message's start:
                    // building the report (its percentiles) is not this
                    // message's work — inside it, it added tens of µs of
                    // CPU to one message a second.
                    stats.tick(&m, clock.now_ns())?;
                    let t_in = clock.now_ns();
                    m.budget.start();
                    if !obs_gate.admit(obs_sub, &origin) {
                        m.reject(Reason::Foreign as usize);
                        continue;
                    }
                    m.count_drop(DropReason::Lost, seq.observe(o.header.seq));
                    if max_age_ns > 0
                        && t_in.saturating_sub(o.header.t_pub_ns) > max_age_ns
                        && obs_sub.has_data()
                    {
                        // Stale, and a fresher one waits.
                        m.count_drop(DropReason::Stale, 1);
                        continue;
                    }
                    if time_out_of_range(o.header.t_valid_ns, t_in, ahead_ns, epoch.is_none()) {
                        m.reject(Reason::TimeRange as usize);
                        continue;
                    }
                    let epoch_ns = *epoch.get_or_insert(o.header.t_valid_ns);
                    if o.header.t_valid_ns < epoch_ns {
                        // Measured before the resumed belief: too old.
                        m.reject(Reason::TimeBackwards as usize);
                        continue;
                    }
                    while let Some((c, origin)) = control.receive_from()? {
                        if control_gate.admit(control, &origin) && limits.check(&c).is_ok() {
                            let n = (c.dim as usize).min(dims.control);
                            u[..n].copy_from_slice(&c.u[..n]);
                        }
                    }
                    let t = secs_since(epoch_ns, o.header.t_valid_ns);
                    if let Err(e) = filter.predict(t, &u[..dims.control]) {
                        m.reject(Reason::of(&e) as usize);
                        continue;
                    }
                    let std = if o.has_std != 0 {
                        // Unflagged components keep the model's σ.
                        let mut s = model_std;
                        for i in ObsMask(o.mask).iter().take_while(|&i| i < dims.obs) {
                            s[i] = o.std[i];
                        }
                        Some(s)
                    } else {
                        None
                    };
                    let meas = Measurement {
                        y: &o.y[..dims.obs],
                        mask: ObsMask(o.mask),
                        std: std.as_ref().map(|s| &s[..dims.obs]),
                    };
                    out.status = 0;
                    let updated = filter.update(&meas, t_in);
                    m.ess_collapses = filter.ess_collapses();
                    match updated {
                        Ok(info) => {
                            out.ess = info.ess;
                            out.log_evidence = info.log_evidence;
                            if info.resampled {
                                out.status |= belief_status::RESAMPLED;
                            }
                        }
                        Err(e) => {
                            m.reject(Reason::of(&e) as usize);
                            out.status |= belief_status::UPDATE_REFUSED;
                        }
                    }
                    if let Backend::Chain(g) = &filter {
                        if g.on_fallback() {
                            out.status |= belief_status::CHAIN_FALLBACK;
                        }
                    }
                    out.set_gaussian(&filter.belief());
                    out.trace = o.trace;
                    out.trace.t_filter_in_ns = t_in;
                    out.header.seq = out_seq;
                    out.header.t_valid_ns = o.header.t_valid_ns;
                    let now = clock.now_ns();
                    out.header.t_pub_ns = now;
                    out.trace.t_filter_out_ns = now;
                    belief.publish(&out)?;
                    out_seq += 1;
                    // A refused update is counted as rejected, not filtered.
                    if out.status & belief_status::UPDATE_REFUSED == 0 {
                        m.processed += 1;
                    }
                    m.budget.record_released(o.header.t_pub_ns, t_in, now);
                    m.record_hops(&out.trace);
                    if let Backend::Chain(g) = &mut filter {
                        // The fallback's step, when the chain's belief
                        // went out without it.
                        g.after_publish();
                        if let Some(ns) = g.fallback_ns() {
                            m.chain.fallback_cost.record(ns.max(1));
                        }
                        m.chain.guard = g.counts();
                    }
                    if let (Backend::Chain(f), Some(sub)) = (&mut filter, chain_sub) {
                        chain_work(f, sub, prepare, &mut m, clock)?;
                    }
                }
            }
            // Idle wake-ups (a snapshot arrived, or a tick) prepare too.
            if let (Backend::Chain(f), Some(sub)) = (&mut filter, chain_sub) {
                chain_work(f, sub, prepare, &mut m, clock)?;
            }
            stats.tick(&m, clock.now_ns())?;
            Ok(())
        })
    })?;
    // What is still queued is accounted for, not filtered (at most a few
    // queues' worth: a publisher still running cannot hold up the stop).
    for _ in 0..256 {
        let Ok(Some(o)) = ports.obs.receive() else {
            break;
        };
        m.count_drop(DropReason::Lost, seq.observe(o.header.seq));
        m.count_drop(DropReason::Shutdown, 1);
    }
    let last = ports.stats.publish(&m, clock.now_ns(), true)?;
    match err {
        Some(e) if !stopped(stop) => Err(e),
        _ => Ok(last),
    }
}
