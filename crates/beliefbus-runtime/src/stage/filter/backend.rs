//! The filter a stage runs: a plain Bayes filter, or the chain filter on
//! live snapshots guarded by its stale-chain fallback ([`GuardedChain`]),
//! and the off-path work that takes and prepares new chain versions
//! ([`chain_work`]).

use super::*;

/// The filter of a stage: a plain backend, or the chain filter on live
/// snapshots with its stale-chain fallback.
pub enum Backend {
    Plain(Box<dyn BayesFilter>),
    Chain(Box<GuardedChain>),
}

/// The chain filter on live snapshots, and the Gaussian filter (EKF) that
/// runs beside it on every observation and is published while the chain is
/// stale ([`super::chain_guard`]; `filter.chain.stale.enabled = false`: the
/// chain alone).
///
/// Order within a step: the chain predicts and updates; the guard judges
/// it (age, degenerate update, the evidence average so far). Stale: the
/// fallback predicts and updates at once and its belief is published.
/// Healthy: the chain's belief is published first and the fallback's step
/// runs after it ([`Self::after_publish`], from the stored time, control
/// and measurement), so in the usual case the fallback adds nothing to the
/// sensor→belief latency.
pub struct GuardedChain {
    pub chain: LiveChainFilter<DynModel, SliceSample<u64>>,
    fallback: Option<Box<dyn BayesFilter>>,
    guard: StaleGuard,
    /// The belief of the last step comes from the fallback.
    on_fallback: bool,
    /// The chain's last predict succeeded (a refused prediction makes its
    /// step degenerate when the fallback predicted).
    chain_predicted: bool,
    /// The fallback's step not yet run: its time and control (predict), and
    /// the measurement (update) with the chain's log-likelihood of it.
    due: Option<DueStep>,
    /// Wall time of the fallback's predict + update in the last step, ns
    /// (its extra cost; recorded in the stage's `chain` stats).
    fallback_ns: u64,
}

/// A step of the fallback filter still to run (fixed-size copies: no
/// allocation per observation).
#[derive(Clone, Copy)]
struct DueStep {
    t: f64,
    u: [f64; MAX_CONTROL],
    predicted: bool,
    y: [f64; crate::MAX_OBS],
    mask: ObsMask,
    std: Option<[f64; crate::MAX_OBS]>,
    updated: bool,
    chain_ll: Option<f64>,
}

