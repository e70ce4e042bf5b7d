//! Ingest: validates every sensor sample and forwards a time-ordered stream
//! of observations to the filter. A bad sample is counted by reason, logged
//! at a bounded rate and dropped; it can never crash or stall the pipeline
//! (DESIGN.md). The sample ABI and the rules for publishers are in
//! `docs/sensor-abi.md`.
//!
//! Checks, in order (the first failing one names the reason): known channel
//! (`unknown_channel`); `dim` equals the channel's number of components
//! (`dimension`); values finite (`non_finite`); per-sample σ (if flagged)
//! finite and > 0 and a measurement time that is set and at most
//! `ingest.max_age_s` in the future (`invalid`); sequence number above the
//! channel's last accepted one (`duplicate`); age at arrival at most
//! `ingest.max_age_s` (`too_old`); measurement time not before the channel's
//! last accepted one (`time_backwards`); rate within the channel's
//! `max_rate_hz` (token bucket of [`RATE_BURST`] samples refilled at
//! `max_rate_hz` on measurement time, `rate`). A rejected sample leaves the
//! channel's state untouched, so the good samples after it are accepted.
//!
//! Several channels (several sensors, each filling its components of the
//! observation vector — the observation's [`crate::model::ObsMask`]) are
//! merged by measurement time through a bounded reorder window
//! ([`super::reorder::ReorderBuffer`], `ingest.reorder_window_ms`); a sample
//! measured before the last forwarded observation arrives too late for the
//! filter and is rejected as `too_old`.

use super::reorder::{RejectLog, ReorderBuffer};
use super::{guarded, stopped, DropReason, Metrics, StageError, StageIdentity, StatsPort};
use crate::config::ChannelConfig;
use crate::config::PipelineConfig;
use crate::ipc::{
    run_loop, Bus, Hop, Observation, Publisher, SensorSample, StageKind, StageStats, Subscriber,
    Wake, SENSOR_MAX_DIM,
};
use crate::rt::Clock;
use crate::MAX_OBS;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

/// Why ingest rejected a sample (index into `rejected_by_reason`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::IntoStaticStr, strum::VariantNames)]
#[strum(serialize_all = "snake_case")]
#[repr(usize)]
pub enum Reason {
    Dimension = 0,
    NonFinite = 1,
    TimeBackwards = 2,
    TooOld = 3,
    Duplicate = 4,
    UnknownChannel = 5,
    Rate = 6,
    /// Invalid σ, or a measurement time of 0 or in the future.
    Invalid = 7,
    /// Another publisher than the one the channel is bound to.
    ForeignPublisher = 8,
    /// A sequence number further ahead of the channel's last one than its
    /// rate allows since then.
    SeqJump = 9,
}

impl Reason {
    /// Every reason, in index order.
    pub const ALL: [Reason; 10] = [
        Reason::Dimension,
        Reason::NonFinite,
        Reason::TimeBackwards,
        Reason::TooOld,
        Reason::Duplicate,
        Reason::UnknownChannel,
        Reason::Rate,
        Reason::Invalid,
        Reason::ForeignPublisher,
        Reason::SeqJump,
    ];

    /// Report name (`stages.ingest.rejected_by_reason.<name>`).
    pub fn name(self) -> &'static str {
        self.into()
    }
}

/// Burst the rate limiter tolerates (samples).
pub const RATE_BURST: f64 = 3.0;
/// Sequence numbers a channel may skip beyond twice what its `max_rate_hz`
/// allows over the measurement time since its last accepted sample.
pub const SEQ_JUMP_SLACK: f64 = 1024.0;
/// Observations the reorder window holds at most.
const REORDER_CAPACITY: usize = 256;
/// At most one log line per rejection reason per second.
const REJECT_LOG_PERIOD_NS: u64 = 1_000_000_000;

/// The ports of the ingest stage.
pub struct IngestPorts {
    pub sensor: Subscriber<SensorSample>,
    pub obs: Publisher<Observation>,
    pub stats: StatsPort,
}

impl IngestPorts {
    /// Open them on `bus`.
    pub fn open(bus: &Bus, id: StageIdentity, cfg: &PipelineConfig) -> Result<Self, StageError> {
        Ok(Self {
            sensor: bus.subscriber_with(cfg.plant.burst_queue::<SensorSample>(), true)?,
            obs: bus.publisher()?,
            stats: StatsPort::open(bus, id, cfg.run.stats_period_s)?,
        })
    }
}

