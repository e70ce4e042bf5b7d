//! Refine: the anytime Markov-chain refinement stage. It grows a
//! bounded chain around the latest belief and publishes versioned snapshots
//! of it, written in place on the `chain` slice channel, for the filter's
//! chain backend.
//!
//! Each round (every `refine.period_ms`, for at most `refine.work_ms`):
//! 1. First rounds: a batch chain (thesis Alg. 2.1) of `initial_states`
//!    around the prior, built in slices and published as soon as it is
//!    complete (a crude chain quickly).
//! 2. Incremental construction (Alg. 2.3: add z, ConnectState(z), reconnect
//!    Near(z)) with new states drawn around the latest belief: N(m(τ),
//!    (inflate·σ)²) with m(τ) the belief mean carried by the uncontrolled
//!    drift for τ ~ U[0, horizon_s] (the belief moves; the chain must be
//!    there before it; the drift under the latest control once refine has
//!    read one from the control channel), σ floored at `min_std_fraction`
//!    of the bounds, mixed with `uniform_fraction` uniform draws
//!    (exploration).
//! 3. Exponential backup (§3.3.2): after each insertion δ is halved until it
//!    is below the holding time of every (re)connected state
//!    ([`TimeEqualized::backup`]).
//! 4. Bounded size: above `max_states`, the `retire_fraction` of states
//!    farthest from the belief's predicted path over `horizon_s`
//!    (Mahalanobis distance under the inflated belief covariance to the
//!    nearest of 5 points on it — far states carry negligible belief mass,
//!    and the states it left behind go first) are retired and their
//!    neighbours reconnected ([`crate::chain::retire`]); δ is refitted to
//!    the remaining holding times (it may grow back).
//! 5. Every `publish_period_ms`: P^δ is built ([`PropagationKernel`]) and
//!    the snapshot written in place ([`crate::chain::snapshot::write`]).
//!
//! **Moving frame** (`refine.moving_frame`, the default scenario's mode):
//! instead of one incremental chain, every version is a batch chain
//! (Alg. 2.1) of `max_states` states drawn around the latest belief and
//! built for f(x, u₀) − w, w the mean uncontrolled drift of its states: the
//! chain carries the belief's shape and the filter carries its motion as a
//! translation of the frame (see
//! [`crate::filter::live_chain::LiveChainFilter::set_moving_frame`] for
//! why: a fixed point set diffuses the ship's position drift numerically).
//! A version is started when one is due, from the latest belief, and is a
//! lineage of its own. Steps 2–4 above then do not apply.
//!
//! **Bounded rounds** (anytime): a round never runs past `refine.work_ms`.
//! A moving-frame version (2000 states: about 40 ms of one core) is built
//! in slices ([`crate::chain::frame::FrameJob`]: per-state caches, k-d
//! tree, order, one row at a time, the clock read between units), continued
//! every `period_ms`, and published in the round that completes it; the
//! last publication's cost (P^δ, snapshot, checkpoint) is kept free at the
//! end of every round, so that round ends in time too. The compute time
//! recorded against the stage's budget is the whole round, building and
//! publishing.
//!
//! The snapshot service keeps history 1 and buffer 1 (latest value) and
//! lets a subscriber hold 2 snapshots (the filter's active and pending
//! ones), so the number of live snapshots in shared memory is fixed by the
//! port settings. The stage runs at the lowest priority and never blocks
//! the filter: the belief channel is latest-value and a slow filter only
//! misses intermediate versions.
//!
//! With a filter backend other than `chain` nobody reads the chain: refine
//! then only follows the beliefs and reports (no rounds, no snapshots).

use super::snapshots::{chain_config, chain_qos, CHAIN_CHANNEL};
use super::{StageError, StageIdentity, StatsPort};
use crate::belief::Gaussian;
use crate::chain::frame::{sampler_around, FrameBuild, FrameJob};
use crate::chain::snapshot::{self, SnapshotMeta};
use crate::chain::{BatchBuild, Chain, PropagationKernel, Sampler, TimeEqualized};
use crate::config::PipelineConfig;
use crate::ipc::{Belief, Bus, Control, SlicePublisher, Subscriber};
use crate::model::SdeModel;
use crate::rng::SimRng;
use crate::scenario::DynModel;
use crate::{MAX_CONTROL, MAX_STATE};
use rand::RngExt;
use std::time::{Duration, Instant};

#[path = "refine_resume.rs"]
pub mod resume;

