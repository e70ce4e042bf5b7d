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

use std::cell::Cell;
use std::time::{Duration, Instant};

use crate::belief::{Gaussian, WeightedMoments};
use crate::chain::linalg::{cholesky, forward_sub};
use crate::chain::snapshot::{SnapshotError, SnapshotView};
use crate::filter::control_transport::ControlTransport;
use crate::filter::{check_measurement, check_predict, BayesFilter, FilterError, UpdateInfo};
use crate::model::{Dims, Measurement, SdeModel};
use crate::{MAX_CONTROL, MAX_OBS, MAX_STATE};

const HALF_LOG_2PI: f64 = 0.918_938_533_204_672_8;
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

/// The measurement's components and inverse variances.
struct Lik {
    idx: [usize; MAX_OBS],
    inv_var: [f64; MAX_OBS],
    nm: usize,
}

struct Pending<S> {
    snap: S,
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

struct Active<S> {
    snap: S,
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
    /// Moving frame (see [`Self::set_moving_frame`]): the active version's
    /// frame drift w and the frame's displacement F (mass at z stands for
    /// the belief at z + F + pending_d).
    moving: bool,
    /// Moving frame: log-weights installing the belief on the pending
    /// version (phase 2 of its preparation).
    pre_w: Vec<f64>,
    frame_w: [f64; MAX_STATE],
    frame_d: [f64; MAX_STATE],
}

/// The moving frame of a chain version: the mean uncontrolled drift w of
/// its states and their mean c. A moving-frame chain is built for
/// f(x, u₀) − w (see `stage::refine`), and refine computes the same w from
/// the same states.
pub fn frame_of<M: SdeModel + ?Sized>(
    model: &M,
    view: &SnapshotView,
) -> ([f64; MAX_STATE], [f64; MAX_STATE]) {
    let d = view.dim;
    let nu = model.dims().control;
    let u = [0.0; MAX_CONTROL];
    let (mut w, mut c) = ([0.0; MAX_STATE], [0.0; MAX_STATE]);
    let mut f = [0.0; MAX_STATE];
    let n = view.len();
    for i in 0..n {
        let z = view.state(i);
        model.drift(z, &u[..nu], &mut f[..d]);
        for a in 0..d {
            w[a] += f[a];
            c[a] += z[a];
        }
    }
    for a in 0..d {
        w[a] /= n.max(1) as f64;
        c[a] /= n.max(1) as f64;
    }
    (w, c)
}

fn gaussian_weights(view: &SnapshotView, g: &Gaussian, out: &mut [f64]) {
    let d = view.dim;
    let n = view.len();
    let mut l = [0.0; MAX_STATE * MAX_STATE];
    l[..d * d].copy_from_slice(g.cov());
    if !cholesky(&mut l[..d * d], d) {
        // Singular: all mass on the nearest state.
        let mut best = (f64::INFINITY, 0);
        for i in 0..n {
            let q: f64 = (0..d).map(|a| (view.state(i)[a] - g.mean[a]).powi(2)).sum();
            if q < best.0 {
                best = (q, i);
            }
        }
        out[..n].fill(0.0);
        out[best.1] = 1.0;
        return;
    }
    let mut lmax = f64::NEG_INFINITY;
    for i in 0..n {
        let z = view.state(i);
        let mut y = [0.0; MAX_STATE];
        for a in 0..d {
            y[a] = z[a] - g.mean[a];
        }
        forward_sub(&l[..d * d], d, &mut y[..d]);
        let q: f64 = y[..d].iter().map(|v| v * v).sum();
        let lw = -0.5 * q + view.volume[i].max(1e-300).ln();
        out[i] = lw;
        lmax = lmax.max(lw);
    }
    let mut s = 0.0;
    for v in &mut out[..n] {
        *v = (*v - lmax).exp();
        s += *v;
    }
    for v in &mut out[..n] {
        *v /= s;
    }
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
        let (d, nu) = (dims.state, dims.control);
        let mut f0 = [0.0; MAX_STATE];
        let mut f1 = [0.0; MAX_STATE];
        let mut moved = [false; MAX_STATE];
        let zero = [0.0; MAX_CONTROL];
        model.drift(&prior.mean[..d], &zero[..nu], &mut f0[..d]);
        for c in 0..nu {
            let mut u = [0.0; MAX_CONTROL];
            u[c] = 1.0;
            model.drift(&prior.mean[..d], &u[..nu], &mut f1[..d]);
            for i in 0..d {
                moved[i] |= (f1[i] - f0[i]).abs() > 1e-12 || !(f1[i] - f0[i]).is_finite();
            }
        }
        let ctrl_slots = (0..d)
            .filter(|&i| moved[i])
            .flat_map(|i| [2 * i, 2 * i + 1])
            .collect();
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
            moving: false,
            pre_w: Vec::with_capacity(n),
            frame_w: [0.0; MAX_STATE],
            frame_d: [0.0; MAX_STATE],
        }
    }

    /// Hand over a received snapshot; it replaces a pending one (which is
    /// released). The active snapshot is untouched until the swap.
    pub fn offer(&mut self, snap: S) -> Result<(), SnapshotError> {
        let v = SnapshotView::parse(snap.as_ref())?;
        if v.dim != self.dims.state {
            return Err(SnapshotError::Shape(
                "state dimension differs from the model",
            ));
        }
        if v.is_empty() {
            return Err(SnapshotError::Shape("no state"));
        }
        if v.len() > self.max_states {
            return Err(SnapshotError::TooLarge {
                need: v.len(),
                have: self.max_states,
            });
        }
        let buf = self.active.as_ref().map_or(0, |a| 1 - a.buf);
        self.pending = Some(Pending {
            snap,
            next: 0,
            next_tr: 0,
            mapped: false,
            reuse: false,
            buf,
            prepare_ns: 0,
            frame_sums: ([0.0; MAX_STATE], [0.0; MAX_STATE]),
            chol: None,
            lw_max: f64::NEG_INFINITY,
            next_exp: 0,
            w_sum: 0.0,
            wz_sum: [0.0; MAX_STATE],
        });
        Ok(())
    }

    /// Whether a version is being prepared.
    pub fn has_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// Prepare the pending version for at most about `budget` (one chunk at
    /// least) and swap to it once it is ready. A snapshot that fails
    /// validation is dropped with the error.
    pub fn advance(&mut self, budget: Duration) -> Result<Option<SwapInfo>, SnapshotError> {
        // Moving frame: the belief whose covariance installs the version
        // (cached after each update).
        let g_now = (self.moving && self.pending.is_some()).then(|| self.belief());
        let Some(p) = self.pending.as_mut() else {
            return Ok(None);
        };
        let t0 = Instant::now();
        let m = self.dims.obs;
        let view = SnapshotView::parse(p.snap.as_ref())?;
        let n = view.len();
        let g = &mut self.obs_mean[p.buf];
        if p.next == 0 {
            g.clear();
            g.resize(n * m, 0.0);
        }
        while p.next < n {
            let hi = (p.next + CHUNK).min(n);
            if let Err(e) = view.validate_rows(p.next, hi) {
                self.pending = None;
                return Err(e);
            }
            for i in p.next..hi {
                self.model
                    .obs_mean(view.state(i), &mut g[i * m..(i + 1) * m]);
            }
            if self.moving {
                let (d, nu) = (self.dims.state, self.dims.control);
                let mut f = [0.0; MAX_STATE];
                for i in p.next..hi {
                    let z = view.state(i);
                    self.model.drift(z, &[0.0; MAX_CONTROL][..nu], &mut f[..d]);
                    for a in 0..d {
                        p.frame_sums.0[a] += f[a];
                        p.frame_sums.1[a] += z[a];
                    }
                }
            }
            p.next = hi;
            if t0.elapsed() >= budget {
                p.prepare_ns += t0.elapsed().as_nanos() as u64;
                return Ok(None);
            }
        }
        // Phase 2: the control's transport rates of this version (off the
        // per-observation path): reused by id from the active version where
        // their targets survive, else solved.
        if self.moving {
            // No control transport on moving-frame versions; phase 2
            // computes the weights that install the belief on the version
            // (see `install_framed`), so the swap only normalises them.
            let d = self.dims.state;
            if p.next_tr == 0 {
                let g = g_now.expect("moving");
                let mut l = [0.0; MAX_STATE * MAX_STATE];
                l[..d * d].copy_from_slice(g.cov());
                p.chol = cholesky(&mut l[..d * d], d).then_some(l);
                self.pre_w.clear();
                self.pre_w.resize(n, f64::NEG_INFINITY);
                p.lw_max = f64::NEG_INFINITY;
            }
            let mut c = [0.0; MAX_STATE];
            for a in 0..d {
                c[a] = p.frame_sums.1[a] / n as f64;
            }
            if let Some(l) = p.chol {
                while p.next_tr < n {
                    let hi = (p.next_tr + CHUNK).min(n);
                    for i in p.next_tr..hi {
                        let z = view.state(i);
                        let mut y = [0.0; MAX_STATE];
                        for a in 0..d {
                            y[a] = z[a] - c[a];
                        }
                        forward_sub(&l[..d * d], d, &mut y[..d]);
                        let q: f64 = y[..d].iter().map(|v| v * v).sum();
                        let lw = -0.5 * q + view.volume[i].max(1e-300).ln();
                        self.pre_w[i] = lw;
                        p.lw_max = p.lw_max.max(lw);
                    }
                    p.next_tr = hi;
                    if t0.elapsed() >= budget && p.next_tr < n {
                        p.prepare_ns += t0.elapsed().as_nanos() as u64;
                        return Ok(None);
                    }
                }
                while p.next_exp < n {
                    let hi = (p.next_exp + CHUNK).min(n);
                    for (i, v) in (p.next_exp..hi).zip(&mut self.pre_w[p.next_exp..hi]) {
                        *v = (*v - p.lw_max).exp();
                        p.w_sum += *v;
                        let z = view.state(i);
                        for a in 0..d {
                            p.wz_sum[a] += *v * z[a];
                        }
                    }
                    p.next_exp = hi;
                    if t0.elapsed() >= budget && p.next_exp < n {
                        p.prepare_ns += t0.elapsed().as_nanos() as u64;
                        return Ok(None);
                    }
                }
            }
            p.next_tr = n;
        }
        if !p.mapped {
            self.transport[p.buf].reset(n);
            p.reuse = false;
            if let Some(act) = self.active.as_ref().filter(|a| a.lineage == view.lineage) {
                let old = SnapshotView::parse(act.snap.as_ref()).expect("active parses");
                let n_old = old.len();
                self.o2n[..n_old].fill(u32::MAX);
                self.n2o[..n].fill(u32::MAX);
                let (mut i, mut j) = (0, 0);
                while i < n_old && j < n {
                    let (a, b) = (old.ids[i], view.ids[j]);
                    if a == b {
                        self.o2n[i] = j as u32;
                        self.n2o[j] = i as u32;
                        i += 1;
                        j += 1;
                    } else if a < b {
                        i += 1;
                    } else {
                        j += 1;
                    }
                }
                p.reuse = true;
            }
            p.mapped = true;
        }
        let (lo, hi) = self.transport.split_at_mut(1);
        let (cur, prev) = if p.buf == 0 {
            (&mut lo[0], &hi[0])
        } else {
            (&mut hi[0], &lo[0])
        };
        while p.next_tr < n {
            let z = p.next_tr;
            let o = self.n2o[z];
            let old = (p.reuse && o != u32::MAX).then_some((prev, o as usize, &self.o2n[..]));
            cur.prepare_state(&view, z, &self.ctrl_slots, old);
            p.next_tr += 1;
            if p.next_tr % 16 == 0 && t0.elapsed() >= budget && p.next_tr < n {
                p.prepare_ns += t0.elapsed().as_nanos() as u64;
                return Ok(None);
            }
        }
        p.prepare_ns += t0.elapsed().as_nanos() as u64;
        Ok(Some(self.swap()))
    }

    /// Moving frame: the version's masses from the weights prepared in
    /// phase 2 (so that the swap is one normalising pass), φ(z) ∝
    /// N(z; c, P̂)·vol(z) — the belief N(x̂, P̂) seen from the
    /// frame F = x̂ − c, c the mean of the version's states, with P̂ the
    /// belief covariance when phase 2 started (a few observations before
    /// the swap) — into `tmp`; sets the frame. False when P̂ was not
    /// positive definite (the caller installs from the Gaussian).
    fn install_framed(&mut self, p: &Pending<S>, newv: &SnapshotView) -> bool {
        if p.chol.is_none() {
            return false;
        }
        let n = newv.len();
        let d = self.dims.state;
        let s = p.w_sum;
        if !(s > 0.0 && s.is_finite()) {
            return false;
        }
        let inv = 1.0 / s;
        for (t, &w) in self.tmp[..n].iter_mut().zip(&self.pre_w[..n]) {
            *t = w * inv;
        }
        // The belief is cached after each update.
        let g = self.belief();
        // F = x̂ − (mean of the installed mass), not x̂ − c: the weights'
        // mean differs from c by the discretisation (finite states, cell
        // volumes), and that difference would be a jump of the belief mean
        // at every version.
        for a in 0..d {
            self.frame_w[a] = p.frame_sums.0[a] / n as f64;
            self.frame_d[a] = g.mean[a] - p.wz_sum[a] * inv;
        }
        self.pending_d = [0.0; MAX_STATE];
        true
    }

    fn swap(&mut self) -> SwapInfo {
        let t0 = Instant::now();
        let p = self.pending.take().expect("pending");
        let newv = SnapshotView::parse(p.snap.as_ref()).expect("parsed before");
        let n_new = newv.len();
        let mut mass_lost = 0.0;
        let mut from_gaussian = true;
        // tmp ← new masses
        self.tmp.clear();
        self.tmp.resize(n_new, 0.0);
        // Moving frame: installed from the prepared weights.
        let framed = self.moving && self.install_framed(&p, &newv);
        if let Some(act) = self
            .active
            .as_ref()
            .filter(|a| !framed && a.lineage == newv.lineage)
        {
            let old = SnapshotView::parse(act.snap.as_ref()).expect("active parses");
            let n_old = old.len();
            // aux[j] = density of new state j, NaN when new.
            self.aux.clear();
            self.aux.resize(n_new, f64::NAN);
            let (mut i, mut j) = (0, 0);
            while i < n_old && j < n_new {
                let (a, b) = (old.ids[i], newv.ids[j]);
                if a == b {
                    let v = old.volume[i];
                    self.aux[j] = if v > 0.0 { self.phi[i] / v } else { 0.0 };
                    i += 1;
                    j += 1;
                } else if a < b {
                    mass_lost += self.phi[i];
                    i += 1;
                } else {
                    j += 1;
                }
            }
            mass_lost += self.phi[i..n_old].iter().sum::<f64>();
            // New states: mean density over their Near set's existing states.
            for j in 0..n_new {
                let rho = if self.aux[j].is_nan() {
                    let (s, e) = (
                        newv.row_offsets[j] as usize,
                        newv.row_offsets[j + 1] as usize,
                    );
                    let (mut acc, mut k) = (0.0, 0u32);
                    for &c in &newv.cols[s..e] {
                        let r = self.aux[c as usize];
                        if !r.is_nan() {
                            acc += r;
                            k += 1;
                        }
                    }
                    if k > 0 {
                        acc / k as f64
                    } else {
                        0.0
                    }
                } else {
                    self.aux[j]
                };
                self.tmp[j] = rho * newv.volume[j];
            }
            let s: f64 = self.tmp.iter().sum();
            if s > 0.0 && s.is_finite() {
                for v in &mut self.tmp {
                    *v /= s;
                }
                from_gaussian = false;
            }
        }
        if from_gaussian && !framed {
            let g = self.belief_now();
            let mut h = g;
            if self.moving {
                let (w, c) = frame_of(&self.model, &newv);
                self.frame_w = w;
                for k in 0..self.dims.state {
                    self.frame_d[k] = g.mean[k] - c[k];
                    h.mean[k] -= self.frame_d[k];
                }
            }
            gaussian_weights(&newv, &h, &mut self.tmp);
            self.pending_d = [0.0; MAX_STATE];
        }
        std::mem::swap(&mut self.phi, &mut self.tmp);
        let info = SwapInfo {
            version: newv.version,
            states: n_new,
            delta: newv.delta,
            mass_lost,
            from_gaussian,
            swap_ns: 0,
            prepare_ns: p.prepare_ns,
        };
        let lineage = newv.lineage;
        self.active = Some(Active {
            snap: p.snap,
            buf: p.buf,
            lineage,
        });
        self.belief.set(None);
        self.mass_mean = None;
        self.versions += 1;
        SwapInfo {
            swap_ns: t0.elapsed().as_nanos() as u64,
            ..info
        }
    }

    /// The belief right now (the fallback's before the first snapshot).
    fn belief_now(&self) -> Gaussian {
        if self.active.is_some() {
            self.moments()
        } else {
            self.fallback.belief()
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
    /// Moving frame (`refine.moving_frame`): every version is a
    /// chain built for g(z) = f(z, u₀) − w, w the mean uncontrolled drift of
    /// its states ([`frame_of`]), around the belief: the chain carries the
    /// belief's shape, a frame displacement F carries its motion. Mass at z
    /// stands for the state z + F, and F moves with what the chain does not
    /// model, evaluated at the belief mean x̂:
    ///
    /// ```text
    /// dF/dt = f(x̂, u) − g(x̂ − F) = f(x̂, u) − f(x̂ − F, u₀) + w
    /// ```
    ///
    /// exact for every state when f(z + F, u) − f(z, u₀) does not depend on
    /// z (the ship inside the disc: positions move at the velocity offset,
    /// velocities at the control), first order otherwise. F is a pure
    /// translation: no numerical diffusion, where a jump chain for the
    /// ship's position drift v on states of spacing r diffuses at about
    /// |v|·r/2 (its velocity information washes out), and no control
    /// transport (rates are not prepared). Each version (a lineage of its
    /// own) is installed from the Gaussian belief with F = x̂ − c, c the
    /// mean of its states, so the belief sits on them.
    pub fn set_moving_frame(&mut self, on: bool) {
        self.moving = on;
        self.frame_w = [0.0; MAX_STATE];
        self.frame_d = [0.0; MAX_STATE];
    }
    /// The active version's frame velocity w and displacement F.
    pub fn frame(&self) -> ([f64; MAX_STATE], [f64; MAX_STATE]) {
        (self.frame_w, self.frame_d)
    }

    /// Total displacement between the mass's states and the belief.
    fn shift(&self) -> [f64; MAX_STATE] {
        let mut s = [0.0; MAX_STATE];
        for k in 0..self.dims.state {
            s[k] = self.pending_d[k] + self.frame_d[k];
        }
        s
    }

    /// φ from the Gaussian `g` (belief coordinates): the mass at z stands
    /// for z + F.
    fn spread_gaussian(&mut self, view: &SnapshotView, g: &Gaussian) {
        let mut h = *g;
        for k in 0..self.dims.state {
            h.mean[k] -= self.frame_d[k];
        }
        gaussian_weights(view, &h, &mut self.phi);
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
    /// (version, states, δ) of the active snapshot.
    pub fn active_info(&self) -> Option<(u64, usize, f64)> {
        let a = self.active.as_ref()?;
        let v = SnapshotView::parse(a.snap.as_ref()).ok()?;
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
        SnapshotView::parse(self.active.as_ref()?.snap.as_ref()).ok()
    }
    /// The mass function on the active snapshot's states.
    pub fn masses(&self) -> &[f64] {
        &self.phi
    }

    /// The control's drift v = f(x̂, u) − f(x̂, u₀) at the belief mean
    /// (u₀ = 0: the refine stage builds uncontrolled chains); exact for
    /// control-affine models with constant input matrix.
    fn control_velocity(&self, u: &[f64], v: &mut [f64]) {
        let d = self.dims.state;
        let nu = self.dims.control;
        let m = self.last.mean;
        let mut f0 = [0.0; MAX_STATE];
        let zero = [0.0; MAX_CONTROL];
        self.model.drift(&m[..d], &zero[..nu], &mut f0[..d]);
        self.model.drift(&m[..d], u, &mut v[..d]);
        for k in 0..d {
            v[k] -= f0[k];
            if !v[k].is_finite() {
                v[k] = 0.0;
            }
        }
    }

    /// F over `dt` with `u` held (see [`Self::set_moving_frame`]): with
    /// z̄ = x̂ − F the mass mean in frame coordinates (moved by the chain at
    /// f(z̄, u₀) − w) and r(F, z̄) = f(z̄ + F, u) − f(z̄, u₀) + w, one Heun
    /// step
    ///
    /// ```text
    /// k₁ = r(F, z̄),  k₂ = r(F + k₁·dt, z̄ + (f(z̄, u₀) − w)·dt),  F += (k₁ + k₂)·dt/2
    /// ```
    ///
    /// — second order; exact for a linear SDE whose A² = 0 (the double
    /// integrator: F_p gains F_v·dt + u·dt²/2). The former Euler step
    /// F += k₁·dt dropped u·dt²/2 of position per step under a control,
    /// a bias the chain filter could only observe away.
    fn move_frame(&mut self, u: &[f64], dt: f64) {
        let d = self.dims.state;
        let nu = self.dims.control;
        let u0 = [0.0; MAX_CONTROL];
        let m = self.last.mean;
        let mut zb = [0.0; MAX_STATE];
        for k in 0..d {
            zb[k] = m[k] - self.frame_d[k];
        }
        // r(F, z̄) into `r`; f(z̄, u₀) into `f0`.
        let rate = |f: &[f64; MAX_STATE],
                    zb: &[f64; MAX_STATE],
                    r: &mut [f64; MAX_STATE],
                    f0: &mut [f64; MAX_STATE]| {
            let mut x = [0.0; MAX_STATE];
            for k in 0..d {
                x[k] = zb[k] + f[k];
            }
            self.model.drift(&x[..d], u, &mut r[..d]);
            self.model.drift(&zb[..d], &u0[..nu], &mut f0[..d]);
            for k in 0..d {
                r[k] += self.frame_w[k] - f0[k];
            }
        };
        let (mut k1, mut k2, mut f0) = ([0.0; MAX_STATE], [0.0; MAX_STATE], [0.0; MAX_STATE]);
        let f = self.frame_d;
        rate(&f, &zb, &mut k1, &mut f0);
        let (mut f1, mut z1) = (f, zb);
        for k in 0..d {
            f1[k] += k1[k] * dt;
            z1[k] += (f0[k] - self.frame_w[k]) * dt;
        }
        rate(&f1, &z1, &mut k2, &mut f0);
        for k in 0..d {
            let r = 0.5 * (k1[k] + k2[k]);
            if r.is_finite() {
                self.frame_d[k] += r * dt;
            }
        }
    }

    /// Accumulate the displacement v·h and transport it once it is about a
    /// jump length.
    fn transport_by(&mut self, buf: usize, view: &SnapshotView, v: &[f64], h: f64) {
        let d = self.dims.state;
        for k in 0..d {
            self.pending_d[k] += v[k] * h;
        }
        let pd = self.pending_d;
        if self.transport[buf].apply(
            view,
            &pd[..d],
            1.0,
            TRANSPORT_MIN_JUMP,
            &mut self.phi,
            &mut self.tmp,
        ) {
            self.pending_d = [0.0; MAX_STATE];
        }
    }

    /// One step of the equalised chain: out = (P^δ)ᵀ phi.
    fn step(view: &SnapshotView, phi: &[f64], out: &mut [f64]) {
        let n = view.len();
        for z in 0..n {
            let (s, e) = (view.in_off[z] as usize, view.in_off[z + 1] as usize);
            let mut acc = 0.0;
            for (w, &src) in view.in_w[s..e].iter().zip(&view.in_src[s..e]) {
                acc += w * phi[src as usize];
            }
            out[z] = view.stay[z] * phi[z] + acc;
        }
    }

    /// Re-spread the mass from the predicted Gaussian (the moments of the
    /// current mass, or the last posterior when no mass is left) with its
    /// std inflated by `RESPREAD_INFLATE`.
    fn respread(&mut self) {
        let Some(act) = self.active.as_ref() else {
            return;
        };
        let words: *const [u64] = act.snap.as_ref();
        // SAFETY: the active snapshot is not replaced in this function.
        let view = SnapshotView::parse(unsafe { &*words }).expect("active parses");
        let mass: f64 = self.phi.iter().sum();
        let mut g = if mass > 0.0 && mass.is_finite() {
            self.moments()
        } else {
            self.last
        };
        if !g.is_finite() {
            g = self.last;
        }
        let f2 = RESPREAD_INFLATE * RESPREAD_INFLATE;
        for v in g.cov_mut() {
            *v *= f2;
        }
        self.spread_gaussian(&view, &g);
        self.pending_d = [0.0; MAX_STATE];
        self.respreads += 1;
        self.belief.set(None);
        self.mass_mean = None;
    }

    /// φ ∝ vol(z): the chain's uniform density (last-resort recovery).
    fn spread_by_volume(&mut self) {
        let Some(act) = self.active.as_ref() else {
            return;
        };
        let view = SnapshotView::parse(act.snap.as_ref()).expect("active parses");
        let s: f64 = view.volume.iter().map(|v| v.max(0.0)).sum();
        for (p, v) in self.phi.iter_mut().zip(view.volume) {
            *p = if s > 0.0 { v.max(0.0) / s } else { 1.0 };
        }
        self.pending_d = [0.0; MAX_STATE];
        self.respreads += 1;
        self.belief.set(None);
        self.mass_mean = None;
    }

    fn moments(&self) -> Gaussian {
        let d = self.dims.state;
        let Some(act) = self.active.as_ref() else {
            return self.fallback.belief();
        };
        let view = SnapshotView::parse(act.snap.as_ref()).expect("active parses");
        let mut acc = WeightedMoments::new(&self.last.mean[..d]);
        for (i, &w) in self.phi.iter().enumerate() {
            if w != 0.0 {
                acc.add(w, view.state(i));
            }
        }
        // The displacement not yet transported (and the moving frame's)
        // shifts the whole belief.
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

    /// Restart from N(mean, cov) at `t` (on the active chain, else in the
    /// fallback).
    pub fn reset(&mut self, t: f64, prior: &Gaussian) {
        self.t = t;
        self.last = *prior;
        self.fallback.reset(t, prior);
        if let Some(act) = self.active.as_ref() {
            let words: *const [u64] = act.snap.as_ref();
            // SAFETY: the active snapshot is not replaced in this function.
            let view = SnapshotView::parse(unsafe { &*words }).expect("active parses");
            if self.moving {
                let (_, c) = frame_of(&self.model, &view);
                for k in 0..self.dims.state {
                    self.frame_d[k] = prior.mean[k] - c[k];
                }
            }
            self.spread_gaussian(&view, prior);
            self.pending_d = [0.0; MAX_STATE];
        }
        self.belief.set(None);
        self.mass_mean = None;
    }

    /// Propagate to `t` with `u` held.
    pub fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        check_predict(self.t, t, u, self.dims)?;
        let dt = t - self.t;
        let Some(act) = self.active.as_ref() else {
            self.fallback.predict(t, u)?;
            self.t = t;
            self.belief.set(None);
            return Ok(());
        };
        if dt == 0.0 {
            return Ok(());
        }
        // Borrow the snapshot independently of `self`'s buffers.
        let words: *const [u64] = act.snap.as_ref();
        // SAFETY: the active snapshot is neither replaced nor dropped in this
        // function (only `swap` replaces it), so its words outlive `view`.
        let view = SnapshotView::parse(unsafe { &*words }).expect("active parses");
        let buf = act.buf;
        let mut v = [0.0; MAX_STATE];
        if self.moving {
            self.move_frame(u, dt);
        } else {
            self.control_velocity(u, &mut v);
        }
        let n = view.len();
        self.tmp.clear();
        self.tmp.resize(n, 0.0);
        let q = dt / view.delta;
        let whole = (q + 1e-9).floor();
        let frac = (q - whole).max(0.0);
        // Lie splitting per chain step: the u₀ chain, then the control's
        // transport over the same time (see `control_transport`), applied
        // once the accumulated displacement makes the fastest active state
        // jump with probability one.
        for _ in 0..whole as usize {
            Self::step(&view, &self.phi, &mut self.tmp);
            std::mem::swap(&mut self.phi, &mut self.tmp);
            self.transport_by(buf, &view, &v, view.delta);
        }
        if frac > 1e-9 {
            self.tmp.resize(n, 0.0);
            Self::step(&view, &self.phi, &mut self.tmp);
            for z in 0..n {
                self.phi[z] = (1.0 - frac) * self.phi[z] + frac * self.tmp[z];
            }
            self.transport_by(buf, &view, &v, frac * view.delta);
        }
        self.t = t;
        self.belief.set(None);
        Ok(())
    }

    /// Condition on a measurement at the current time. A degenerate update
    /// (no state with mass explains y) is recovered, never refused: the
    /// mass is re-spread from the predicted Gaussian with its covariance
    /// inflated and the update retried; if that fails too, the belief
    /// restarts from the likelihood on the whole chain, p(y|z)·vol(z).
    /// Both count in [`Self::respreads`].
    pub fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        let Some(act) = self.active.as_ref() else {
            let r = self.fallback.update(meas);
            self.belief.set(None);
            self.last = self.fallback.belief();
            return r;
        };
        check_measurement(meas, self.dims)?;
        let buf = act.buf;
        let m = self.dims.obs;
        let mut std = [0.0; MAX_OBS];
        match meas.std {
            Some(s) => std[..m].copy_from_slice(&s[..m]),
            None => self.model.obs_std(&mut std[..m]),
        }
        let mut lk = Lik {
            idx: [0usize; MAX_OBS],
            inv_var: [0.0; MAX_OBS],
            nm: 0,
        };
        let mut cst = 0.0;
        for i in meas.mask.iter().take_while(|&i| i < m) {
            lk.idx[lk.nm] = i;
            lk.inv_var[lk.nm] = 1.0 / (std[i] * std[i]);
            lk.nm += 1;
            cst -= std[i].ln() + HALF_LOG_2PI;
        }
        // The mass sits at z, the belief at z + D (D the displacement not
        // yet transported): compare y − (g(x̂ + D) − g(x̂)) with g(z).
        let mut y = [0.0; MAX_OBS];
        y[..m].copy_from_slice(&meas.y[..m]);
        let d = self.dims.state;
        let sh = self.shift();
        if sh[..d].iter().any(|v| *v != 0.0) {
            // The linearisation point: the mass mean of the last posterior
            // (one prediction old: the error is second order in D).
            let x0 = match self.mass_mean {
                Some(m) => m,
                None => {
                    let mut m = self.moments().mean;
                    for k in 0..d {
                        m[k] -= sh[k];
                    }
                    m
                }
            };
            let mut xs = x0;
            for k in 0..d {
                xs[k] += sh[k];
            }
            let (mut g1, mut g0, mut dg) = ([0.0; MAX_OBS], [0.0; MAX_OBS], [0.0; MAX_OBS]);
            self.model.obs_mean(&xs[..d], &mut g1[..m]);
            self.model.obs_mean(&x0[..d], &mut g0[..m]);
            self.model.obs_residual(&g1[..m], &g0[..m], &mut dg[..m]);
            for i in 0..m {
                if dg[i].is_finite() {
                    y[i] -= dg[i];
                }
            }
        }
        let mut r = self.weigh(buf, &lk, &y[..m]);
        if r.is_none() {
            self.respread();
            r = self.weigh(buf, &lk, &meas.y[..m]);
        }
        if r.is_none() {
            self.spread_by_volume();
            r = self.weigh(buf, &lk, &meas.y[..m]);
        }
        let Some((lmax, sum, tmax)) = r else {
            // No state of the chain at all (cannot happen on a parsed
            // snapshot): keep the prediction.
            self.last = self.moments();
            return Err(FilterError::Degenerate);
        };
        let n = self.phi.len();
        let inv = 1.0 / sum;
        let thr = FLUSH.max(self.flush_rel * tmax * inv);
        let mut s2 = 0.0;
        // Normalise, flush and accumulate the moments in one pass.
        let act = self.active.as_ref().expect("checked above");
        let words: *const [u64] = act.snap.as_ref();
        // SAFETY: the active snapshot is neither replaced nor dropped in this
        // function (only `swap` replaces it), so its words outlive `view`.
        let view = SnapshotView::parse(unsafe { &*words }).expect("active parses");
        let mut acc = WeightedMoments::new(&self.last.mean[..d]);
        let mut heaviest = (0.0, 0usize);
        for z in 0..n {
            let mut w = self.tmp[z] * inv;
            if w < thr {
                w = 0.0;
            } else {
                s2 += w * w;
                acc.add(w, view.state(z));
                if w > heaviest.0 {
                    heaviest = (w, z);
                }
            }
            self.phi[z] = w;
        }
        let mut g = acc.gaussian();
        if 1.0 / s2 < self.reanchor_ess {
            g = self.reanchor(&view, &g, heaviest.1);
        }
        let mut mm = [0.0; MAX_STATE];
        mm[..d].copy_from_slice(&g.mean[..d]);
        self.mass_mean = Some(mm);
        for k in 0..d {
            g.mean[k] += sh[k];
        }
        self.last = g;
        self.belief.set(Some(g));
        Ok(UpdateInfo {
            log_evidence: lmax + sum.ln() + cst,
            ess: 1.0 / s2,
            resampled: false,
        })
    }

    /// The posterior's support collapsed to a few states (effective number
    /// 1/Σφ² below `reanchor_ess`): the chain cannot resolve it, and a
    /// belief held on one or two states neither moves with the next
    /// observations nor admits its error (NEES ≫ d). Re-spread the mass
    /// from N(x̂, P̂ + C/4), C the second moment of the displacements from the
    /// heaviest state z* to its Near set (its transition row): the chain's
    /// local resolution. Returns the belief with that covariance (the mean
    /// is the posterior's). Counted in [`Self::reanchors`].
    fn reanchor(&mut self, view: &SnapshotView, g: &Gaussian, zs: usize) -> Gaussian {
        let d = self.dims.state;
        let (s, e) = (
            view.row_offsets[zs] as usize,
            view.row_offsets[zs + 1] as usize,
        );
        let z0 = view.state(zs);
        let mut c = [0.0; MAX_STATE * MAX_STATE];
        let mut k = 0usize;
        for &j in &view.cols[s..e] {
            if j as usize == zs {
                continue;
            }
            let y = view.state(j as usize);
            for a in 0..d {
                for b in 0..d {
                    c[a + b * d] += (y[a] - z0[a]) * (y[b] - z0[b]);
                }
            }
            k += 1;
        }
        let mut h = *g;
        if k > 0 {
            for (v, cv) in h.cov_mut().iter_mut().zip(&c[..d * d]) {
                *v += 0.25 * cv / k as f64;
            }
        }
        if !h.is_finite() {
            return *g;
        }
        gaussian_weights(view, &h, &mut self.phi);
        self.reanchors += 1;
        h
    }

    /// tmp ← φ(z)·p(y|z)/exp(l_max) over the states with mass; returns
    /// (l_max, Σ tmp, max tmp), or None when nothing is left (degenerate).
    fn weigh(&mut self, buf: usize, lk: &Lik, y: &[f64]) -> Option<(f64, f64, f64)> {
        let m = self.dims.obs;
        let g = &self.obs_mean[buf];
        let n = self.phi.len();
        self.aux.clear();
        self.aux.resize(n, f64::NEG_INFINITY);
        let mut r = [0.0; MAX_OBS];
        let mut lmax = f64::NEG_INFINITY;
        for z in 0..n {
            if self.phi[z] == 0.0 {
                continue;
            }
            self.model
                .obs_residual(y, &g[z * m..(z + 1) * m], &mut r[..m]);
            let mut q = 0.0;
            for j in 0..lk.nm {
                let ri = r[lk.idx[j]];
                q += ri * ri * lk.inv_var[j];
            }
            self.aux[z] = -0.5 * q;
            lmax = lmax.max(-0.5 * q);
        }
        let (mut sum, mut tmax) = (0.0, 0.0f64);
        self.tmp.clear();
        self.tmp.resize(n, 0.0);
        if lmax.is_finite() {
            for z in 0..n {
                let a = self.aux[z] - lmax;
                let w = if a > -700.0 {
                    self.phi[z] * a.exp()
                } else {
                    0.0
                };
                self.tmp[z] = w;
                sum += w;
                tmax = tmax.max(w);
            }
        }
        (sum > 0.0 && sum.is_finite()).then_some((lmax, sum, tmax))
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
}

#[cfg(test)]
#[path = "live_chain_frame_tests.rs"]
mod frame_tests;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chain::snapshot::{encode, SnapshotMeta};
    use crate::chain::{Chain, ChainConfig, Sampler, TimeEqualized};
    use crate::filter::chain_filter::ChainFilter;
    use crate::filter::ekf::{Ekf, EkfConfig};
    use crate::model::linear::LinearSde;
    use crate::model::{simulate_observation, Bounds};
    use nalgebra::DMatrix;

    /// dx = (A x + B u) dt + 0.5 dw, y = x + 0.2 v: constant B and F, so the
    /// tilt at the belief mean is the per-state tilt of `ChainFilter`.
    fn model() -> LinearSde {
        LinearSde::new(
            "ctl2",
            DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.5, -1.0]),
            DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
            DMatrix::from_row_slice(2, 2, &[0.5, 0.0, 0.0, 0.5]),
            DMatrix::identity(2, 2),
            vec![0.2, 0.2],
            Bounds::new_box(&[-2.5, -2.5], &[2.5, 2.5]).unwrap(),
        )
    }

    fn meta(version: u64, lineage: u64) -> SnapshotMeta {
        SnapshotMeta {
            version,
            lineage,
            t_pub_ns: 0,
        }
    }

    fn live(m: &LinearSde, prior: &Gaussian) -> LiveChainFilter<LinearSde, Vec<u64>> {
        let ekf = Ekf::new(m.clone(), &EkfConfig::default(), prior, 0.0).unwrap();
        LiveChainFilter::new(m.clone(), Box::new(ekf), 5000, prior, 0.0)
    }

    fn chain(m: &LinearSde, n: usize, seed: u64) -> Chain {
        let mut c = Chain::new(m, ChainConfig::moment_matched(2)).unwrap();
        let mut t = vec![];
        c.grow(
            m,
            &Sampler::Uniform,
            n,
            &mut crate::rng::stream(seed, 1),
            &mut t,
        )
        .unwrap();
        c
    }

    #[test]
    fn on_one_snapshot_it_is_the_offline_chain_filter_and_its_control_helps_against_kalman() {
        let m = model();
        let dt = 0.05;
        let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
        let mut c = chain(&m, 1500, 3);
        let mut eq = TimeEqualized::new(dt).unwrap();
        eq.fit(c.holding());
        let snap = encode(&mut c, eq.delta(), meta(1, 7));
        let mut off = ChainFilter::new(m.clone(), c, dt).unwrap();
        off.reset(0.0, &prior);
        let mut lf = live(&m, &prior);
        lf.offer(snap).unwrap();
        let info = lf.advance(Duration::from_secs(1)).unwrap().unwrap();
        assert!(info.from_gaussian && info.mass_lost == 0.0);
        assert_eq!(info.states, 1500);
        let mut kf = crate::filter::kalman::Kalman::new(m.clone(), &prior, 0.0).unwrap();
        let mut k0 = crate::filter::kalman::Kalman::new(m.clone(), &prior, 0.0).unwrap();
        let mut rng = crate::rng::stream(3, 0);
        let mut x = [0.8, -0.4];
        let mut worst: f64 = 0.0;
        let (mut gap, mut gap0) = (0.0f64, 0.0f64);
        for k in 1..=60 {
            let t = k as f64 * dt;
            let u = [if k > 20 { 1.5 } else { 0.0 }];
            crate::model::discrete::em_integrate(&m, &mut x, &u, dt, 1e-3, &mut rng);
            let mut y = [0.0; 2];
            simulate_observation(&m, &x, &mut rng, &mut y);
            lf.predict(t, &u).unwrap();
            kf.predict(t, &u).unwrap();
            k0.predict(t, &[0.0]).unwrap();
            let b = lf.update(&Measurement::full(&y)).unwrap();
            kf.update(&Measurement::full(&y)).unwrap();
            k0.update(&Measurement::full(&y)).unwrap();
            if k <= 20 {
                // u = u₀: the same recursion as the offline filter.
                off.predict(t, &u).unwrap();
                let a = off.update(&Measurement::full(&y)).unwrap();
                assert!((a.log_evidence - b.log_evidence).abs() < 1e-6);
                let (ga, gb) = (off.belief(), lf.belief());
                for i in 0..2 {
                    worst = worst.max((ga.mean[i] - gb.mean[i]).abs());
                }
                for i in 0..4 {
                    worst = worst.max((ga.cov[i] - gb.cov[i]).abs());
                }
            } else {
                let (g, gk, g0) = (lf.belief(), kf.belief(), k0.belief());
                gap = gap.max((g.mean[1] - gk.mean[1]).abs());
                gap0 = gap0.max((g0.mean[1] - gk.mean[1]).abs());
            }
        }
        assert!(worst < 1e-9, "live vs offline: {worst}");
        // With u = 1.5 held (mild: B u δ well inside the Near radius) the
        // control's transport must bring the estimate closer to the
        // controlled Kalman filter than ignoring the control does. Measured:
        // 0.094 vs 0.104 (the former exponential tilt: 0.072 here, but 1.39
        // Kalman std off under the strong control of the next test, where
        // the transport stays within 1.25 std). The chain's own error with
        // both states observed dominates this mild case.
        eprintln!("live chain vs Kalman {gap:.4}, uncontrolled Kalman vs Kalman {gap0:.4}");
        assert!(gap0 > 0.08, "control must matter: {gap0}");
        assert!(
            gap < gap0,
            "live chain vs Kalman {gap} (uncontrolled {gap0})"
        );
    }

    /// Strong known control on a linear SDE: the filter's mean must follow
    /// the controlled Kalman–Bucy filter (exact for this model), measured
    /// as max |mean − Kalman mean| in units of Kalman's largest std, next to
    /// the chain's own error without control and to a Kalman filter that
    /// ignores the control. Two sensors: both states observed, and only x₁
    /// (the controlled x₂ is then known through the dynamics only, so the
    /// control's transport decides the estimate).
    #[test]
    fn under_a_strong_control_the_mean_tracks_the_controlled_kalman_filter() {
        let lin = |c: DMatrix<f64>, std: Vec<f64>| {
            LinearSde::new(
                "ctl2wide",
                DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.5, -1.0]),
                DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
                DMatrix::from_row_slice(2, 2, &[0.5, 0.0, 0.0, 0.5]),
                c,
                std,
                Bounds::new_box(&[-3.5, -3.5], &[3.5, 3.5]).unwrap(),
            )
        };
        let full = lin(DMatrix::identity(2, 2), vec![0.2, 0.2]);
        let part = lin(DMatrix::from_row_slice(1, 2, &[1.0, 0.0]), vec![0.2]);
        let dt = 0.05;
        let prior = Gaussian::diagonal(&[0.0, 0.0], &[0.3, 0.3]);
        let mut c = Chain::new(&full, ChainConfig::moment_matched(2)).unwrap();
        c.grow(
            &full,
            &Sampler::Uniform,
            2500,
            &mut crate::rng::stream(21, 1),
            &mut vec![],
        )
        .unwrap();
        let mut eq = TimeEqualized::new(dt).unwrap();
        eq.fit(c.holding());
        let snap = encode(&mut c, eq.delta(), meta(1, 7));
        // (max |Δmean| live chain vs Kalman, same for a Kalman filter that
        // ignores the control, Kalman's largest std).
        let run = |m: &LinearSde, amp: f64| {
            let ekf = Ekf::new(m.clone(), &EkfConfig::default(), &prior, 0.0).unwrap();
            let mut lf: LiveChainFilter<LinearSde, Vec<u64>> =
                LiveChainFilter::new(m.clone(), Box::new(ekf), 5000, &prior, 0.0);
            lf.offer(snap.clone()).unwrap();
            lf.advance(Duration::from_secs(1)).unwrap().unwrap();
            let mut kf = crate::filter::kalman::Kalman::new(m.clone(), &prior, 0.0).unwrap();
            let mut k0 = crate::filter::kalman::Kalman::new(m.clone(), &prior, 0.0).unwrap();
            let mut rng = crate::rng::stream(21, 0);
            let mut x = [0.0, 0.0];
            let (mut gap, mut gap0, mut sd) = (0.0f64, 0.0f64, 0.0f64);
            let mut y = vec![0.0; m.dims().obs];
            // Piecewise constant: ±amp switching every second.
            for k in 1..=120 {
                let t = k as f64 * dt;
                let u = [if (k - 1) / 20 % 2 == 0 { amp } else { -amp }];
                crate::model::discrete::em_integrate(m, &mut x, &u, dt, 1e-3, &mut rng);
                simulate_observation(m, &x, &mut rng, &mut y);
                lf.predict(t, &u).unwrap();
                kf.predict(t, &u).unwrap();
                k0.predict(t, &[0.0]).unwrap();
                lf.update(&Measurement::full(&y)).unwrap();
                kf.update(&Measurement::full(&y)).unwrap();
                k0.update(&Measurement::full(&y)).unwrap();
                let (g, gk, g0) = (lf.belief(), kf.belief(), k0.belief());
                for i in 0..2 {
                    gap = gap.max((g.mean[i] - gk.mean[i]).abs());
                    gap0 = gap0.max((g0.mean[i] - gk.mean[i]).abs());
                    sd = sd.max(gk.cov_at(i, i).sqrt());
                }
            }
            (gap, gap0, sd)
        };
        for (name, m) in [("full", &full), ("x1 only", &part)] {
            let (floor, _, _) = run(m, 0.0);
            let (gap, gap0, sd) = run(m, 2.5);
            eprintln!(
                "{name}: live chain vs controlled Kalman max |Δmean| {gap:.4} = {:.2} std (u = 0: {floor:.4}); control ignored {gap0:.4}; Kalman std {sd:.4}",
                gap / sd
            );
            assert!(
                gap0 > sd,
                "{name}: the control must matter: {gap0} vs std {sd}"
            );
            assert!(
                gap < 1.25 * sd,
                "{name}: live chain vs Kalman {gap} (std {sd}, u = 0 {floor}, uncontrolled {gap0})"
            );
        }
    }

    #[test]
    fn remap_keeps_mass_on_kept_ids_and_reports_what_retired_states_held() {
        let m = model();
        let prior = Gaussian::diagonal(&[0.5, 0.0], &[0.4, 0.4]);
        let mut c = chain(&m, 800, 4);
        let delta = 0.01;
        let mut lf = live(&m, &prior);
        lf.offer(encode(&mut c, delta, meta(1, 7))).unwrap();
        lf.advance(Duration::from_secs(1)).unwrap().unwrap();
        let mut rng = crate::rng::stream(4, 0);
        for k in 1..=5 {
            lf.predict(k as f64 * 0.05, &[0.0]).unwrap();
            lf.update(&Measurement::full(&[0.5, 0.1])).unwrap();
        }
        let before = lf.belief();
        // v2: 200 more states (no retirement): nothing lost, belief barely
        // moves (new states take their neighbours' density).
        let mut t = vec![];
        c.grow(&m, &Sampler::Uniform, 200, &mut rng, &mut t)
            .unwrap();
        lf.offer(encode(&mut c, delta, meta(2, 7))).unwrap();
        let info = lf.advance(Duration::from_secs(1)).unwrap().unwrap();
        assert!(!info.from_gaussian);
        assert_eq!((info.version, info.states, info.mass_lost), (2, 1000, 0.0));
        let after = lf.belief();
        for i in 0..2 {
            assert!(
                (before.mean[i] - after.mean[i]).abs() < 0.05,
                "{before:?} {after:?}"
            );
        }
        // v3: retire every state with x₀ > 0.4; the lost mass is what they held.
        let phi = lf.masses().to_vec();
        let keep: Vec<bool> = (0..c.len()).map(|i| c.state(i)[0] <= 0.4).collect();
        let expect: f64 = (0..c.len()).filter(|&i| !keep[i]).map(|i| phi[i]).sum();
        assert!(expect > 0.05, "the test must retire real mass: {expect}");
        let mut touched = vec![];
        let mut r = crate::chain::retire::retire(&m, &mut c, &keep, &mut touched).unwrap();
        lf.offer(encode(&mut r, delta, meta(3, 7))).unwrap();
        let info = lf.advance(Duration::from_secs(1)).unwrap().unwrap();
        assert!(
            (info.mass_lost - expect).abs() < 1e-12,
            "{} vs {expect}",
            info.mass_lost
        );
        assert!((lf.masses().iter().sum::<f64>() - 1.0).abs() < 1e-9);
        // A new lineage starts from the Gaussian belief.
        let g = lf.belief();
        let mut other = chain(&m, 600, 5);
        lf.offer(encode(&mut other, delta, meta(1, 8))).unwrap();
        let info = lf.advance(Duration::from_secs(1)).unwrap().unwrap();
        assert!(info.from_gaussian);
        let h = lf.belief();
        assert!((g.mean[0] - h.mean[0]).abs() < 0.1, "{g:?} {h:?}");
        assert_eq!(lf.versions(), 4);
    }

    #[test]
    fn preparation_is_spread_over_calls_and_bad_snapshots_are_refused() {
        let m = model();
        let prior = Gaussian::diagonal(&[0.0, 0.0], &[0.5, 0.5]);
        let mut lf = live(&m, &prior);
        let mut c = chain(&m, 1200, 6);
        let snap = encode(&mut c, 0.01, meta(1, 1));
        // Before any snapshot the fallback (EKF) answers.
        lf.predict(0.01, &[0.0]).unwrap();
        lf.update(&Measurement::full(&[0.1, 0.1])).unwrap();
        assert!(lf.active_info().is_none());
        lf.offer(snap.clone()).unwrap();
        let mut calls = 0;
        loop {
            calls += 1;
            if lf.advance(Duration::ZERO).unwrap().is_some() {
                break;
            }
        }
        // Phase 1 (g(z)) in chunks of CHUNK states, phase 2 (the control's
        // transport rates) in pieces of 16.
        assert_eq!(calls, 1200usize.div_ceil(CHUNK) + 1200usize.div_ceil(16));
        assert_eq!(lf.active_info().map(|a| a.1), Some(1200));
        let mut bad = snap.clone();
        bad[0] = 0;
        assert_eq!(lf.offer(bad), Err(SnapshotError::Magic));
        let mut bad = snap;
        let n = 1200;
        // Corrupt the first incoming source index (after every f64 section
        // and the ids/offsets/cols u32 sections).
        let v = SnapshotView::parse(&bad).unwrap();
        let off = (v.in_src.as_ptr() as usize - bad.as_ptr() as usize) / 8;
        bad[off] = u64::MAX;
        lf.offer(bad).unwrap();
        assert!(matches!(
            lf.advance(Duration::from_secs(1)),
            Err(SnapshotError::Index(_))
        ));
        assert!(!lf.has_pending());
        // Still filtering on the last good version.
        assert_eq!(lf.active_info().map(|a| a.1), Some(n));
        lf.predict(0.02, &[0.0]).unwrap();
        lf.update(&Measurement::full(&[0.1, 0.1])).unwrap();
    }
}
