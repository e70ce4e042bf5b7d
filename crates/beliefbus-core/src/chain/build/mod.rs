//! The chain M_n = (S_n, P_n, T_n) and its construction: `ConnectState`
//! (thesis Alg. 2.2), batch construction (Alg. 2.1) and incremental
//! construction with reconnection of every neighbour of a new state
//! (Alg. 2.3).
//!
//! ```text
//! ConnectState(z):  Δt(z) ← ComputeHoldingTime(z);  Z ← Near(z, S);
//!                   P(· | z) ← ComputeTransProb(z, Z, Δt(z))
//! Alg. 2.1:  sample N states, then ConnectState every state with n = N
//! Alg. 2.3:  per new z: S ← S ∪ {z}; ConnectState(z); ConnectState(z') ∀ z' ∈ Near(z)
//! ```
//!
//! Near sets of the k-NN rule (without advection) are kept as exact lists
//! (slot, squared distance) under insertion: adding z puts z into the list
//! of every state whose k-th neighbour is farther than z (a reverse query
//! of [`super::knn_tree::KnnTree`], which also finds Near(z) in the same
//! traversal), so ConnectState(z')
//! for z' ∈ Near(z) needs no k-d tree query and its row is recomputed only
//! if the list changed since the row was last computed — the same Near
//! sets and rows as querying the tree (test
//! `near_lists_give_the_rows_of_a_fresh_query`). Batch construction
//! connects states in Hilbert order ([`super::order`]), so consecutive
//! queries share leaves.
//!
//! Storage is flat: coordinates n × d in one `Vec<f64>`, stable `u32` ids,
//! holding times, radii, and slab/CSR transitions ([`super::storage`]).
//! Per-state caches of f(z), ‖f‖, ‖FFᵀ‖ and the Cholesky factor L of FFᵀ
//! make reconnection independent of model evaluation cost; the model is
//! needed only when a state is added. What a Gaussian row reads is one record
//! per slot (f, ‖f‖, ‖FFᵀ‖ and L⁻¹ packed, so the kernel's quadratic forms
//! are products, not forward substitutions), and the flags of a slot's list
//! and row another; the rows and lists of the states a new state touches are
//! prefetched before they are edited (incremental construction at
//! n = 10⁵ is memory-bound: these are random slots). Columns are state
//! *slots* (indices into the arrays); ids are what survives across versions.
//!
//! Layout: this file (state, construction entry points, caches),
//! [`batch`] (Alg. 2.1 as resumable work), [`connect`] (ConnectState),
//! [`lists`] (incremental insertion with exact k-NN lists), [`access`]
//! (views, snapshots, accessors).

mod access;
mod batch;
mod connect;
mod lists;

pub use batch::BatchBuild;

use super::index::{SpatialIndex, MAX_INDEX_DIM};
use super::kernel::{KernelKind, KernelOutcome, KernelWork};
use super::knn_tree::KnnTree;
use super::linalg::{cholesky, lower_inverse_packed, sym_spectral_norm};
use super::sample::Sampler;
use super::storage::Transitions;
use super::{ChainConfig, ChainError, NearRule};
use crate::model::SdeModel;
use crate::rng::SimRng;
use crate::{MAX_NOISE, MAX_STATE};

/// Advected construction: the Near ball around z + m(z) holds at least
/// this many diffusion standard deviations √(‖FFᵀ‖τ).
pub const ADVECTED_SPREAD: f64 = 2.5;

/// Transition probabilities below this are dropped from a row.
pub const MIN_PROB: f64 = 1e-12;

/// Counters of construction work and kernel outcomes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ChainStats {
    /// ConnectState calls.
    pub connects: u64,
    /// ConnectState calls that computed a row (the others found an
    /// unchanged Near set and kept the row).
    pub rows_computed: u64,
    /// Rows from the Gaussian kernel (incl. LP fallbacks).
    pub gaussian: u64,
    /// LP rows meeting the moment equations exactly.
    pub exact: u64,
    /// LP rows that were infeasible (least-violating fit).
    pub least_squares: u64,
    /// States with no neighbour (absorbing).
    pub absorbing: u64,
}

/// Per-slot flags kept together (one cache line serves all of them).
#[derive(Clone, Copy, Debug)]
struct SlotMeta {
    /// k of the slot's Near list; 0 when it has none (reconnection then
    /// queries the tree).
    near_k: u32,
    /// Whether the Near list changed since the row was computed.
    stale: bool,
    /// Whether F Fᵀ(z) is positive definite (its Cholesky factor cached).
    chol_ok: bool,
    /// Counter the current row was tallied under (a reconnection whose
    /// Near set did not change is tallied again without recomputing).
    outcome: KernelOutcome,
}

