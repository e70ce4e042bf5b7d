//! The Markov-chain filter on live chain snapshots: the Bayes
//! recursion of thesis §3.3 (eq. 3.6) run directly on a snapshot that the
//! refine stage wrote into shared memory ([`crate::chain::snapshot`]),
//! while newer versions of the chain keep arriving.
//!
//! ```text
//! predict over Δ:  φ ← ((P^δ_u)ᵀ)^{⌊Δ/δ⌋} φ, then a fraction θ = frac(Δ/δ) of a step
//! update:          φ(z) ∝ p(y | z) φ(z),  p(y | z) = Π_{i∈mask} N(y_i; g_i(z), σ_i²)
//! estimate:        x̂ = Σ_z z φ(z),  P̂ = Σ_z (z − x̂)(z − x̂)ᵀ φ(z)
//! ```
//! P^δ is read in place from the snapshot (gather form: stay weights and
//! incoming edges), so propagation allocates and copies nothing.
//!
//! **New versions** ([`LiveChainFilter::offer`], [`LiveChainFilter::advance`]):
//! a received snapshot is *prepared* in chunks within a time budget per
//! call — its index structure is validated and the per-state observation
//! means g(z) of that version are computed into a second buffer — while the
//! filter keeps running on the active one. Then the swap, O(n_old + n_new):
//! 1. remap the belief by state id (ids are strictly increasing: one
//!    merge-join), as a density ρ = φ/vol so that states whose cells shrank
//!    (new neighbours) keep their density and not their mass;
//! 2. a new state gets the average density of its Near set (its transition
//!    row) over the states that existed — the thesis's `ApproximateDensity`
//!    (§3.5), applied as in [`super::chain_filter`];
//! 3. φ = ρ·vol, renormalised. The mass of retired states before
//!    renormalisation is reported (`mass_lost`).
//!
//! A snapshot of another lineage (refine restarted from scratch: ids not
//! comparable), the first snapshot, or a remap that leaves no mass, start
//! from the current Gaussian belief: φ(z) ∝ N(z; x̂, P̂)·vol(z). Until the
//! first snapshot arrives, the `fallback` filter (an EKF in the pipeline)
//! answers, so the filter never waits for refine; if refine stops, the
//! filter keeps its last snapshot, which stays mapped while it is held.
//!
//! **Controls.** The chain is built for u₀ = 0. Under u the prediction is
//! split (Lie) per chain step: the u₀ step above, then the control's
//! transport by v = f(x̂, u) − f(x̂, u₀) at the belief mean over the same
//! time, a jump process whose mean jump rate is exactly v for every u
//! (Kushner's local consistency of the drift term, built per signed axis:
//! see [`super::control_transport`] for the equations and why the previous
//! exponential tilt of the u₀ kernel was replaced). v at the belief mean is
//! exact for control-affine models with constant input matrix (the ship,
//! linear SDEs), first order otherwise.
//!
//! **Moving frame** ([`LiveChainFilter::set_moving_frame`], the default
//! scenario's mode): each version is a chain around the belief built for
//! f − w, and the belief's motion is a translation F of the frame,
//! dF/dt = f(x̂, u) − f(x̂ − F, u₀) + w, with no control transport. On a
//! fixed point set of spacing r a jump chain diffuses the ship's position
//! drift v at about |v|·r/2 (ten times the model's e² = 0.09 at |v| = 3,
//! r ≈ 0.6), which washes out the velocity information the positions
//! carry; in the frame only |v − w|·r/2 remains. Measured (experiment
//! chain-closed-loop drive=1, seeds 1–2): position RMSE 0.30 / 0.30 vs the
//! PF's 0.29 / 0.32, velocity 0.49 / 0.51 vs 0.48 / 0.55, NEES 4.9 / 4.8;
//! without the frame 0.45 / 0.54, velocity 1.9 / 1.8. F is integrated by
//! one Heun step per prediction (exact for the double integrator under a
//! held control, where Euler lost u·dt²/2 of position per step), and a
//! version is installed with F = x̂ − (mean of the installed mass), so the
//! belief mean does not jump at a swap. Tested against the exact Kalman
//! filter on a constant-velocity model (`live_chain_frame_tests.rs`).
//!
//! **Re-anchoring** (off unless [`LiveChainFilter::set_reanchor`]): a
//! posterior whose effective number of states falls below a threshold is
//! re-spread over the chain's local resolution, counted in
//! [`LiveChainFilter::reanchors`] (did not help in the closed loop).
//!
//! **Degenerate updates** (no state with mass explains the observation: the
//! belief left the chain's support) are recovered in the same call, never
//! refused: the mass is re-spread from the predicted Gaussian with its std
//! inflated ×2 and the update retried; if that fails too, the belief
//! restarts from the likelihood over the whole chain. Both are counted
//! ([`LiveChainFilter::respreads`]).
//!
//! Layout: [`prepare`] (offer, chunked preparation, swap), [`propagate`]
//! (prediction, the control's transport), [`update`] (Bayes update and its
//! recoveries), [`moving`] (the moving frame), [`mass`] (the likelihood and
//! Gaussian-install terms shared with the batch filter).