#[path = "refine_placement.rs"]
pub mod placement;

/// Points on the belief's predicted path that retirement measures from.
const PATH_POINTS: usize = 4;

/// The ports of the refine stage.
pub struct RefinePorts {
    pub belief: Subscriber<Belief>,
    /// Latest control (no wake-up: read with each belief).
    pub control: Subscriber<Control>,
    pub chain: SlicePublisher<u64>,
    pub stats: StatsPort,
}

impl RefinePorts {
    /// Open them on `bus`.
    pub fn open(bus: &Bus, id: StageIdentity, cfg: &PipelineConfig) -> Result<Self, StageError> {
        let dim = cfg.dims()?.state;
        Ok(Self {
            belief: bus.subscriber()?,
            control: bus.subscriber_with(1, false)?,
            chain: bus.slice_publisher(CHAIN_CHANNEL, &chain_qos(cfg, dim))?,
            stats: StatsPort::open(bus, id, cfg.run.stats_period_s)?,
        })
    }
}

/// The anytime chain builder (the stage's state, usable without ports).
pub struct Refiner {
    model: DynModel,
    cfg: PipelineConfig,
    chain: Option<Chain>,
    eq: TimeEqualized,
    kern: PropagationKernel,
    vol: Vec<f64>,
    belief: Gaussian,
    rng: SimRng,
    lineage: u64,
    version: u64,
    /// Moving frame: the version under construction, and whether a
    /// completed one awaits publication.
    job: Option<FrameJob>,
    ready: bool,
    /// Incremental chain: the first (batch) chain under construction.
    first: Option<BatchBuild>,
    touched: Vec<u32>,
    rec: Vec<u32>,
    /// Drift of the belief mean that f(m, u₀) does not explain (the
    /// control, mostly), estimated from beliefs ≥ 0.1 s apart, and the
    /// last such belief (mean, time).
    drive: [f64; MAX_STATE],
    anchor: Option<([f64; MAX_STATE], f64)>,
    /// The latest control, once one is known: the belief is then carried
    /// ahead by f(m, u) instead of f(m, u₀) + drive.
    control: Option<[f64; MAX_CONTROL]>,
    /// Moving-frame chains built (each its own lineage).
    pub frames: u64,
    /// Insertions rejected by the chain (e.g. duplicate coordinates).
    pub failed_inserts: u64,
    /// Row diagnostics summed over the moving-frame versions built.
    pub rows: placement::RowCounts,
    /// Steady placement: versions published again as new lineages, and
    /// versions drawn around the belief because P∞ could not be solved.
    pub recentred: u64,
    pub steady_failures: u64,
    /// States retired so far.
    pub retired: u64,
}

impl Refiner {
    /// A builder for `cfg`'s model, starting from the filter's prior;
    /// `lineage` identifies this chain's id space.
    pub fn new(cfg: &PipelineConfig, lineage: u64) -> Result<Self, StageError> {
        let model = cfg.model()?;
        let eq = TimeEqualized::new(cfg.sample_dt()).map_err(|e| StageError::Build {
            what: "chain",
            reason: e.to_string(),
        })?;
        Ok(Self {
            model,
            cfg: cfg.clone(),
            chain: None,
            eq,
            kern: PropagationKernel::default(),
            vol: Vec::new(),
            belief: cfg.prior(),
            rng: crate::rng::stream(cfg.run.seed, 0x5eed_c4a1),
            lineage,
            version: 0,
            job: None,
            ready: false,
            first: None,
            touched: Vec::new(),
            rec: Vec::new(),
            drive: [0.0; MAX_STATE],
            anchor: None,
            control: None,
            frames: 0,
            failed_inserts: 0,
            rows: placement::RowCounts::default(),
            recentred: 0,
            steady_failures: 0,
            retired: 0,
        })
    }

    /// Follow a new belief (ignored unless finite and of the model's size).
    pub fn set_belief(&mut self, g: &Gaussian) {
        if g.dim == self.belief.dim && g.is_finite() {
            self.belief = *g;
        }
    }

