//! Plant: the simulated system, a sensor publisher like any other.
//!
//! Every sensor period Δ = 1/`plant.sensor_rate_hz` it wakes at the absolute
//! time t_k = t_0 + kΔ, integrates the true SDE over (t_{k−1}, t_k] with
//! Euler–Maruyama steps of at most `plant.integration_dt`
//! (x ← x + f(x, u) h + F(x) √h ξ), draws the measurement
//! y_k = g(x(t_k)) + v_k, publishes it on `sensor` (measurement time t_k),
//! then publishes `truth` for evaluation.
//!
//! A discrete-time plant (`Dynamics::Discrete`) does not move between
//! samples: it takes one step per sample ([`crate::scenario::Plant::step`])
//! with the control in force at t_k. Its step index is the sample's
//! sequence number, so after a stall it never skips numbers: where a
//! continuous plant skips the missed ticks (its state moved on meanwhile),
//! a discrete one moves its schedule to the present and takes the next
//! step there (the missed ticks are counted as stale either way).
//!
//! A multi-rate plant (several sensors at their own rates, e.g. odometry
//! at 40 Hz and a laser at 5 Hz) announces each sample
//! ([`crate::scenario::Plant::next_sample`]): the plant wakes at that
//! sample's time instead of the next period, moves there, and publishes
//! the announced channel's components on that channel's id, numbered per
//! channel; its truth carries the same channel and number.
//!
//! Controls act as a zero-order hold from their publish time: controls that
//! arrived during the interval split it into segments, each integrated with
//! the control in force. (The plant reads them at its tick, so it never needs
//! to be woken by the controller.)

use super::reorder::RejectLog;
use super::resume::Resume;
use super::{stopped, DropReason, Metrics, StageError, StageIdentity, StatsPort};
use crate::config::PipelineConfig;
use crate::ipc::{
    Bus, Control, ControlReject, Publisher, PublisherGate, SensorSample, StageKind, StageStats,
    Subscriber, Truth,
};
use crate::rng;
use crate::rt::Clock;
use crate::scenario::NextSample;
use crate::{MAX_CONTROL, MAX_OBS};
use std::sync::atomic::AtomicBool;

pub use crate::scenario::PLANT_STREAM;

/// Why the plant refused a control (index into `rejected_by_reason`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::IntoStaticStr, strum::VariantNames)]
#[strum(serialize_all = "snake_case")]
#[repr(usize)]
pub enum Reason {
    /// `dim` is not the model's control dimension.
    #[strum(serialize = "control_dimension")]
    Dimension = 0,
    /// NaN or infinite components.
    #[strum(serialize = "control_non_finite")]
    NonFinite = 1,
    /// Outside the controller's limits.
    #[strum(serialize = "control_limit")]
    Limit = 2,
    /// Published by a process that is not the run's controller
    /// ([`crate::ipc::PublisherGate`]).
    #[strum(serialize = "foreign_publisher")]
    Foreign = 3,
}

impl Reason {
    /// Every reason, in index order.
    pub const ALL: [Reason; 4] = [
        Reason::Dimension,
        Reason::NonFinite,
        Reason::Limit,
        Reason::Foreign,
    ];

    /// Report name (`stages.plant.rejected_by_reason.<name>`).
    pub fn name(self) -> &'static str {
        self.into()
    }

    fn of(r: ControlReject) -> Self {
        match r {
            ControlReject::Dimension => Reason::Dimension,
            ControlReject::NonFinite => Reason::NonFinite,
            ControlReject::Limit => Reason::Limit,
        }
    }
}

/// At most one log line per rejection reason per second.
const REJECT_LOG_PERIOD_NS: u64 = 1_000_000_000;
/// Controls buffered between two ticks.
const CONTROL_BUFFER: usize = 16;

/// The ports of the plant.
pub struct PlantPorts {
    /// Controls, buffered (no wake-up: read at each tick).
    pub control: Subscriber<Control>,
    pub sensor: Publisher<SensorSample>,
    pub truth: Publisher<Truth>,
    pub stats: StatsPort,
}

impl PlantPorts {
    /// Open them on `bus`.
    pub fn open(bus: &Bus, id: StageIdentity, cfg: &PipelineConfig) -> Result<Self, StageError> {
        Ok(Self {
            control: bus.subscriber_with(CONTROL_BUFFER, false)?,
            sensor: bus.publisher()?,
            truth: bus.publisher()?,
            stats: StatsPort::open(bus, id, cfg.run.stats_period_s)?,
        })
    }
}

/// The simulation state: the scenario's plant ([`crate::scenario::SdePlant`]
/// for an SDE model).
pub use crate::scenario::SdePlant as Simulator;

/// Run the plant until `stop`; returns its final stats.
pub fn run(
    ports: PlantPorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
) -> Result<StageStats, StageError> {
    run_for(ports, cfg, clock, stop, None)
}