use std::cell::Cell;

use crate::belief::{Gaussian, WeightedMoments};
use crate::chain::snapshot::{HeldSnapshot, SnapshotView};
use crate::filter::control_transport::ControlTransport;
use crate::filter::{BayesFilter, FilterError, UpdateInfo};
use crate::model::{Dims, Measurement, SdeModel};
use crate::{MAX_CONTROL, MAX_STATE};

pub(crate) mod mass;
mod moving;
mod prepare;
mod propagate;
mod update;

pub use moving::frame_of;

/// Posterior mass flushed to zero after an update (see `chain_filter`).
const FLUSH: f64 = 1e-150;
/// ... and below this fraction of the largest posterior mass (≈ 7.4 σ out
/// for a Gaussian): the states outside the belief's support then cost
/// nothing in the update, the moments and the control's transport.
const FLUSH_REL: f64 = 1e-12;
/// The accumulated control displacement is transported once it makes the
/// fastest active state jump with this probability (see `transport_by`).
const TRANSPORT_MIN_JUMP: f64 = 1.0;
/// States prepared per chunk before the time budget is checked.
const CHUNK: usize = 256;
/// Covariance inflation (std factor) of a re-spread after a degenerate update.
const RESPREAD_INFLATE: f64 = 2.0;

/// What a swap did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SwapInfo {
    pub version: u64,
    pub states: usize,
    pub delta: f64,
    /// Belief mass on retired states, before renormalisation.
    pub mass_lost: f64,
    /// The belief was started from its Gaussian summary (first snapshot,
    /// new lineage, or nothing left after the remap).
    pub from_gaussian: bool,
    /// Duration of the swap itself (remap, new-state mass, renormalise).
    pub swap_ns: u64,
    /// Total preparation time of this version (validation, g(z)), spread
    /// over calls.
    pub prepare_ns: u64,
}

/// A version being prepared: the snapshot and how far its preparation got.
struct Pending<S> {
    snap: HeldSnapshot<S>,
    prog: Progress,
}

/// The preparation's progress (apart from the snapshot, so that a phase
/// reads the view and writes its counters).
struct Progress {
    /// Next state whose g(z) is computed (phase 1).
    next: usize,
    /// Next state whose control-transport rates are prepared (phase 2).
    next_tr: usize,
    /// Phase 2 started: indices mapped to the active version's.
    mapped: bool,
    /// The active version has the same lineage (its rates can be reused).
    reuse: bool,
    buf: usize,
    prepare_ns: u64,
    /// Moving frame: Σ f(z, u₀) and Σ z over the states (phase 1), the
    /// Cholesky factor of the belief covariance the installing weights are
    /// computed with (None: not positive definite) and their log maximum.
    frame_sums: ([f64; MAX_STATE], [f64; MAX_STATE]),
    chol: Option<[f64; MAX_STATE * MAX_STATE]>,
    lw_max: f64,
    /// Next state whose weight exp(lw − lw_max) is taken, their sum and
    /// Σ weight·z (the installed mass's mean, which the frame must match).
    next_exp: usize,
    w_sum: f64,
    wz_sum: [f64; MAX_STATE],
}