/// A Markov-chain approximation of a diffusion.
#[derive(Clone)]
pub struct Chain {
    dim: usize,
    cfg: ChainConfig,
    control_len: usize,
    states: Vec<f64>,
    ids: Vec<u32>,
    holding: Vec<f64>,
    radius: Vec<f64>,
    near_count: Vec<u32>,
    trans: Transitions,
    // per-state caches
    /// What recomputing a row reads, one record per slot (stride
    /// [`Self::kern_stride`]): f(z) (d), ‖f‖, ‖FFᵀ‖, L⁻¹ packed by rows
    /// (d(d+1)/2; NaN when FFᵀ is singular) — one or two cache lines
    /// instead of one per array.
    kern: Vec<f64>,
    ff: Vec<f64>,
    chol: Vec<f64>,
    /// Advected construction: flow displacement m(z) over τ, n × d.
    adv: Vec<f64>,
    index: SpatialIndex,
    /// k-NN rule without advection: each slot's Near set as (slot, squared
    /// distance) in ascending order, kept exact under insertion (see
    /// [`Self::add_state`]) so that reconnection needs no k-d tree query.
    near_lists: Transitions,
    /// Per-slot flags of the Near list and row (one record per slot).
    meta: Vec<SlotMeta>,
    /// k-NN rule without advection: the states again, each with the squared
    /// distance to the k-th entry of its Near list as the bound of its
    /// reverse queries (0 without a list of the current k).
    rtree: Option<KnnTree>,
    next_id: u32,
    stats: ChainStats,
    // scratch
    neigh: Vec<(u32, f64)>,
    /// Reverse-query hits (slot, squared distance) of the state being added.
    hits: Vec<(u32, f64)>,
    near_list: Vec<u32>,
    dz: Vec<f64>,
    pbuf: Vec<f64>,
    cbuf: Vec<u32>,
    work: KernelWork,
}

impl Chain {
    /// An empty chain for `model` with construction parameters `cfg`.
    pub fn new<M: SdeModel + ?Sized>(model: &M, cfg: ChainConfig) -> Result<Self, ChainError> {
        cfg.validate()?;
        let dims = model.dims();
        let d = dims.state;
        if d == 0 || d > MAX_STATE {
            return Err(ChainError::Dimension(d));
        }
        let index = SpatialIndex::new(d).ok_or(ChainError::Dimension(d))?;
        let lists = matches!(cfg.near, NearRule::Knn { .. }) && cfg.step.is_none();
        let rtree = lists.then(|| KnnTree::new(d));
        Ok(Self {
            dim: d,
            cfg,
            control_len: dims.control,
            states: vec![],
            ids: vec![],
            holding: vec![],
            radius: vec![],
            near_count: vec![],
            trans: Transitions::default(),
            kern: vec![],
            ff: vec![],
            chol: vec![],
            adv: vec![],
            index,
            rtree,
            near_lists: Transitions::default(),
            meta: vec![],
            next_id: 0,
            stats: ChainStats::default(),
            neigh: Vec::with_capacity(256),
            hits: Vec::with_capacity(256),
            near_list: Vec::with_capacity(256),
            dz: Vec::with_capacity(256 * d),
            pbuf: Vec::with_capacity(256),
            cbuf: Vec::with_capacity(256),
            work: KernelWork::new(),
        })
    }

    /// Batch construction (Alg. 2.1): all `points` (flat n × d) first, then
    /// ConnectState for each with the final n (in one go; [`BatchBuild`]
    /// builds the same chain in slices).
    pub fn batch<M: SdeModel + ?Sized>(
        model: &M,
        cfg: ChainConfig,
        points: &[f64],
    ) -> Result<Self, ChainError> {
        let mut b = BatchBuild::new(model, cfg, points.to_vec())?;
        b.run(model, || true)?;
        b.finish()
    }

    /// Batch construction from `n` draws of `sampler`.
    pub fn sample_batch<M: SdeModel + ?Sized>(
        model: &M,
        cfg: ChainConfig,
        sampler: &Sampler,
        n: usize,
        rng: &mut SimRng,
    ) -> Result<Self, ChainError> {
        let pts = sampler.sample_many(model.bounds(), n, rng);
        Self::batch(model, cfg, &pts)
    }