    /// [`Self::set_belief`] for a belief valid at `t` seconds: also
    /// estimates where the belief is going (the mean's drift that the
    /// uncontrolled model does not explain, i.e. the control's effect),
    /// which [`Self::draw`] adds when it carries the mean ahead.
    pub fn set_belief_at(&mut self, g: &Gaussian, t: f64) {
        if !(g.dim == self.belief.dim && g.is_finite() && t.is_finite()) {
            return;
        }
        self.belief = *g;
        let d = g.dim;
        match self.anchor {
            Some((m0, t0)) if t - t0 >= 0.1 => {
                let nu = self.model.dims().control;
                let mut mid = [0.0; MAX_STATE];
                for i in 0..d {
                    mid[i] = 0.5 * (m0[i] + g.mean[i]);
                }
                let mut f = [0.0; MAX_STATE];
                let u0 = self.reference_control();
                self.model.drift(&mid[..d], &u0[..nu], &mut f[..d]);
                for i in 0..d {
                    let c = (g.mean[i] - m0[i]) / (t - t0) - f[i];
                    if c.is_finite() {
                        // Smoothed: the belief mean jitters with every update.
                        self.drive[i] = 0.5 * self.drive[i] + 0.5 * c;
                    }
                }
                self.anchor = Some((g.mean, t));
            }
            Some((_, t0)) if t >= t0 => {}
            _ => self.anchor = Some((g.mean, t)),
        }
    }

    /// The reference control u₀ the chains are built for
    /// (`refine.reference_control`, 0 when empty).
    fn reference_control(&self) -> [f64; MAX_CONTROL] {
        chain_config(&self.cfg, self.belief.dim).control
    }

    /// Follow the latest control (ignored unless finite and of the
    /// model's size): new states are placed where the belief goes under it.
    pub fn set_control(&mut self, u: &[f64]) {
        let nu = self.model.dims().control;
        if u.len() == nu && u.iter().all(|v| v.is_finite()) {
            let mut c = [0.0; MAX_CONTROL];
            c[..nu].copy_from_slice(u);
            self.control = Some(c);
        }
    }

    /// Current chain size.
    pub fn len(&self) -> usize {
        self.chain.as_ref().map_or(0, |c| c.len())
    }
    /// Whether there is no chain yet.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Current δ.
    pub fn delta(&self) -> f64 {
        self.eq.delta()
    }
    /// Versions published.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// The sampling distribution around the belief (σ floored).
    fn sampler_at(&self, mean: &[f64]) -> Option<Sampler> {
        sampler_around(&self.model, &self.belief, mean, &self.frame_build())
    }

    /// The moving-frame construction parameters of this config.
    fn frame_build(&self) -> FrameBuild {
        FrameBuild {
            inflate: self.cfg.refine.inflate,
            uniform_fraction: self.cfg.refine.uniform_fraction,
            min_std_fraction: self.cfg.refine.min_std_fraction,
            chain: chain_config(&self.cfg, self.belief.dim),
            dt: self.cfg.sample_dt(),
        }
    }

    /// The belief mean carried `tau` seconds ahead by the uncontrolled
    /// drift plus the estimated drive (where the belief is going under the
    /// current control), projected into the bounds.
    fn carry(&self, tau: f64) -> [f64; MAX_STATE] {
        let d = self.belief.dim;
        let mut m = [0.0; MAX_STATE];
        m[..d].copy_from_slice(self.belief.mean());
        let steps = (tau / 0.01).ceil() as usize;
        let nu = self.model.dims().control;
        let (u, drive) = match self.control {
            Some(u) => (u, [0.0; MAX_STATE]),
            None => (self.reference_control(), self.drive),
        };
        let mut f = [0.0; MAX_STATE];
        for _ in 0..steps {
            self.model.drift(&m[..d], &u[..nu], &mut f[..d]);
            for i in 0..d {
                m[i] += (f[i] + drive[i]) * tau / steps as f64;
            }
        }
        self.model.bounds().project(&mut m[..d]);
        m
    }

    /// A new state: around the belief mean carried τ ~ U[0, horizon] ahead
    /// ([`Self::carry`]).
    fn draw(&mut self, x: &mut [f64]) {
        let d = self.belief.dim;
        let h = self.cfg.refine.horizon_s;
        let tau = if h > 0.0 {
            self.rng.random::<f64>() * h
        } else {
            0.0
        };
        let m = self.carry(tau);
        match self.sampler_at(&m[..d]) {
            Some(s) => s.sample(self.model.bounds(), &mut self.rng, x),
            None => Sampler::Uniform.sample(self.model.bounds(), &mut self.rng, x),
        }
    }