/// The version the filter runs on.
struct Active<S> {
    snap: HeldSnapshot<S>,
    buf: usize,
    lineage: u64,
}

/// The chain filter on live snapshots held as `S` (a shared-memory sample in
/// the pipeline, a `Vec<u64>` in tests).
pub struct LiveChainFilter<M: SdeModel, S: AsRef<[u64]>> {
    model: M,
    dims: Dims,
    max_states: usize,
    fallback: Box<dyn BayesFilter>,
    active: Option<Active<S>>,
    pending: Option<Pending<S>>,
    obs_mean: [Vec<f64>; 2],
    phi: Vec<f64>,
    tmp: Vec<f64>,
    aux: Vec<f64>,
    /// The control's transport rates per buffer (active, pending).
    transport: [ControlTransport; 2],
    /// Signed axes the control moves (`2i`, `2i + 1` for ±e_i): their rates
    /// are prepared with each version.
    ctrl_slots: Vec<usize>,
    /// Index maps between the active and the pending version (by id).
    o2n: Vec<u32>,
    n2o: Vec<u32>,
    /// Relative flush of the posterior (see [`FLUSH_REL`]).
    flush_rel: f64,
    /// Mean of the mass function (without the pending displacement) after
    /// the last update, when valid.
    mass_mean: Option<[f64; MAX_STATE]>,
    /// Control displacement accumulated but not yet transported (the mass
    /// is moved in pieces of about one jump length; see `predict`).
    pending_d: [f64; MAX_STATE],
    t: f64,
    last: Gaussian,
    belief: Cell<Option<Gaussian>>,
    versions: u64,
    respreads: u64,
    /// Re-anchor the posterior when its effective support (1/Σφ²) falls
    /// below this many states (0: never); see [`Self::reanchor`].
    reanchor_ess: f64,
    reanchors: u64,
    /// Updates that collapsed, and the fraction of effective support an
    /// update must keep not to (see `update`).
    collapses: u64,
    collapse_fraction: f64,
    /// Moving frame (see [`Self::set_moving_frame`]): the active version's
    /// frame drift w and the frame's displacement F (mass at z stands for
    /// the belief at z + F + pending_d).
    moving: bool,
    /// Moving frame: log-weights installing the belief on the pending
    /// version (phase 2 of its preparation).
    pre_w: Vec<f64>,
    frame_w: [f64; MAX_STATE],
    frame_d: [f64; MAX_STATE],
    /// The reference control u₀ every version is built for
    /// ([`Self::set_reference_control`]; 0 by default).
    u_ref: [f64; MAX_CONTROL],
}