    /// Prepare growth by `extra` more states: reserve room in every
    /// per-state array and in the transition and Near-list slabs, and build
    /// the reverse-query tree of the k-NN lists if it is not there yet
    /// (after [`Self::batch`] or [`Self::from_view`]; otherwise the first
    /// [`Self::add_state`] builds it). Adding up to `extra` states then
    /// reallocates nothing but the k-d trees' nodes.
    pub fn reserve(&mut self, extra: usize) {
        self.ensure_rtree();
        let n = self.len();
        // Entries per new row: k(n + extra) for the k-NN rule, the mean row
        // length otherwise, with the slab's slack per row.
        let k = self
            .knn_k(n + extra)
            .max(self.mean_out_degree().ceil() as usize);
        let entries = extra * super::storage::row_capacity(k as u32) as usize;
        self.trans.reserve(extra, entries);
        if self.lists_enabled() {
            self.near_lists.reserve(extra, entries);
        }
        if let Some(t) = &mut self.rtree {
            t.reserve(extra);
        }
        let d = self.dim;
        self.states.reserve(extra * d);
        self.ids.reserve(extra);
        self.holding.reserve(extra);
        self.radius.reserve(extra);
        self.near_count.reserve(extra);
        self.kern.reserve(extra * self.kern_stride());
        self.ff.reserve(extra * d * d);
        self.chol.reserve(extra * d * d);
        self.meta.reserve(extra);
        if self.cfg.step.is_some() {
            self.adv.reserve(extra * d);
        }
    }