    /// A moving-frame version: a batch chain of `max_states` states
    /// (`initial_states` for the first) drawn
    /// around the belief (N(m, (inflate·σ)²), σ floored, mixed with
    /// uniform draws), built for f(x, u₀) − w with w the mean uncontrolled
    /// drift of its states — the filter computes the same w from the
    /// snapshot ([`crate::filter::live_chain::frame_of`]) and carries the
    /// belief's motion as a translation of the frame
    /// ([`crate::filter::live_chain::LiveChainFilter::set_moving_frame`]),
    /// so the states need not be placed ahead of it. Each version is a
    /// lineage of its own.
    fn build_framed(&mut self) -> Result<usize, StageError> {
        self.job = None;
        self.work_until(|| true)?;
        Ok(self.len())
    }

    /// Moving frame, in slices: continue the version under construction
    /// (starting one from the latest belief if there is none) while
    /// `more()` says so — at least one unit of work per call, a unit being
    /// one state's caches, the k-d tree, the order or one row (see
    /// [`crate::chain::BatchBuild`]). Returns whether a version was
    /// completed; it then replaces the chain and awaits
    /// [`Self::write_snapshot`] ([`Self::version_ready`]).
    ///
    /// Incremental chain (`moving_frame = false`): builds the first chain
    /// the same way (then returns true once it is complete) and does
    /// nothing once there is one ([`Self::work`] grows it).
    pub fn work_until(&mut self, more: impl FnMut() -> bool) -> Result<bool, StageError> {
        if !self.cfg.refine.moving_frame {
            return match self.chain {
                None => self.first_until(more),
                Some(_) => Ok(false),
            };
        }
        let build = |e: crate::chain::ChainError| StageError::Build {
            what: "chain",
            reason: e.to_string(),
        };
        let job = match self.job.take() {
            Some(j) => j,
            None => {
                // The first version is a crude chain of `initial_states`.
                let n = if self.chain.is_none() {
                    self.cfg.refine.initial_states
                } else {
                    self.cfg.refine.max_states
                };
                let around = self.placement_belief();
                FrameJob::start(&self.model, &around, n, &self.frame_build(), &mut self.rng)
                    .map_err(build)?
            }
        };
        let mut job = job;
        if !job.run(&self.model, more).map_err(build)? {
            self.job = Some(job);
            return Ok(false);
        }
        let (c, eq) = job.finish().map_err(build)?;
        self.eq = eq;
        self.rows.add(&c);
        self.chain = Some(c);
        self.frames += 1;
        self.ready = true;
        Ok(true)
    }

    /// The incremental chain's first chain: a batch chain of
    /// `initial_states` around the prior, continued while `more()` says so;
    /// returns whether it is complete.
    fn first_until(&mut self, more: impl FnMut() -> bool) -> Result<bool, StageError> {
        let d = self.belief.dim;
        let build = |e: crate::chain::ChainError| StageError::Build {
            what: "chain",
            reason: e.to_string(),
        };
        let mut b = match self.first.take() {
            Some(b) => b,
            None => {
                let n = self.cfg.refine.initial_states;
                let mut pts = vec![0.0; n * d];
                for p in pts.chunks_exact_mut(d) {
                    self.draw(p);
                }
                BatchBuild::new(&self.model, chain_config(&self.cfg, d), pts).map_err(build)?
            }
        };
        if !b.run(&self.model, more).map_err(build)? {
            self.first = Some(b);
            return Ok(false);
        }
        let c = b.finish().map_err(build)?;
        self.eq.fit(c.holding());
        self.chain = Some(c);
        Ok(true)
    }

    /// Whether a moving-frame version is under construction.
    pub fn building(&self) -> bool {
        self.job.is_some()
    }

    /// Whether a completed moving-frame version awaits publication.
    pub fn version_ready(&self) -> bool {
        self.ready
    }

    /// Whether versions are moving-frame batch chains (`refine.moving_frame`):
    /// then [`Self::work`] builds one per call, to be called when a
    /// version is due.
    pub fn moving_frame(&self) -> bool {
        self.cfg.refine.moving_frame
    }

    /// One round of work for at most `budget`; returns states added.
    pub fn work(&mut self, budget: Duration) -> Result<usize, StageError> {
        if self.cfg.refine.moving_frame {
            return self.build_framed();
        }
        let t0 = Instant::now();
        let d = self.belief.dim;
        let build = |e: &dyn std::fmt::Display| StageError::Build {
            what: "chain",
            reason: e.to_string(),
        };
        if self.chain.is_none() {
            self.first_until(|| true)?;
            return Ok(self.len());
        }
        let mut added = 0;
        let mut x = [0.0; MAX_STATE];
        while t0.elapsed() < budget {
            self.draw(&mut x[..d]);
            let chain = self.chain.as_mut().expect("built");
            match chain.add_state(&self.model, &x[..d], &mut self.rec) {
                Ok(_) => {
                    self.eq.backup(chain.holding(), &self.rec);
                    added += 1;
                }
                Err(_) => self.failed_inserts += 1,
            }
            if chain.len() > self.cfg.refine.max_states {
                self.retire().map_err(|e| build(&e))?;
            }
        }
        Ok(added)
    }