#[derive(Clone, Debug)]
struct Channel {
    cfg: ChannelConfig,
    mask: u32,
    /// The publisher (iceoryx2 port id) the channel is bound to: the first
    /// whose sample was accepted; another is bound only once it is gone.
    owner: Option<u128>,
    /// Highest trusted sequence number seen (accepted, or rejected after
    /// the duplicate check): the numbers skipped below it were lost.
    seen: Option<u64>,
    last_seq: Option<u64>,
    last_t: u64,
    tokens: f64,
    tokens_t: u64,
}

/// The validation state of ingest (separate from the loop so it can be
/// tested on plain samples).
#[derive(Debug)]
pub struct Validator {
    channels: Vec<Channel>,
    obs_dim: usize,
    max_age_ns: u64,
    lost: u64,
}

impl Validator {
    /// A validator for `cfg`'s channels and model.
    pub fn new(cfg: &PipelineConfig) -> Result<Self, StageError> {
        let dims = cfg.dims()?;
        let channels = cfg
            .channels(dims.obs)
            .into_iter()
            .map(|c| Channel {
                mask: c.components.iter().fold(0u32, |m, &k| m | (1 << k)),
                cfg: c,
                owner: None,
                seen: None,
                last_seq: None,
                last_t: 0,
                tokens: RATE_BURST,
                tokens_t: 0,
            })
            .collect();
        Ok(Self {
            channels,
            obs_dim: dims.obs,
            max_age_ns: (cfg.ingest.max_age_s * 1e9) as u64,
            lost: 0,
        })
    }

    /// Check one sample received at `now_ns`; on success fill `obs` (y,
    /// mask, σ, channel, the sensor part of the trace) and return the
    /// number of samples of this channel lost before it (sequence gap; see
    /// [`Self::lost`], which also counts gaps revealed by rejected samples).
    pub fn check(
        &mut self,
        s: &SensorSample,
        now_ns: u64,
        obs: &mut Observation,
    ) -> Result<u64, Reason> {
        self.check_from(s, 0, &|_| true, now_ns, obs)
    }