impl GuardedChain {
    pub(super) fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        let rc = self.chain.predict(t, u);
        self.chain_predicted = rc.is_ok();
        if self.fallback.is_none() {
            return rc;
        }
        let mut uu = [0.0; MAX_CONTROL];
        let n = u.len().min(MAX_CONTROL);
        uu[..n].copy_from_slice(&u[..n]);
        self.due = Some(DueStep {
            t,
            u: uu,
            predicted: false,
            y: [0.0; crate::MAX_OBS],
            mask: ObsMask(0),
            std: None,
            updated: false,
            chain_ll: None,
        });
        self.fallback_ns = 0;
        if rc.is_err() {
            // The fallback's prediction is needed now: publishing depends
            // on it.
            self.run_fallback_predict()?;
        }
        Ok(())
    }

    /// The fallback's pending prediction (if any).
    pub(super) fn run_fallback_predict(&mut self) -> Result<(), FilterError> {
        let (Some(f), Some(d)) = (self.fallback.as_mut(), self.due.as_mut()) else {
            return Ok(());
        };
        if d.predicted {
            return Ok(());
        }
        d.predicted = true;
        let t0 = Instant::now();
        let r = f.predict(d.t, &d.u[..f.dims().control]);
        self.fallback_ns += t0.elapsed().as_nanos() as u64;
        r
    }

    /// The fallback's pending update (after its prediction); scores the
    /// step for the guard. Returns the fallback's result (None: nothing
    /// was due).
    pub(super) fn run_fallback_update(
        &mut self,
    ) -> Option<Result<crate::filter::UpdateInfo, FilterError>> {
        let predicted = self.run_fallback_predict();
        let (f, d) = (self.fallback.as_mut()?, self.due.as_mut()?);
        if d.updated {
            return None;
        }
        d.updated = true;
        let obs = f.dims().obs;
        let r = predicted.and_then(|_| {
            let t0 = Instant::now();
            let r = f.update(&Measurement {
                y: &d.y[..obs],
                mask: d.mask,
                std: d.std.as_ref().map(|s| &s[..obs]),
            });
            self.fallback_ns += t0.elapsed().as_nanos() as u64;
            r
        });
        self.guard
            .score(d.chain_ll, r.as_ref().ok().map(|i| i.log_evidence));
        Some(r)
    }

    pub(super) fn update(
        &mut self,
        m: &Measurement,
        now_ns: u64,
    ) -> Result<crate::filter::UpdateInfo, FilterError> {
        let respreads = self.chain.respreads();
        let rc = if self.chain_predicted {
            self.chain.update(m)
        } else {
            Err(FilterError::Degenerate)
        };
        self.on_fallback = false;
        let Some(d) = self.due.as_mut() else {
            return rc;
        };
        let obs = m.y.len().min(crate::MAX_OBS);
        d.y[..obs].copy_from_slice(&m.y[..obs]);
        d.mask = m.mask;
        d.std = m.std.map(|s| {
            let mut a = [0.0; crate::MAX_OBS];
            let k = s.len().min(crate::MAX_OBS);
            a[..k].copy_from_slice(&s[..k]);
            a
        });
        d.chain_ll = rc.as_ref().ok().map(|i| i.log_evidence);
        let respread = self.chain.respreads() > respreads;
        if !self.guard.check(now_ns, rc.is_ok(), respread) {
            // Healthy: the fallback's step runs after the publish.
            return rc;
        }
        let rf = self.run_fallback_update().expect("due");
        if rf.is_err() && rc.is_ok() {
            // The fallback refused: the chain's is the only updated belief.
            return rc;
        }
        self.on_fallback = true;
        self.guard.published_fallback();
        rf
    }

    /// The fallback's step when it was not needed before the publish.
    pub(super) fn after_publish(&mut self) {
        let _ = self.run_fallback_update();
        self.due = None;
    }

    pub(super) fn belief(&self) -> Gaussian {
        match (&self.fallback, self.on_fallback) {
            (Some(f), true) => f.belief(),
            _ => self.chain.belief(),
        }
    }

    /// A version was installed at `now_ns`: end a stale episode by
    /// re-initialising the chain from the fallback, else tether the
    /// fallback to the chain unless the chain was doubtful (see
    /// [`super::chain_guard::Install`]).
    pub(super) fn installed(&mut self, now_ns: u64) {
        // Both filters at the same time first.
        self.after_publish();
        let Some(f) = self.fallback.as_mut() else {
            return;
        };
        let t = self.chain.time();
        match self.guard.installed(now_ns) {
            Install::Reinit => {
                let g = f.belief();
                if g.is_finite() {
                    self.chain.reset(t, &g);
                }
            }
            Install::Tether => {
                let g = self.chain.belief();
                if g.is_finite() && f.time() == t {
                    f.reset(t, &g);
                }
            }
            Install::Keep => {}
        }
    }

    /// Whether the last published belief came from the fallback.
    pub fn on_fallback(&self) -> bool {
        self.on_fallback
    }

    /// The guard's counts.
    pub fn counts(&self) -> crate::stage::chain_guard::GuardCounts {
        self.guard.counts()
    }

    /// The fallback's predict + update time in the last step (ns; None
    /// without a fallback).
    pub fn fallback_ns(&self) -> Option<u64> {
        self.fallback.as_ref().map(|_| self.fallback_ns)
    }
}