impl<M: SdeModel, S: AsRef<[u64]>> LiveChainFilter<M, S> {
    /// A filter for `model` that answers with `fallback` (started from
    /// `prior` at `t0`) until the first snapshot is installed, and accepts
    /// snapshots of at most `max_states` states (buffers are sized here).
    pub fn new(
        model: M,
        mut fallback: Box<dyn BayesFilter>,
        max_states: usize,
        prior: &Gaussian,
        t0: f64,
    ) -> Self {
        let dims = model.dims();
        fallback.reset(t0, prior);
        let n = max_states.max(1);
        // The axes a unit control moves at the prior mean (the ship: the
        // velocities); for a control-affine model with constant B these are
        // the only axes v = f(x, u) − f(x, u₀) ever has.
        let u_ref = [0.0; MAX_CONTROL];
        let ctrl_slots = control_axes(&model, &prior.mean[..dims.state], &u_ref);
        Self {
            model,
            dims,
            max_states: n,
            fallback,
            active: None,
            pending: None,
            obs_mean: [
                Vec::with_capacity(n * dims.obs),
                Vec::with_capacity(n * dims.obs),
            ],
            phi: Vec::with_capacity(n),
            tmp: Vec::with_capacity(n),
            aux: Vec::with_capacity(n),
            transport: [
                ControlTransport::new(dims.state, n),
                ControlTransport::new(dims.state, n),
            ],
            ctrl_slots,
            o2n: vec![u32::MAX; n],
            n2o: vec![u32::MAX; n],
            mass_mean: None,
            flush_rel: FLUSH_REL,
            pending_d: [0.0; MAX_STATE],
            t: t0,
            last: *prior,
            belief: Cell::new(None),
            versions: 0,
            respreads: 0,
            reanchor_ess: 0.0,
            reanchors: 0,
            collapses: 0,
            collapse_fraction: crate::filter::regularise::DEFAULT_COLLAPSE_FRACTION,
            moving: false,
            pre_w: Vec::with_capacity(n),
            frame_w: [0.0; MAX_STATE],
            frame_d: [0.0; MAX_STATE],
            u_ref,
        }
    }

    /// Set the reference control u₀ the chain versions are built for (the
    /// `ChainConfig::control` of the construction: hover thrust, cruise
    /// speed). The control's transport, the moving frame and its drift w
    /// are then taken relative to f(·, u₀). Refuses a control of the wrong
    /// length or with non-finite entries.
    pub fn set_reference_control(&mut self, u0: &[f64]) -> Result<(), FilterError> {
        let nu = self.dims.control;
        if u0.len() != nu {
            return Err(FilterError::Dimension {
                what: "reference control",
                got: u0.len(),
                expected: nu,
            });
        }
        if u0.iter().any(|v| !v.is_finite()) {
            return Err(FilterError::NonFinite("reference control"));
        }
        self.u_ref[..nu].copy_from_slice(u0);
        self.ctrl_slots =
            control_axes(&self.model, &self.last.mean[..self.dims.state], &self.u_ref);
        Ok(())
    }

    /// The reference control u₀ of the chain versions.
    pub fn reference_control(&self) -> &[f64] {
        &self.u_ref[..self.dims.control]
    }

    /// Whether a version is being prepared.
    pub fn has_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// The belief right now (the fallback's before the first snapshot).
    fn belief_now(&self) -> Gaussian {
        match self.active.as_ref() {
            Some(act) => self.moments(&act.snap.view()),
            None => self.fallback.belief(),
        }
    }

    /// Versions installed so far.
    pub fn versions(&self) -> u64 {
        self.versions
    }
    /// Control-transport rate sets (built, not exact at the chain's border).
    pub fn transport_stats(&self) -> (u64, u64) {
        let [a, b] = &self.transport;
        (a.built + b.built, a.partial + b.partial)
    }
    /// Control-transport rate sets whose mean jump misses ±e_i by > 5 %.
    pub fn transport_off(&self) -> u64 {
        let [a, b] = &self.transport;
        a.off + b.off
    }