    /// [`Self::check`] for a sample of publisher `publisher`
    /// ([`crate::ipc::Origin::publisher`]); `connected(p)` tells whether
    /// publisher `p` is still connected. Each channel is bound to the
    /// first publisher whose sample it accepts: samples of any other are
    /// rejected as `foreign_publisher` while that one stays connected; when
    /// it is gone the next publisher is bound and the channel's numbering
    /// starts afresh with it (a restarted sensor).
    pub fn check_from(
        &mut self,
        s: &SensorSample,
        publisher: u128,
        connected: &dyn Fn(u128) -> bool,
        now_ns: u64,
        obs: &mut Observation,
    ) -> Result<u64, Reason> {
        // Long on purpose: the ABI's publisher rules checked in order
        // (docs/sensor-abi.md), each returning its rejection reason.
        let Some(ch) = self.channels.iter_mut().find(|c| c.cfg.id == s.channel) else {
            return Err(Reason::UnknownChannel);
        };
        if let Some(owner) = ch.owner.filter(|&o| o != publisher) {
            if connected(owner) {
                return Err(Reason::ForeignPublisher);
            }
            ch.owner = None;
            ch.last_seq = None;
            ch.seen = None;
        }
        let n = ch.cfg.components.len();
        if s.dim as usize != n || n > SENSOR_MAX_DIM {
            return Err(Reason::Dimension);
        }
        if s.values[..n].iter().any(|v| !v.is_finite()) {
            return Err(Reason::NonFinite);
        }
        if s.has_noise_std()
            && s.noise_std[..n]
                .iter()
                .any(|v| !(v.is_finite() && *v > 0.0))
        {
            return Err(Reason::Invalid);
        }
        if s.t_meas_ns == 0 || s.t_meas_ns > now_ns.saturating_add(self.max_age_ns) {
            return Err(Reason::Invalid);
        }
        if ch.last_seq.is_some_and(|l| s.seq <= l) {
            return Err(Reason::Duplicate);
        }
        // A jump further than the channel's rate allows since its last
        // accepted sample is refused on its own: accepted, it would make
        // every later genuine sample a `duplicate` (one sequence number of
        // 2⁶² did that to 375 of them).
        if let Some(l) = ch.last_seq {
            let dt = s.t_meas_ns.saturating_sub(ch.last_t) as f64 * 1e-9;
            let allowed = 2.0 * dt * ch.cfg.max_rate_hz + SEQ_JUMP_SLACK;
            if (s.seq - l) as f64 > allowed {
                return Err(Reason::SeqJump);
            }
        }
        // From here the sequence number is trusted: numbers skipped before
        // it were lost in transport (`dropped`), whether or not this sample
        // is accepted — a sample rejected for its time or rate was seen,
        // not lost.
        let gap = match ch.seen {
            Some(l) if s.seq > l => s.seq - l - 1,
            _ => 0,
        };
        if ch.seen.is_none_or(|l| s.seq > l) {
            ch.seen = Some(s.seq);
        }
        self.lost += gap;
        if now_ns.saturating_sub(s.t_meas_ns) > self.max_age_ns {
            return Err(Reason::TooOld);
        }
        if s.t_meas_ns < ch.last_t {
            return Err(Reason::TimeBackwards);
        }
        // Token bucket on measurement time. A rate-rejected sample moves
        // `tokens_t` but not `last_t`, so a later accepted one may be
        // measured before `tokens_t`: no refill then (never an underflow).
        let refill = if ch.tokens_t == 0 {
            RATE_BURST
        } else {
            s.t_meas_ns.saturating_sub(ch.tokens_t) as f64 * 1e-9 * ch.cfg.max_rate_hz
        };
        let tokens = (ch.tokens + refill).min(RATE_BURST);
        ch.tokens_t = ch.tokens_t.max(s.t_meas_ns);
        if tokens < 1.0 {
            ch.tokens = tokens;
            return Err(Reason::Rate);
        }
        ch.tokens = tokens - 1.0;
        ch.owner = Some(publisher);
        ch.last_seq = Some(s.seq);
        ch.last_t = s.t_meas_ns;

        let m = self.obs_dim;
        obs.y = [0.0; MAX_OBS];
        obs.std = [0.0; MAX_OBS];
        for (j, &k) in ch.cfg.components.iter().enumerate() {
            obs.y[k] = s.values[j];
            if s.has_noise_std() {
                obs.std[k] = s.noise_std[j];
            }
        }
        obs.channel = s.channel;
        obs.mask = ch.mask;
        obs.dim = m as u32;
        obs.has_std = s.has_noise_std() as u32;
        obs.header.t_valid_ns = s.t_meas_ns;
        obs.trace = Default::default();
        obs.trace.sensor_seq = s.seq;
        obs.trace.sensor_channel = s.channel;
        obs.trace.t_meas_ns = s.t_meas_ns;
        obs.trace.t_sensor_pub_ns = if s.t_pub_ns != 0 {
            s.t_pub_ns
        } else {
            s.t_meas_ns
        };
        Ok(gap)
    }

    /// Samples lost before ingest saw them (sequence numbers skipped on a
    /// channel), in total.
    pub fn lost(&self) -> u64 {
        self.lost
    }

    /// The configured channel ids.
    pub fn channel_ids(&self) -> Vec<u32> {
        self.channels.iter().map(|c| c.cfg.id).collect()
    }
}

/// Forward one released observation.
fn forward(
    o: &mut Observation,
    out_seq: &mut u64,
    obs: &mut Publisher<Observation>,
    m: &mut Metrics,
    now: u64,
) -> Result<(), StageError> {
    o.header.seq = *out_seq;
    o.header.t_pub_ns = now;
    o.trace.t_ingest_out_ns = now;
    obs.publish(o)?;
    *out_seq += 1;
    m.processed += 1;
    m.record_hops(&o.trace);
    Ok(())
}

/// Count a rejection and log it if a line is due for its reason.
fn reject(m: &mut Metrics, log: &mut RejectLog, reason: Reason, s: &SensorSample, now: u64) {
    m.reject(reason as usize);
    if let Some(more) = log.note(reason as usize, now) {
        let also = if more > 0 {
            format!(" (+{more} more since the last line)")
        } else {
            String::new()
        };
        eprintln!(
            "beliefbus-ingest: rejected sample ({}) channel {} seq {} dim {} t_meas {} ns{also}",
            reason.name(),
            s.channel,
            s.seq,
            s.dim,
            s.t_meas_ns
        );
    }
}