    /// One step of incremental construction (Alg. 2.3 lines 3–8): add `x`,
    /// connect it, then reconnect each of its Near states with the new n.
    /// `reconnected` receives the new slot followed by every reconnected
    /// slot (what exponential backup must check). Returns the new slot.
    pub fn add_state<M: SdeModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[f64],
        reconnected: &mut Vec<u32>,
    ) -> Result<u32, ChainError> {
        self.ensure_rtree();
        let slot = self.push_state(model, x)?;
        if self.index.insert(x, slot as u32).is_err() {
            self.pop_state();
            return Err(ChainError::State(
                "kd-tree cannot store it (too many states share coordinate values)",
            ));
        }
        if let Some(t) = &mut self.rtree {
            t.insert(x, slot as u32);
        }
        reconnected.clear();
        if self.lists_enabled() {
            self.add_with_lists(slot, reconnected)?;
            return Ok(slot as u32);
        }
        self.connect(slot)?;
        reconnected.push(slot as u32);
        // Near(z, S_n): the set ConnectState(z) just used. Advected form:
        // the states whose advected neighbourhoods may now contain z, i.e.
        // the neighbours of the upstream point z − m(z).
        let mut near = std::mem::take(&mut self.near_list);
        near.clear();
        if self.cfg.step.is_some() {
            let d = self.dim;
            let mut up = [0.0; MAX_INDEX_DIM];
            for c in 0..d {
                up[c] = x[c] - self.adv[slot * d + c];
            }
            let k = match self.cfg.near {
                NearRule::Knn { .. } => self.knn_k(self.len()),
                NearRule::Radius { .. } => self.neigh.len().max(1),
            };
            self.index.nearest(&up[..d], k + 1, &mut self.neigh);
            self.neigh.retain(|e| e.0 as usize != slot);
        }
        near.extend(self.neigh.iter().map(|x| x.0));
        for &j in &near {
            self.connect(j as usize)?;
            reconnected.push(j);
        }
        self.near_list = near;
        Ok(slot as u32)
    }

    /// Add `count` states drawn from `sampler` incrementally; every slot
    /// touched (added or reconnected) is appended to `touched`.
    pub fn grow<M: SdeModel + ?Sized>(
        &mut self,
        model: &M,
        sampler: &Sampler,
        count: usize,
        rng: &mut SimRng,
        touched: &mut Vec<u32>,
    ) -> Result<(), ChainError> {
        let mut x = [0.0; MAX_STATE];
        let mut rec = Vec::with_capacity(64);
        self.reserve(count);
        for _ in 0..count {
            sampler.sample(model.bounds(), rng, &mut x[..self.dim]);
            self.add_state(model, &x[..self.dim], &mut rec)?;
            touched.extend_from_slice(&rec);
        }
        Ok(())
    }

    fn push_state<M: SdeModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[f64],
    ) -> Result<usize, ChainError> {
        let d = self.dim;
        if x.len() != d {
            return Err(ChainError::State("wrong dimension"));
        }
        if x.iter().any(|v| !v.is_finite()) {
            return Err(ChainError::State("non-finite coordinate"));
        }
        let dims = model.dims();
        let k = dims.noise;
        let mut f = [0.0; MAX_STATE];
        let mut bigf = [0.0; MAX_STATE * MAX_NOISE];
        model.drift(x, &self.cfg.control[..self.control_len], &mut f[..d]);
        model.diffusion(x, &mut bigf[..d * k]);
        let mut ff = [0.0; MAX_STATE * MAX_STATE];
        for i in 0..d {
            for j in 0..d {
                ff[i + j * d] = (0..k).map(|c| bigf[i + c * d] * bigf[j + c * d]).sum();
            }
        }
        if f[..d].iter().chain(&ff[..d * d]).any(|v| !v.is_finite()) {
            return Err(ChainError::State(
                "model drift or diffusion is not finite here",
            ));
        }
        let mut l = ff;
        let ok = cholesky(&mut l[..d * d], d);
        if !ok && self.cfg.kernel == KernelKind::Gaussian {
            return Err(ChainError::SingularDiffusion);
        }
        let slot = self.ids.len();
        self.states.extend_from_slice(x);
        self.ids.push(self.next_id);
        self.next_id += 1;
        self.holding.push(f64::INFINITY);
        self.radius.push(0.0);
        self.near_count.push(0);
        self.kern.extend_from_slice(&f[..d]);
        self.kern
            .push(f[..d].iter().map(|v| v * v).sum::<f64>().sqrt());
        self.kern.push(sym_spectral_norm(&ff[..d * d], d));
        let t = d * (d + 1) / 2;
        let mut linv = [f64::NAN; MAX_STATE * (MAX_STATE + 1) / 2];
        if ok {
            lower_inverse_packed(&l[..d * d], d, &mut linv[..t]);
        }
        self.kern.extend_from_slice(&linv[..t]);
        self.ff.extend_from_slice(&ff[..d * d]);
        self.chol.extend_from_slice(&l[..d * d]);
        self.near_lists.push_row();
        self.meta.push(SlotMeta {
            near_k: 0,
            stale: false,
            chol_ok: ok,
            outcome: KernelOutcome::Absorbing,
        });
        if let Some(tau) = self.cfg.step {
            let m = self.flow_displacement(model, x, tau);
            self.adv.extend_from_slice(&m[..d]);
        }
        self.trans.push_row();
        Ok(slot)
    }

    /// Undo the last `push_state`.
    fn pop_state(&mut self) {
        let d = self.dim;
        let n = self.ids.len() - 1;
        self.states.truncate(n * d);
        self.ids.truncate(n);
        self.next_id -= 1;
        self.holding.truncate(n);
        self.radius.truncate(n);
        self.near_count.truncate(n);
        self.kern.truncate(n * self.kern_stride());
        self.ff.truncate(n * d * d);
        self.chol.truncate(n * d * d);
        self.near_lists.pop_row();
        self.meta.truncate(n);
        if self.cfg.step.is_some() {
            self.adv.truncate(n * d);
        }
        self.trans.pop_row();
    }

    /// Displacement of the deterministic flow ẋ = f(x, u₀) over τ (one
    /// classical RK4 step), the mean of the advected kernel.
    fn flow_displacement<M: SdeModel + ?Sized>(
        &self,
        model: &M,
        x: &[f64],
        tau: f64,
    ) -> [f64; MAX_STATE] {
        let d = self.dim;
        let u = &self.cfg.control[..self.control_len];
        let mut k = [[0.0; MAX_STATE]; 4];
        let mut y = [0.0; MAX_STATE];
        model.drift(x, u, &mut k[0][..d]);
        for (stage, h) in [(1usize, 0.5), (2, 0.5), (3, 1.0)] {
            for c in 0..d {
                y[c] = x[c] + h * tau * k[stage - 1][c];
            }
            let (a, b) = k.split_at_mut(stage);
            let _ = a;
            model.drift(&y[..d], u, &mut b[0][..d]);
        }
        let mut m = [0.0; MAX_STATE];
        for c in 0..d {
            let v = tau / 6.0 * (k[0][c] + 2.0 * k[1][c] + 2.0 * k[2][c] + k[3][c]);
            m[c] = if v.is_finite() { v } else { 0.0 };
        }
        m
    }

    /// Flow displacement m(z) over τ at slot i (advected construction).
    pub fn advection_at(&self, i: usize) -> Option<&[f64]> {
        self.cfg
            .step
            .map(|_| &self.adv[i * self.dim..(i + 1) * self.dim])
    }

    /// Length of a slot's record in `kern`: d + 2 + d(d+1)/2.
    fn kern_stride(&self) -> usize {
        let d = self.dim;
        d + 2 + d * (d + 1) / 2
    }

    /// Neighbour count of the k-NN rule at size n.
    pub fn knn_k(&self, n: usize) -> usize {
        match self.cfg.near {
            NearRule::Knn { c } => {
                let k = (c * (n.max(2) as f64).ln()).ceil() as usize;
                k.max(self.cfg.min_neighbours).min(n.saturating_sub(1))
            }
            NearRule::Radius { .. } => 0,
        }
    }

    /// Radius of the radius rule at size n.
    pub fn rule_radius(&self, n: usize) -> f64 {
        match self.cfg.near {
            NearRule::Radius { gamma } => {
                let n = n.max(2) as f64;
                gamma * (n.ln() / n).powf(1.0 / self.dim as f64)
            }
            NearRule::Knn { .. } => f64::NAN,
        }
    }
}

#[cfg(test)]
mod order_timing_tests;
#[cfg(test)]
mod tests;