/// [`run`], stopping after at most `max_samples` samples.
pub fn run_for(
    ports: PlantPorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
    max_samples: Option<u64>,
) -> Result<StageStats, StageError> {
    run_resumed(ports, cfg, clock, stop, max_samples, &Resume::default())
}

/// [`run_for`] resuming after a restart from the last truth: the simulation
/// continues from that true state (with a fresh noise stream: the seed is
/// mixed with the restart count) and the channel's numbering continues
/// after it (docs/sensor-abi.md, publisher rule 2).
pub fn run_resumed(
    mut ports: PlantPorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
    max_samples: Option<u64>,
    resume: &Resume,
) -> Result<StageStats, StageError> {
    // Long on purpose: the plant's periodic loop — set-up, then one
    // simulated step and sample per period — reads top to bottom in the
    // order of a period, and its preallocated state lives in this
    // function's locals.
    let rt = cfg.stages.get(StageKind::Plant);
    let warmup_ns = (cfg.run.warmup_s * 1e9) as u64;
    let mut m = Metrics::new(rt.budget_ns(), &[], warmup_ns);
    let system = cfg.system();
    let dims = cfg.dims()?;
    let pos_axes = system.position_axes();
    let truth0 = resume
        .truth
        .as_ref()
        .filter(|t| t.x.len() == dims.state && t.x.iter().all(|v| v.is_finite()));
    let seq0 = truth0.map(|t| t.seq + 1).unwrap_or(0);
    let mut sim = system
        .plant(
            truth0.map(|t| &t.x[..]).unwrap_or(&cfg.plant.initial_state),
            match resume.restarts {
                0 => cfg.run.seed,
                n => cfg.run.seed ^ rng::splitmix64(n as u64),
            },
            cfg.plant.integration_dt,
        )
        .map_err(|reason| StageError::Build {
            what: "plant",
            reason,
        })?;
    let limits = cfg.control_limits()?;
    let mut gate = PublisherGate::from_env();
    let mut log = RejectLog::new(Reason::ALL.len(), REJECT_LOG_PERIOD_NS);
    let period_ns = (1e9 / cfg.plant.sensor_rate_hz).round().max(1.0) as u64;
    // Late by more than this: skip ahead instead of catching up.
    let max_behind_ns = cfg.plant.catch_up_periods.saturating_mul(period_ns);
    let mut pending = [Control::default(); CONTROL_BUFFER];
    let mut goal: Option<[f64; 2]> = None;
    let mut y = [0.0; MAX_OBS];
    let mut sample = SensorSample {
        channel: cfg.plant.channel,
        dim: dims.obs as u32,
        ..SensorSample::default()
    };
    let mut truth = Truth {
        channel: cfg.plant.channel,
        dim: dims.state as u32,
        obs_dim: dims.obs as u32,
        control_dim: dims.control as u32,
        ..Truth::default()
    };
    // A multi-rate plant's channels and their numbering (after a restart
    // every channel continues above the last truth's number, which only
    // skips numbers).
    let channels = system.sensor_channels();
    let mut channel_seq = vec![seq0; channels.len()];

    ports.stats.publish(&m, clock.now_ns(), false)?;
    let t0 = clock.now_ns();
    let mut t_prev = t0;
    let discrete = system.sde_model().is_none();
    // Ticks skipped by a discrete plant: its schedule is t0 + (k+1+shift)Δ.
    let mut shift: u64 = 0;
    let mut k: u64 = 0;
    while !stopped(stop) && max_samples.is_none_or(|n| k < n) {
        let (mut t_k, at) = match sim.next_sample() {
            NextSample::Periodic => (t0 + (k + 1 + shift) * period_ns, None),
            NextSample::At { channel, t } => {
                if channel >= channels.len() || !(t.is_finite() && t >= 0.0) {
                    let _ = ports.stats.publish(&m, clock.now_ns(), true);
                    return Err(StageError::Fatal(format!(
                        "the plant announced a sample on channel index {channel} at {t} s; \
                         the scenario has {} channels and times are finite and >= 0",
                        channels.len()
                    )));
                }
                // Never before the previous sample (times do not decrease).
                (
                    t0.saturating_add((t * 1e9).round() as u64).max(t_prev),
                    Some(channel),
                )
            }
            NextSample::Done => {
                // The drive is over: idle until the run stops.
                clock.sleep_until_ns(clock.now_ns() + period_ns);
                ports.stats.tick(&m, clock.now_ns())?;
                continue;
            }
        };
        let now = clock.now_ns();
        if at.is_some() && now > t_k + max_behind_ns {
            // Far behind a multi-rate plant's sample: move past it
            // unpublished (the controls read at the next sample still
            // take effect from their publish times).
            m.count_drop(DropReason::Stale, 1);
            sim.advance(t_k.saturating_sub(t_prev) as f64 * 1e-9);
            sim.step();
            t_prev = t_k;
            continue;
        }
        if at.is_none() && now > t_k + max_behind_ns {
            // Far behind (e.g. the machine stalled): skip to the present —
            // the sample numbers too, unless a step is a sample.
            let skip = (now - t_k) / period_ns;
            m.count_drop(DropReason::Stale, skip);
            if discrete {
                shift += skip;
            } else {
                k += skip;
            }
            t_k += skip * period_ns;
        }
        clock.sleep_until_ns(t_k);
        if clock.now_ns() < t_k {
            continue; // woken early by a signal: re-check stop
        }
        let t_wake = clock.now_ns();
        m.budget.start();

        // Controls published up to t_k, in publish order, each from its
        // publish time (zero-order hold). Anyone who can open the control
        // service can publish on it: a control of the wrong dimension,
        // non-finite or outside the controller's limits is counted and
        // ignored, and the last good one stays in force.
        let mut n = 0;
        for _ in 0..CONTROL_BUFFER {
            let Some((c, origin)) = ports.control.receive_from()? else {
                break;
            };
            let verdict = if gate.admit(&ports.control, &origin) {
                limits.check(&c).map_err(Reason::of)
            } else {
                Err(Reason::Foreign)
            };
            match verdict {
                Ok(()) => {
                    pending[n] = c;
                    n += 1;
                }
                Err(r) => {
                    m.reject(r as usize);
                    if let Some(more) = log.note(r as usize, t_wake) {
                        eprintln!(
                            "beliefbus-plant: rejected control ({}) seq {} dim {}{}",
                            r.name(),
                            c.header.seq,
                            c.dim,
                            if more > 0 {
                                format!(" (+{more} more since the last line)")
                            } else {
                                String::new()
                            }
                        );
                    }
                }
            }
        }
        m.controls_received += n as u64;
        let ctl = &mut pending[..n];
        ctl.sort_by_key(|c| c.header.t_pub_ns);
        let mut t = t_prev;
        for c in ctl.iter() {
            let tc = c.header.t_pub_ns.clamp(t, t_k);
            if tc > t {
                sim.advance((tc - t) as f64 * 1e-9);
                t = tc;
            }
            sim.set_control(&c.u[..(c.dim as usize).min(MAX_CONTROL)]);
            goal = Some(c.goal);
            m.waypoints_reached = c.waypoints_reached;
        }
        if t_k > t {
            sim.advance((t_k - t) as f64 * 1e-9);
        }
        // A discrete-time plant steps once per sample, with the control in
        // force now.
        sim.step();
        t_prev = t_k;
        // Controls are checked, so this takes a model that blows up under
        // admissible inputs (or a bug): the truth is gone, and a restart
        // would resume from the same diverged trajectory. End the run.
        if let Some(i) = sim.state().iter().position(|v| !v.is_finite()) {
            let _ = ports.stats.publish(&m, clock.now_ns(), true);
            return Err(StageError::Fatal(format!(
                "the plant state became non-finite (component {i} = {}) at sample {}; \
                 the run cannot continue",
                sim.state()[i],
                seq0 + k
            )));
        }

        sim.measure(&mut y[..dims.obs]);
        let seq = match at {
            None => {
                sample.values[..dims.obs].copy_from_slice(&y[..dims.obs]);
                seq0 + k
            }
            Some(i) => {
                // The announced channel's components, in its order.
                let c = &channels[i];
                sample.channel = c.id;
                sample.dim = c.components.len() as u32;
                sample.values.fill(0.0);
                for (v, &j) in sample.values.iter_mut().zip(&c.components) {
                    *v = y[j];
                }
                truth.channel = c.id;
                channel_seq[i] += 1;
                channel_seq[i] - 1
            }
        };
        sample.seq = seq;
        sample.t_meas_ns = t_k;
        let t_pub = clock.now_ns();
        sample.t_pub_ns = t_pub;
        ports.sensor.publish(&sample)?;

        truth.header.seq = seq;
        truth.header.t_valid_ns = t_k;
        truth.header.t_pub_ns = clock.now_ns();
        truth.x[..dims.state].copy_from_slice(sim.state());
        truth.u[..dims.control].copy_from_slice(sim.control());
        truth.y[..dims.obs].copy_from_slice(&y[..dims.obs]);
        ports.truth.publish(&truth)?;

        m.processed += 1;
        // Released when the tick was due.
        m.budget.record_released(t_k, t_wake, t_pub);
        if m.past_warmup(t_k) {
            m.processed_after_warmup += 1;
            // The control message carries the goal's first two axes.
            if let (Some(g), 1..=2) = (goal, pos_axes.len()) {
                let x = sim.state();
                let d2: f64 = pos_axes
                    .iter()
                    .zip(g)
                    .map(|(&a, g)| (x[a] - g).powi(2))
                    .sum();
                m.goal_distance_sum += d2.sqrt();
                m.goal_distance_count += 1;
            }
        }
        k += 1;
        ports.stats.tick(&m, clock.now_ns())?;
    }
    Ok(ports.stats.publish(&m, clock.now_ns(), true)?)
}
