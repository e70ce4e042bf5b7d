//! The refine stage in simulated time, for experiments that run the live
//! chain filter ([`LiveChainFilter`]) without processes: every
//! `refine.period_ms` of simulated time, refine grows the chain around the
//! filter's belief for `work` of wall-clock time; every
//! `refine.publish_period_ms` (and as soon as the first states exist) it
//! writes a snapshot and offers it to the filter, unless the filter is still
//! preparing the previous one (the filter stage finishes a version first).

use crate::chain::snapshot::words_needed;
use crate::filter::live_chain::LiveChainFilter;
use crate::model::SdeModel;
use crate::pipeline::PipelineConfig;
use crate::stage::refine::Refiner;
use anyhow::Result;
use std::time::Duration;

/// Refine interleaved with a live chain filter at a filter step of `dt`.
pub struct SimRefine {
    pub refiner: Refiner,
    period: usize,
    publish: usize,
    work: Duration,
    dt: f64,
    state_dim: usize,
    /// States added by refine so far.
    pub added: u64,
}

impl SimRefine {
    /// `work`: refine time per period (`None`: `refine.work_ms`).
    pub fn new(
        cfg: &PipelineConfig,
        dt: f64,
        state_dim: usize,
        work: Option<Duration>,
    ) -> Result<Self> {
        let steps = |ms: f64| (ms * 1e-3 / dt).round().max(1.0) as usize;
        Ok(Self {
            refiner: Refiner::new(cfg, 1)?,
            period: steps(cfg.refine.period_ms),
            publish: steps(cfg.refine.publish_period_ms),
            work: work.unwrap_or(Duration::from_secs_f64(cfg.refine.work_ms * 1e-3)),
            dt,
            state_dim,
            added: 0,
        })
    }

    /// Before filter step `k` (time k·dt), with `u` the control in force
    /// (as the refine stage reads it from the control channel): refine and
    /// offer a snapshot when due.
    pub fn tick<M: SdeModel>(
        &mut self,
        k: usize,
        u: &[f64],
        live: &mut LiveChainFilter<M, Vec<u64>>,
    ) -> Result<()> {
        if !k.is_multiple_of(self.period) {
            return Ok(());
        }
        let r = &mut self.refiner;
        r.set_belief_at(&live.belief(), k as f64 * self.dt);
        r.set_control(u);
        let fresh = r.is_empty();
        let due = fresh || k.is_multiple_of(self.publish);
        // Moving frame: a version is built when one is due (as the stage does).
        if !r.moving_frame() || (due && !live.has_pending()) {
            self.added += r.work(self.work)? as u64;
        }
        if due && !live.has_pending() {
            let mut buf = vec![0u64; r.snapshot_words().max(words_needed(self.state_dim, 0, 0))];
            r.write_snapshot(&mut buf, 0)?;
            live.offer(buf)?;
        }
        Ok(())
    }
}
