//! Refine: the anytime Markov-chain refinement stage. Until a backend needs a
//! chain (issue 4) it follows the belief stream — counting beliefs, and
//! beliefs superseded before it looked — and reports like every stage, so
//! the pipeline's process layout, priorities and shutdown are already those
//! of the final design. It runs at the lowest priority and never blocks the
//! filter (the belief channel is latest-value).

use super::{guarded, stopped, Metrics, SeqTracker, StageError, StageIdentity, StatsPort};
use crate::ipc::{run_loop, Belief, Bus, StageKind, StageStats, Subscriber, Wake};
use crate::pipeline::PipelineConfig;
use crate::rt::Clock;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

/// The ports of the refine stage.
pub struct RefinePorts {
    pub belief: Subscriber<Belief>,
    pub stats: StatsPort,
}

impl RefinePorts {
    /// Open them on `bus`.
    pub fn open(bus: &Bus, id: StageIdentity, cfg: &PipelineConfig) -> Result<Self, StageError> {
        Ok(Self {
            belief: bus.subscriber()?,
            stats: StatsPort::open(bus, id, cfg.run.stats_period_s)?,
        })
    }
}

/// Run refine until `stop`; returns its final stats.
pub fn run(
    mut ports: RefinePorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
) -> Result<StageStats, StageError> {
    let rt = cfg.stages.get(StageKind::Refine);
    let mut m = Metrics::new(rt.budget_ns(), &[], (cfg.run.warmup_s * 1e9) as u64);
    let mut seq = SeqTracker::default();
    let mut err = None;
    ports.stats.publish(&m, clock.now_ns(), false)?;
    let tick = Duration::from_secs_f64(cfg.refine.period_ms * 1e-3);
    let belief = &ports.belief;
    let stats = &mut ports.stats;
    run_loop(&[belief], rt.wake_mode(), tick, stop, |w| {
        guarded(&mut err, || {
            if w == Wake::Data {
                let t_in = clock.now_ns();
                let (latest, skipped) = belief.latest()?;
                if let Some(b) = latest {
                    m.dropped += skipped + seq.observe(b.header.seq);
                    m.processed += 1;
                    m.budget
                        .record_released(b.header.t_pub_ns, t_in, clock.now_ns());
                }
            }
            stats.tick(&m, clock.now_ns())?;
            Ok(())
        })
    })?;
    let last = ports.stats.publish(&m, clock.now_ns(), true)?;
    match err {
        Some(e) if !stopped(stop) => Err(e),
        _ => Ok(last),
    }
}