    /// Retire the states farthest from the belief (see the module doc).
    fn retire(&mut self) -> Result<(), crate::chain::ChainError> {
        let chain = self.chain.as_ref().expect("built");
        let n = chain.len();
        let target = ((self.cfg.refine.max_states as f64) * (1.0 - self.cfg.refine.retire_fraction))
            as usize;
        let d = chain.dim();
        let infl = self.cfg.refine.inflate;
        let mut l = [0.0; MAX_STATE * MAX_STATE];
        for (c, v) in l[..d * d].iter_mut().zip(self.belief.cov()) {
            *c = v * infl * infl;
        }
        let b = self.model.bounds();
        for i in 0..d {
            let floor = self.cfg.refine.min_std_fraction * (b.hi()[i] - b.lo()[i]) * infl;
            if l[i + i * d] < floor * floor {
                l[i + i * d] = floor * floor;
            }
        }
        let ok = crate::chain::linalg::cholesky(&mut l[..d * d], d);
        // Distance to the belief's path over the next horizon (where new
        // states are drawn): the states it has left behind go first.
        let h = self.cfg.refine.horizon_s;
        let path: Vec<[f64; MAX_STATE]> = (0..=PATH_POINTS)
            .map(|j| self.carry(h * j as f64 / PATH_POINTS as f64))
            .collect();
        let chain = self.chain.as_mut().expect("built");
        let mut dist: Vec<(f64, u32)> = (0..n)
            .map(|i| {
                let z = chain.state(i);
                let mut best = f64::INFINITY;
                for m in &path {
                    let mut y = [0.0; MAX_STATE];
                    for a in 0..d {
                        y[a] = z[a] - m[a];
                    }
                    if ok {
                        crate::chain::linalg::forward_sub(&l[..d * d], d, &mut y[..d]);
                    }
                    best = best.min(y[..d].iter().map(|v| v * v).sum());
                }
                (best, i as u32)
            })
            .collect();
        dist.select_nth_unstable_by(target, |a, b| a.0.total_cmp(&b.0));
        let mut keep = vec![false; n];
        for &(_, i) in &dist[..target] {
            keep[i as usize] = true;
        }
        let reduced = crate::chain::retire::retire(&self.model, chain, &keep, &mut self.touched)?;
        self.retired += (n - reduced.len()) as u64;
        self.eq.fit(reduced.holding());
        self.chain = Some(reduced);
        Ok(())
    }

    /// Write the current chain as the next version into `out` (in place);
    /// returns the words written.
    pub fn write_snapshot(&mut self, out: &mut [u64], t_pub_ns: u64) -> Result<usize, StageError> {
        let Some(chain) = self.chain.as_mut() else {
            return Ok(0);
        };
        self.ready = false;
        snapshot::cell_volumes(chain, &mut self.vol);
        let view = chain.view();
        self.kern.rebuild(&view, self.eq.delta(), false);
        self.version += 1;
        // A moving-frame version is a lineage of its own (a new id space
        // and frame: the filter installs it from the Gaussian belief).
        let lineage = if self.cfg.refine.moving_frame {
            self.lineage ^ self.frames.rotate_left(40)
        } else {
            self.lineage
        };
        let meta = SnapshotMeta {
            version: self.version,
            lineage,
            t_pub_ns,
        };
        snapshot::write(out, meta, &view, &self.vol, &self.kern).map_err(|e| StageError::Build {
            what: "chain snapshot",
            reason: e.to_string(),
        })
    }

    /// Words the next snapshot needs.
    pub fn snapshot_words(&mut self) -> usize {
        match self.chain.as_mut() {
            Some(c) => {
                c.compact();
                let v = c.compact_view().expect("compact");
                snapshot::words_needed(v.dim, v.len(), v.nnz())
            }
            None => 0,
        }
    }
}

#[path = "refine_run.rs"]
mod stage_loop;
pub use stage_loop::{run, run_with};

#[cfg(test)]
#[path = "refine_tests.rs"]
mod tests;