/// Run ingest until `stop`; returns its final stats.
pub fn run(
    mut ports: IngestPorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
) -> Result<StageStats, StageError> {
    // Long on purpose: the stage's loop — set-up, then the per-message
    // body handed to `run_loop` — reads top to bottom in the order a
    // message takes on the latency path, and its preallocated state lives in
    // this function's locals, borrowed by the loop body.
    let rt = cfg.stages.get(StageKind::Ingest);
    let mut m = Metrics::new(
        rt.budget_ns(),
        &[Hop::SensorToIngest],
        (cfg.run.warmup_s * 1e9) as u64,
    );
    let mut v = Validator::new(cfg)?;
    let channels = v.channel_ids();
    let window_ns = (cfg.ingest.reorder_window_ms * 1e6) as u64;
    let mut merge = ReorderBuffer::new(
        &channels,
        REORDER_CAPACITY,
        window_ns,
        (cfg.ingest.max_age_s * 1e9) as u64,
    );
    let mut log = RejectLog::new(Reason::ALL.len(), REJECT_LOG_PERIOD_NS);
    let mut o = Observation::default();
    let mut out_seq = 0u64;
    let mut err: Option<StageError> = None;
    ports.stats.publish(&m, clock.now_ns(), false)?;
    // Several channels: wake often enough to release held observations
    // when their window expires.
    let mut tick = Duration::from_secs_f64(cfg.run.stats_period_s.min(0.1));
    if channels.len() > 1 {
        tick = tick.min(Duration::from_nanos(window_ns / 2).max(Duration::from_millis(1)));
    }

    let sensor = &ports.sensor;
    let obs = &mut ports.obs;
    let stats = &mut ports.stats;
    run_loop(&[sensor], rt.wake_mode(), tick, stop, |w| {
        guarded(&mut err, || {
            if w == Wake::Data {
                while let Some((s, origin)) = sensor.receive_from()? {
                    let t_in = clock.now_ns();
                    m.budget.start();
                    let connected = |p| sensor.publisher_connected(p);
                    match v.check_from(&s, origin.publisher, &connected, t_in, &mut o) {
                        Ok(_) => {
                            o.trace.t_ingest_in_ns = t_in;
                            if merge.push(&o, t_in).is_err() {
                                reject(&mut m, &mut log, Reason::TooOld, &s, t_in);
                            }
                        }
                        Err(reason) => reject(&mut m, &mut log, reason, &s, t_in),
                    }
                    let lost = v.lost() - m.dropped_by_reason[DropReason::Lost as usize];
                    m.count_drop(DropReason::Lost, lost);
                    while let Some(mut r) = merge.pop_ready(clock.now_ns()) {
                        forward(&mut r, &mut out_seq, obs, &mut m, clock.now_ns())?;
                    }
                    // Released when the sensor published it (its measurement
                    // time when the publisher left the stamp 0): lateness
                    // then covers queueing in front of ingest too.
                    let release = if s.t_pub_ns != 0 {
                        s.t_pub_ns
                    } else {
                        s.t_meas_ns
                    };
                    m.budget.record_released(release, t_in, clock.now_ns());
                }
            }
            while let Some(mut r) = merge.pop_ready(clock.now_ns()) {
                forward(&mut r, &mut out_seq, obs, &mut m, clock.now_ns())?;
            }
            stats.tick(&m, clock.now_ns())?;
            Ok(())
        })
    })?;
    // Whatever is still held goes out before the final report (what cannot
    // be sent any more is counted, not lost silently).
    while let Some(mut r) = merge.pop_ready(u64::MAX) {
        if forward(&mut r, &mut out_seq, &mut ports.obs, &mut m, clock.now_ns()).is_err() {
            m.count_drop(DropReason::Shutdown, 1);
        }
    }
    let last = ports.stats.publish(&m, clock.now_ns(), true)?;
    match err {
        Some(e) if !stopped(stop) => Err(e),
        _ => Ok(last),
    }
}
