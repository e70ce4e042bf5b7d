//! The refine stage's loop: beliefs and controls in, bounded work rounds
//! (see the parent module's "Bounded rounds"), snapshots out.

use super::resume;
use super::RefinePorts;
use crate::config::PipelineConfig;
use crate::ipc::{run_loop, StageKind, StageStats, Wake};
use crate::rt::Clock;
use crate::stage::resume::Resume;
use crate::stage::{guarded, stopped, DropReason, Metrics, SeqTracker, StageError};
use crate::MAX_CONTROL;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

/// Run refine until `stop`; returns its final stats.
pub fn run(
    ports: RefinePorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
) -> Result<StageStats, StageError> {
    run_with(ports, cfg, clock, stop, &Resume::default())
}

/// [`run`] under a supervisor: checkpoints each published snapshot into the
/// run's state directory and, after a restart, resumes from the last one
/// (see [`resume`]).
pub fn run_with(
    mut ports: RefinePorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
    restart: &Resume,
) -> Result<StageStats, StageError> {
    // Long on purpose: the stage's loop — set-up, then the per-message
    // body handed to `run_loop` — reads top to bottom in the order a
    // message takes on the latency path, and its preallocated state lives in
    // this function's locals, borrowed by the loop body.
    let rt = cfg.stages.get(StageKind::Refine);
    let mut m = Metrics::new(rt.budget_ns(), &[], (cfg.run.warmup_s * 1e9) as u64);
    let mut seq = SeqTracker::default();
    let mut err = None;
    ports.stats.publish(&m, clock.now_ns(), false)?;
    // A lineage per chain: a restarted refine continues its checkpointed
    // chain (same lineage and ids), else starts a new id space.
    let active = cfg.filter.backend == crate::config::FilterBackend::Chain;
    // Inactive, it builds no chain (a discrete-time scenario has no SDE
    // model to build one from).
    let mut refiner = match active {
        true => Some(resume::start(cfg, clock, restart)?),
        false => None,
    };
    let mut ckpt = resume::Checkpointer::new(restart, ports.chain.max_len());
    let tick = Duration::from_secs_f64(cfg.refine.period_ms * 1e-3);
    let work = Duration::from_secs_f64(cfg.refine.work_ms * 1e-3);
    let publish_ns = (cfg.refine.publish_period_ms * 1e6) as u64;
    let period_ns = (cfg.refine.period_ms * 1e6) as u64;
    // The chain has one consumer, the filter's chain backend: with another
    // backend refine only follows the beliefs and reports, instead of
    // spending a core's worth of rounds (and cache and memory bandwidth the
    // real-time stages share) on a chain nobody reads.
    let mut next_work = if active { 0u64 } else { u64::MAX };
    let mut next_publish = 0u64;
    let moving = refiner.as_ref().is_some_and(|r| r.moving_frame());
    // A version written and checkpointed but not yet sent (words, version,
    // states, δ), its words, and what writing them took.
    let mut staged: Option<(usize, u64, usize, f64)> = None;
    let mut staged_buf: Vec<u64> = Vec::with_capacity(ports.chain.max_len());
    let mut stage_cost = Duration::ZERO;
    // Steady placement: the last version sent (its words stay in
    // staged_buf) is sent again as a new lineage every recenter_ms.
    let recentre_ns = (cfg.refine.recenter_ms * 1e6) as u64;
    let recentres = refiner.as_ref().is_some_and(|r| r.recentres());
    let mut sent_len = 0usize;
    let mut next_recentre = u64::MAX;
    let belief = &ports.belief;
    let control = &ports.control;
    let chain_pub = &mut ports.chain;
    let stats = &mut ports.stats;
    run_loop(&[belief], rt.wake_mode(), tick, stop, |w| {
        guarded(&mut err, || {
            if w == Wake::Data {
                let (latest, skipped) = belief.latest()?;
                if let Some(b) = latest {
                    m.count_drop(DropReason::Superseded, skipped);
                    m.count_drop(DropReason::Lost, seq.observe(b.header.seq));
                    m.processed += 1;
                    if let Some(r) = refiner.as_mut() {
                        r.set_belief_at(&b.gaussian(), b.header.t_valid_ns as f64 * 1e-9);
                    }
                }
                if let (Some(c), _) = control.latest()? {
                    let n = (c.dim as usize).min(MAX_CONTROL);
                    if let Some(r) = refiner.as_mut() {
                        r.set_control(&c.u[..n]);
                    }
                }
            }
            let Some(refiner) = refiner.as_mut() else {
                stats.tick(&m, clock.now_ns())?;
                return Ok(());
            };
            let now = clock.now_ns();
            // Moving frame: a version is started when one is due, from the
            // latest belief, continued every round until it is complete,
            // and staged in the round that completes it; a staged version
            // is sent in the first round that finds its checkpoint durable.
            let due = !moving
                || refiner.is_empty()
                || refiner.building()
                || refiner.version_ready()
                || staged.is_some()
                || now >= next_publish
                || (recentres && now >= next_recentre);
            if now >= next_work && due {
                next_work = now + period_ns;
                let t_in = clock.now_ns();
                m.budget.start();
                // The round lasts `work`: the last staging's cost (P^δ,
                // snapshot) is kept free at its end (at most half the
                // round), so a round that completes a version still ends
                // in time.
                let slice = work.saturating_sub(stage_cost.min(work / 2));
                let complete = if moving {
                    let start = !refiner.building()
                        && !refiner.version_ready()
                        && (refiner.is_empty() || t_in >= next_publish);
                    if start {
                        next_publish = t_in + publish_ns;
                    }
                    let end = t_in + slice.as_nanos() as u64;
                    refiner.version_ready()
                        || ((start || refiner.building())
                            && refiner.work_until(|| clock.now_ns() < end)?)
                } else {
                    // The first chain in slices, sent as soon as it is
                    // complete; then growth for `slice` per round.
                    let first = refiner.is_empty();
                    let fresh = if first {
                        let end = t_in + slice.as_nanos() as u64;
                        refiner.work_until(|| clock.now_ns() < end)?
                    } else {
                        refiner.work(slice)?;
                        false
                    };
                    let now = clock.now_ns();
                    let due = fresh || (!first && now >= next_publish);
                    if due {
                        next_publish = now + publish_ns;
                    }
                    due
                };
                if complete && staged.is_none() {
                    let t_pub = clock.now_ns();
                    let len = refiner.snapshot_words();
                    if len > chain_pub.max_len() {
                        return Err(StageError::Build {
                            what: "chain snapshot",
                            reason: format!(
                                "{len} words exceed the channel's {}",
                                chain_pub.max_len()
                            ),
                        });
                    }
                    // Capacity max_len from the start: no reallocation.
                    staged_buf.resize(len, 0);
                    let n = refiner.write_snapshot(&mut staged_buf, t_pub)?;
                    // Checkpoint before sending: no version is seen that a
                    // restart could publish again.
                    ckpt.begin(refiner.next_id(), &staged_buf[..n]);
                    staged = Some((n, refiner.version(), refiner.len(), refiner.delta()));
                    stage_cost = Duration::from_nanos(clock.now_ns().saturating_sub(t_pub));
                }
                if !complete && staged.is_none() && recentres && sent_len > 0 {
                    let t_pub = clock.now_ns();
                    if t_pub >= next_recentre {
                        refiner.recentre(&mut staged_buf[..sent_len], t_pub)?;
                        ckpt.begin(refiner.next_id(), &staged_buf[..sent_len]);
                        staged =
                            Some((sent_len, refiner.version(), refiner.len(), refiner.delta()));
                    }
                }
                if let Some((n, version, states, delta)) = staged {
                    if ckpt.is_durable() {
                        chain_pub.publish_with(n, |buf| {
                            buf[..n].copy_from_slice(&staged_buf[..n]);
                            Ok::<_, StageError>(n)
                        })??;
                        staged = None;
                        sent_len = n;
                        next_recentre = clock.now_ns().saturating_add(recentre_ns);
                        m.chain.versions = version;
                        m.chain.states = states as u64;
                        m.chain.delta_s = delta;
                        m.chain.rows = refiner.rows;
                        m.chain.recentred = refiner.recentred;
                    }
                }
                // The whole round counts against the budget: building,
                // staging and sending.
                m.budget.record(t_in, clock.now_ns());
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