impl Backend {
    /// Build the configured backend at `t0` from `start` (the prior, or the
    /// belief a restarted stage resumes from).
    pub fn new(cfg: &PipelineConfig, start: &Gaussian, t0: f64) -> Result<Self, StageError> {
        let f = make_filter_from(cfg, start, t0)?;
        Ok(match cfg.filter.backend {
            FilterBackend::Chain => {
                let mut c = LiveChainFilter::new(cfg.model()?, f, cfg.refine.max_states, start, t0);
                c.set_reanchor(cfg.filter.chain.reanchor_ess);
                c.set_collapse_fraction(cfg.filter.chain.collapse_fraction);
                c.set_moving_frame(cfg.refine.moving_frame);
                if !cfg.refine.reference_control.is_empty() {
                    c.set_reference_control(&cfg.refine.reference_control)
                        .map_err(|e| StageError::Build {
                            what: "chain filter",
                            reason: e.to_string(),
                        })?;
                }
                let stale = &cfg.filter.chain.stale;
                // The fallback: the chain backend's Gaussian filter (EKF).
                let fallback = if stale.enabled {
                    Some(make_filter_from(cfg, start, t0)?)
                } else {
                    None
                };
                Backend::Chain(Box::new(GuardedChain {
                    chain: c,
                    fallback,
                    guard: StaleGuard::new(stale, cfg.refine.moving_frame),
                    on_fallback: false,
                    chain_predicted: true,
                    due: None,
                    fallback_ns: 0,
                }))
            }
            _ => Backend::Plain(f),
        })
    }
    pub(super) fn dims(&self) -> crate::model::Dims {
        match self {
            Backend::Plain(f) => f.dims(),
            Backend::Chain(f) => f.chain.dims(),
        }
    }
    pub(super) fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        match self {
            Backend::Plain(f) => f.predict(t, u),
            Backend::Chain(f) => f.predict(t, u),
        }
    }
    pub(super) fn update(
        &mut self,
        m: &Measurement,
        now_ns: u64,
    ) -> Result<crate::filter::UpdateInfo, FilterError> {
        match self {
            Backend::Plain(f) => f.update(m),
            Backend::Chain(f) => f.update(m, now_ns),
        }
    }
    pub(super) fn belief(&self) -> Gaussian {
        match self {
            Backend::Plain(f) => f.belief(),
            Backend::Chain(f) => f.belief(),
        }
    }
    /// Collapsed steps of the filter that publishes (the chain's, not its
    /// fallback's; None for a Gaussian filter).
    pub(super) fn ess_collapses(&self) -> Option<u64> {
        match self {
            Backend::Plain(f) => f.ess_collapses(),
            Backend::Chain(f) => Some(f.chain.collapses()),
        }
    }
}

/// Take the newest snapshot from `sub` (if any, and none is being
/// prepared) and prepare a pending one for at most `budget`; record swaps in
/// `m`. A version being prepared is finished before a newer one is taken
/// (the channel keeps the latest): replacing it would restart its
/// preparation, and a preparation longer than the publish period would
/// then never finish.
pub(super) fn chain_work(
    g: &mut GuardedChain,
    sub: &SliceSubscriber<u64>,
    budget: Duration,
    m: &mut Metrics,
    clock: &dyn Clock,
) -> Result<(), StageError> {
    let f = &mut g.chain;
    if f.has_pending() {
        // finish it first
    } else if let Some(s) = sub.receive_sample()? {
        if f.offer(s).is_err() {
            m.reject(Reason::Snapshot as usize);
        }
    }
    match f.advance(budget) {
        Ok(Some(info)) => {
            record_swap(m, &info);
            g.installed(clock.now_ns());
        }
        Ok(None) => {}
        Err(_) => m.reject(Reason::Snapshot as usize),
    }
    m.chain.guard = g.counts();
    Ok(())
}

fn record_swap(m: &mut Metrics, info: &SwapInfo) {
    let c = &mut m.chain;
    c.versions += 1;
    c.states = info.states as u64;
    c.delta_s = info.delta;
    c.swap.record(info.swap_ns.max(1));
    c.mass_lost_max = c.mass_lost_max.max(info.mass_lost);
}