    /// Re-anchor the posterior when its effective number of states falls
    /// below `ess` (0 or less: never).
    pub fn set_reanchor(&mut self, ess: f64) {
        self.reanchor_ess = if ess.is_finite() { ess.max(0.0) } else { 0.0 };
    }
    /// Times the posterior was re-anchored (its support had collapsed).
    pub fn reanchors(&self) -> u64 {
        self.reanchors
    }
    /// Times the belief was re-spread after a degenerate update.
    pub fn respreads(&self) -> u64 {
        self.respreads
    }
    /// Updates that collapsed on the chain: re-spread or refused, or kept
    /// less than the collapse fraction of the predicted mass's effective
    /// support (see [`crate::filter::regularise`]).
    pub fn collapses(&self) -> u64 {
        self.collapses
    }
    /// The collapse fraction f (default 0.01; clamped to [0, 1]).
    pub fn set_collapse_fraction(&mut self, f: f64) {
        self.collapse_fraction = if f.is_finite() {
            f.clamp(0.0, 1.0)
        } else {
            0.0
        };
    }
    /// (version, states, δ) of the active snapshot.
    pub fn active_info(&self) -> Option<(u64, usize, f64)> {
        let v = self.active_view()?;
        Some((v.version, v.len(), v.delta))
    }
    /// Tuning for experiments: the relative posterior flush (default
    /// [`FLUSH_REL`]; 0 keeps every state above the absolute floor) and the
    /// control transport's two-hop candidates (default off).
    pub fn set_tuning(&mut self, flush_rel: f64, two_hop: bool) {
        self.flush_rel = flush_rel.max(0.0);
        for t in &mut self.transport {
            t.two_hop = two_hop;
        }
    }
    /// The active snapshot, read in place.
    pub fn active_view(&self) -> Option<SnapshotView<'_>> {
        Some(self.active.as_ref()?.snap.view())
    }
    /// The mass function on the active snapshot's states.
    pub fn masses(&self) -> &[f64] {
        &self.phi
    }

    /// Mean and covariance of the mass on `view` (the active version),
    /// moved by the displacement not yet transported and the moving
    /// frame's.
    fn moments(&self, view: &SnapshotView) -> Gaussian {
        let d = self.dims.state;
        let mut acc = WeightedMoments::new(&self.last.mean[..d]);
        for (i, &w) in self.phi.iter().enumerate() {
            if w != 0.0 {
                acc.add(w, view.state(i));
            }
        }
        let mut g = acc.gaussian();
        let sh = self.shift();
        for k in 0..d {
            g.mean[k] += sh[k];
        }
        g
    }

    /// Time of the belief.
    pub fn time(&self) -> f64 {
        self.t
    }

    /// Dimensions of the model.
    pub fn dims(&self) -> Dims {
        self.dims
    }

    /// Mean and covariance of the belief.
    pub fn belief(&self) -> Gaussian {
        if let Some(g) = self.belief.get() {
            return g;
        }
        let g = self.belief_now();
        self.belief.set(Some(g));
        g
    }
}

impl<M: SdeModel, S: AsRef<[u64]> + Send> BayesFilter for LiveChainFilter<M, S> {
    fn name(&self) -> &'static str {
        "chain"
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.t
    }
    fn reset(&mut self, t: f64, prior: &Gaussian) {
        LiveChainFilter::reset(self, t, prior)
    }
    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        LiveChainFilter::predict(self, t, u)
    }
    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        LiveChainFilter::update(self, meas)
    }
    fn belief(&self) -> Gaussian {
        LiveChainFilter::belief(self)
    }
    fn ess_collapses(&self) -> Option<u64> {
        Some(self.collapses)
    }
}

/// The signed axes (`2i`, `2i + 1` for ±e_i) a unit control moves at `x`
/// relative to the reference control `u0` (the ship: its velocities); for
/// a control-affine model with constant B these are the only axes
/// v = f(x, u) − f(x, u₀) ever has.
fn control_axes<M: SdeModel>(model: &M, x: &[f64], u0: &[f64; MAX_CONTROL]) -> Vec<usize> {
    let dims = model.dims();
    let (d, nu) = (dims.state, dims.control);
    let mut f0 = [0.0; MAX_STATE];
    let mut f1 = [0.0; MAX_STATE];
    let mut moved = [false; MAX_STATE];
    model.drift(x, &u0[..nu], &mut f0[..d]);
    for c in 0..nu {
        let mut u = *u0;
        u[c] += 1.0;
        model.drift(x, &u[..nu], &mut f1[..d]);
        for i in 0..d {
            moved[i] |= (f1[i] - f0[i]).abs() > 1e-12 || !(f1[i] - f0[i]).is_finite();
        }
    }
    (0..d)
        .filter(|&i| moved[i])
        .flat_map(|i| [2 * i, 2 * i + 1])
        .collect()
}

#[cfg(test)]
mod frame_tests;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod timing_tests;
