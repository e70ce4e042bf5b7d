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
//! connects states in Morton order, so consecutive queries share leaves.
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

use super::index::{SpatialIndex, MAX_INDEX_DIM};
use super::kernel::{
    gaussian_gather_at, holding_time, moment_matched_at, KernelKind, KernelOutcome, KernelWork,
    LocalDyn, ADVECTED_MEAN_ROW_WEIGHT, MAX_LP_NEIGHBOURS, MEAN_ROW_WEIGHT,
};
use super::knn_tree::KnnTree;
use super::linalg::{cholesky, lower_inverse_packed, sym_spectral_norm};
use super::sample::Sampler;
use super::storage::{ChainView, Transitions};
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
    /// ConnectState for each with the final n.
    pub fn batch<M: SdeModel + ?Sized>(
        model: &M,
        cfg: ChainConfig,
        points: &[f64],
    ) -> Result<Self, ChainError> {
        let mut c = Self::new(model, cfg)?;
        let d = c.dim;
        if !points.len().is_multiple_of(d) {
            return Err(ChainError::State("points length is not a multiple of d"));
        }
        let n = points.len() / d;
        c.reserve(n);
        for p in points.chunks_exact(d) {
            c.push_state(model, p)?;
        }
        c.index = SpatialIndex::from_points(d, points).ok_or(ChainError::State(
            "kd-tree cannot store the states (too many share coordinate values)",
        ))?;
        // The reverse-query tree serves incremental insertion only; it is
        // built from the lists at the first `add_state` (batch pays nothing).
        c.rtree = None;
        // ConnectState in a space-filling-curve order of the states: each
        // row depends only on the states, so the order changes no result,
        // but consecutive k-d tree queries then touch the same leaves.
        for i in morton_order(d, points) {
            c.connect(i as usize)?;
        }
        Ok(c)
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

    /// ConnectState (Alg. 2.2) for slot `i` with the current n. Leaves the
    /// Near set in `self.neigh`.
    fn connect(&mut self, i: usize) -> Result<(), ChainError> {
        let d = self.dim;
        let n = self.ids.len();
        let centre = self.query_centre(i);
        let q = &centre[..d];
        let r = match self.cfg.near {
            NearRule::Knn { .. } => {
                let k = self.knn_k(n);
                self.index.nearest(q, k + 1, &mut self.neigh);
                if let Some(pos) = self.neigh.iter().position(|e| e.0 as usize == i) {
                    self.neigh.remove(pos);
                } else {
                    self.neigh.truncate(k);
                }
                if self.lists_enabled() {
                    self.keep_list(i, k);
                }
                self.neigh.iter().fold(0.0f64, |m, e| m.max(e.1)).sqrt()
            }
            NearRule::Radius { .. } => {
                let r = self.rule_radius(n);
                self.index.within(q, r, &mut self.neigh);
                self.neigh.retain(|e| e.0 as usize != i);
                if let Some(maxd) = self.cfg.max_degree {
                    if self.neigh.len() > maxd {
                        self.neigh
                            .sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
                        self.neigh.truncate(maxd);
                    }
                }
                r
            }
        };
        self.connect_near(i, r)
    }

    /// Keep the k-NN Near set in `self.neigh` (ascending) as the list of
    /// slot `i`, with its k-th squared distance as i's reverse-query bound.
    fn keep_list(&mut self, i: usize, k: usize) {
        if self.neigh.len() == k && k > 0 {
            self.cbuf.clear();
            self.pbuf.clear();
            self.cbuf.extend(self.neigh.iter().map(|e| e.0));
            self.pbuf.extend(self.neigh.iter().map(|e| e.1));
            self.near_lists.set_row(i, &self.cbuf, &self.pbuf);
            self.meta[i].near_k = k as u32;
            if let Some(t) = &mut self.rtree {
                t.set_bound(i as u32, self.pbuf[k - 1]);
            }
        } else {
            self.meta[i].near_k = 0;
            if let Some(t) = &mut self.rtree {
                t.set_bound(i as u32, 0.0);
            }
        }
    }

    /// The Near query centre of slot `i`: z, or the advected point z + m(z).
    fn query_centre(&self, i: usize) -> [f64; MAX_INDEX_DIM] {
        let d = self.dim;
        let mut centre = [0.0; MAX_INDEX_DIM];
        centre[..d].copy_from_slice(&self.states[i * d..(i + 1) * d]);
        if self.cfg.step.is_some() {
            for (c, m) in centre[..d].iter_mut().zip(&self.adv[i * d..(i + 1) * d]) {
                *c += m;
            }
        }
        centre
    }

    /// The rest of ConnectState for slot `i` once its Near set is in
    /// `self.neigh` with radius `r`: holding time and transition row.
    fn connect_near(&mut self, i: usize, r: f64) -> Result<(), ChainError> {
        let d = self.dim;
        let x: [f64; MAX_INDEX_DIM] = {
            let mut a = [0.0; MAX_INDEX_DIM];
            a[..d].copy_from_slice(&self.states[i * d..(i + 1) * d]);
            a
        };
        let x = &x[..d];
        let centre = self.query_centre(i);
        let q = &centre[..d];
        self.meta[i].stale = false;
        let ks = self.kern_stride();
        let (fnorm, dnorm) = (self.kern[i * ks + d], self.kern[i * ks + d + 1]);
        // Advected form: the Near ball must hold the diffusion's spread
        // √(‖FFᵀ‖τ) or the covariance cannot be matched (fixed τ, unlike
        // the thesis's Δt ∝ r²). Widen it to ADVECTED_SPREAD standard
        // deviations and keep an evenly strided subset by distance.
        let mut r = r;
        let mut near_total = self.neigh.len();
        if let Some(tau) = self.cfg.step {
            let rho = ADVECTED_SPREAD * (dnorm * tau).sqrt();
            if r < rho {
                self.index.within(q, rho, &mut self.neigh);
                self.neigh.retain(|e| e.0 as usize != i);
                self.neigh
                    .sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
                near_total = self.neigh.len();
                let cap = MAX_LP_NEIGHBOURS;
                if near_total > cap {
                    for j in 0..cap {
                        self.neigh[j] = self.neigh[j * near_total / cap];
                    }
                    self.neigh.truncate(cap);
                }
                r = rho;
            }
        }
        self.stats.connects += 1;
        self.stats.rows_computed += 1;
        self.radius[i] = r;
        self.near_count[i] = near_total as u32;
        if self.neigh.is_empty() || !(r > 0.0) || (fnorm == 0.0 && dnorm == 0.0) {
            // No neighbour, or no dynamics at z: absorbing.
            self.neigh.clear();
            self.holding[i] = f64::INFINITY;
            self.trans.set_row(i, &[], &[]);
            self.stats.absorbing += 1;
            self.meta[i].outcome = KernelOutcome::Absorbing;
            return Ok(());
        }
        let dt = match self.cfg.step {
            Some(tau) => tau,
            None => holding_time(
                r,
                dnorm,
                fnorm,
                self.cfg.kappa_diffusion,
                self.cfg.kappa_drift,
            ),
        };
        let mut mean = [0.0; MAX_STATE];
        match self.cfg.step {
            Some(_) => mean[..d].copy_from_slice(&self.adv[i * d..(i + 1) * d]),
            None => {
                for c in 0..d {
                    mean[c] = self.kern[i * ks + c] * dt;
                }
            }
        }
        let mean = &mean[..d];
        if self.cfg.kernel == KernelKind::MomentMatched && self.neigh.len() > MAX_LP_NEIGHBOURS {
            self.neigh
                .sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        }
        let kk = match self.cfg.kernel {
            KernelKind::MomentMatched => self.neigh.len().min(MAX_LP_NEIGHBOURS),
            KernelKind::Gaussian => self.neigh.len(),
        };
        self.cbuf.clear();
        self.cbuf.extend(self.neigh[..kk].iter().map(|e| e.0));
        if self.cfg.kernel == KernelKind::MomentMatched {
            self.dz.clear();
            for &j in &self.cbuf {
                let j = j as usize;
                for c in 0..d {
                    self.dz.push(self.states[j * d + c] - x[c]);
                }
            }
        }
        self.pbuf.clear();
        self.pbuf.resize(kk, 0.0);
        let dd = d * d;
        let chol_ok = self.meta[i].chol_ok;
        let holding = match self.cfg.kernel {
            KernelKind::Gaussian => {
                if !chol_ok {
                    return Err(ChainError::SingularDiffusion);
                }
                let linv = &self.kern[i * ks + d + 2..(i + 1) * ks];
                gaussian_gather_at(
                    d,
                    &self.states,
                    &self.cbuf,
                    x,
                    mean,
                    dt,
                    linv,
                    &mut self.work,
                    &mut self.pbuf,
                );
                self.stats.gaussian += 1;
                self.meta[i].outcome = KernelOutcome::Gaussian;
                dt
            }
            KernelKind::MomentMatched => {
                let dynl = LocalDyn {
                    f: &self.kern[i * ks..i * ks + d],
                    ff: &self.ff[i * dd..(i + 1) * dd],
                    chol: chol_ok.then(|| &self.chol[i * dd..(i + 1) * dd]),
                };
                // Rows scaled by the extent of the displacements.
                let scale = match self.cfg.step {
                    Some(_) => r + mean.iter().map(|v| v * v).sum::<f64>().sqrt(),
                    None => r,
                };
                let fit = moment_matched_at(
                    d,
                    &self.dz,
                    mean,
                    dt,
                    scale,
                    if self.cfg.step.is_some() {
                        ADVECTED_MEAN_ROW_WEIGHT
                    } else {
                        MEAN_ROW_WEIGHT
                    },
                    &dynl,
                    &mut self.work,
                    &mut self.pbuf,
                );
                let tally = match fit.outcome {
                    KernelOutcome::Exact => KernelOutcome::Exact,
                    KernelOutcome::LeastSquares => KernelOutcome::LeastSquares,
                    _ => KernelOutcome::Gaussian,
                };
                self.tally(tally);
                self.meta[i].outcome = tally;
                fit.holding
            }
        };
        // Drop negligible entries (p < 1e-12): they cost filter time, carry
        // nothing, and products of them become subnormal floats, which are
        // two orders of magnitude slower in the filter's mat-vec.
        let mut w = 0;
        let mut kept = 0.0;
        for k in 0..kk {
            if self.pbuf[k] >= MIN_PROB {
                self.pbuf[w] = self.pbuf[k];
                self.cbuf[w] = self.cbuf[k];
                kept += self.pbuf[k];
                w += 1;
            }
        }
        for v in &mut self.pbuf[..w] {
            *v /= kept;
        }
        self.holding[i] = holding;
        self.trans.set_row(i, &self.cbuf[..w], &self.pbuf[..w]);
        Ok(())
    }

    /// Whether Near sets are kept as exact lists (k-NN rule, no advection).
    /// Build the reverse-query tree if the k-NN lists need it and it is not
    /// there (after `batch` or `from_view`): every state, each bounded by
    /// the k-th squared distance of its list when the list is of the
    /// current k (0 otherwise, as `keep_list` sets it).
    fn ensure_rtree(&mut self) {
        if !self.lists_enabled() || self.rtree.is_some() {
            return;
        }
        let mut t = KnnTree::from_points(self.dim, &self.states);
        for i in 0..self.len() {
            let k = self.meta[i].near_k as usize;
            let b = if k > 0 {
                self.near_lists.row(i).1.get(k - 1).copied().unwrap_or(0.0)
            } else {
                0.0
            };
            t.set_bound(i as u32, b);
        }
        self.rtree = Some(t);
    }

    fn lists_enabled(&self) -> bool {
        matches!(self.cfg.near, NearRule::Knn { .. }) && self.cfg.step.is_none()
    }

    fn tally(&mut self, o: KernelOutcome) {
        match o {
            KernelOutcome::Gaussian => self.stats.gaussian += 1,
            KernelOutcome::Exact => self.stats.exact += 1,
            KernelOutcome::LeastSquares => self.stats.least_squares += 1,
            KernelOutcome::Absorbing => self.stats.absorbing += 1,
        }
    }

    /// Alg. 2.3 lines 3–8 with exact Near lists, for the new slot `z`
    /// (already in both trees).
    ///
    /// Every list of the current k stays the exact k-NN set of its state:
    /// z enters the list of each slot j with ‖z_j − z‖ < r_k(j). One
    /// traversal of [`KnnTree`] finds both these j (each node bounded by
    /// the largest r_k² below it, so only regions whose own radii reach z
    /// are searched — a radius query with the chain-wide max r_k had 140
    /// candidates per state at n = 10⁵, d = 4, for 18 hits) and Near(z),
    /// the k nearest states to z (ConnectState(z)). Then each
    /// z' ∈ Near(z) is reconnected from its list — recomputing the row when
    /// the list changed since the row was computed, and otherwise leaving
    /// it as it is, which is what ConnectState(z') gives for an unchanged
    /// Near set and unchanged k. A slot whose list is of a smaller k
    /// (k = ⌈c log n⌉ grew) is reconnected with a k-d tree query, which
    /// also renews its list.
    fn add_with_lists(&mut self, z: usize, reconnected: &mut Vec<u32>) -> Result<(), ChainError> {
        let d = self.dim;
        let k = self.knn_k(self.len());
        let Some(mut tree) = self.rtree.take() else {
            return Err(ChainError::State("k-NN lists without their tree"));
        };
        let mut x = [0.0; MAX_INDEX_DIM];
        x[..d].copy_from_slice(&self.states[z * d..(z + 1) * d]);
        let k32 = k as u32;
        // Visited: every slot j with ‖z − z_j‖² below its bound, the k-th
        // squared distance of its list. They are random slots: collect them
        // first and edit their lists after the traversal, with the lists
        // prefetched, so the cache misses overlap (their tree bounds stay
        // upper bounds meanwhile, and are set exactly below).
        let hits = &mut self.hits;
        hits.clear();
        tree.nearest_and_reverse(
            &x[..d],
            k,
            z as u32,
            &mut self.neigh,
            &mut |j, d2, bound| {
                if k32 != 0 && j as usize != z {
                    hits.push((j, d2));
                }
                bound
            },
        );
        for &(j, _) in self.hits.iter() {
            super::prefetch::line(&self.meta[j as usize]);
            self.near_lists.prefetch(j as usize, false);
        }
        for &(j, _) in self.hits.iter() {
            if self.meta[j as usize].near_k == k32 {
                self.near_lists.prefetch(j as usize, true);
            }
        }
        for &(j, d2) in self.hits.iter() {
            let m = &mut self.meta[j as usize];
            if m.near_k != k32 {
                continue;
            }
            m.stale = true;
            let (cols, vals) = self.near_lists.row_mut(j as usize);
            let mut p = vals.len() - 1;
            debug_assert_eq!(tree.bound(j), Some(vals[p]));
            while p > 0 && vals[p - 1] > d2 {
                cols[p] = cols[p - 1];
                vals[p] = vals[p - 1];
                p -= 1;
            }
            cols[p] = z as u32;
            vals[p] = d2;
            tree.tighten_bound(j, vals[vals.len() - 1]);
        }
        self.rtree = Some(tree);
        self.keep_list(z, k);
        let r = self.neigh.last().map_or(0.0, |e| e.1.sqrt());
        self.connect_near(z, r)?;
        reconnected.push(z as u32);
        let mut near = std::mem::take(&mut self.near_list);
        near.clear();
        near.extend(self.neigh.iter().map(|e| e.0));
        self.warm_rows(&near);
        for &j in &near {
            let ju = j as usize;
            let m = self.meta[ju];
            if m.near_k != k32 {
                self.connect(ju)?;
            } else if m.stale {
                self.neigh.clear();
                let (c, v) = self.near_lists.row(ju);
                self.neigh.extend(c.iter().copied().zip(v.iter().copied()));
                let r = v.last().map_or(0.0, |r2| r2.sqrt());
                self.connect_near(ju, r)?;
            } else {
                self.stats.connects += 1;
                self.tally(m.outcome);
            }
            reconnected.push(j);
        }
        self.near_list = near;
        Ok(())
    }

    /// Prefetch what recomputing the stale rows among `near` reads and
    /// writes (their caches, neighbours' coordinates, holding time, radius,
    /// and transition rows), so that the cache misses of all rows overlap
    /// instead of stalling each row in turn (rows of random slots are
    /// otherwise memory-bound). Changes no result.
    fn warm_rows(&self, near: &[u32]) {
        use super::prefetch::{line, range};
        let d = self.dim;
        let ks = self.kern_stride();
        let mm = self.cfg.kernel == KernelKind::MomentMatched;
        for &j in near {
            let j = j as usize;
            if !self.meta[j].stale {
                continue;
            }
            range(&self.kern[j * ks..(j + 1) * ks]);
            line(&self.states[j * d]);
            line(&self.holding[j]);
            line(&self.radius[j]);
            line(&self.near_count[j]);
            self.trans.prefetch(j, false);
            if mm {
                let dd = d * d;
                range(&self.ff[j * dd..(j + 1) * dd]);
                range(&self.chol[j * dd..(j + 1) * dd]);
            }
            for &c in self.near_lists.row(j).0 {
                line(&self.states[c as usize * d]);
            }
        }
        for &j in near {
            if self.meta[j as usize].stale {
                self.trans.prefetch(j as usize, true);
            }
        }
    }

    /// ConnectState (Alg. 2.2) again for slot `i` with the current n (e.g.
    /// after some of its neighbours were retired; see [`super::retire`]).
    pub fn reconnect(&mut self, i: usize) -> Result<(), ChainError> {
        if i >= self.len() {
            return Err(ChainError::State("slot out of range"));
        }
        self.connect(i)
    }

    /// Make the next new state's id at least `next` (ids are never reused,
    /// also across [`Self::from_view`] of a chain whose newest states were
    /// removed).
    pub fn reserve_ids(&mut self, next: u32) {
        self.next_id = self.next_id.max(next);
    }

    /// The id the next new state gets.
    pub fn next_id(&self) -> u32 {
        self.next_id
    }

    /// Import a snapshot (e.g. one received from another process); the
    /// model supplies the caches needed to keep growing it.
    pub fn from_view<M: SdeModel + ?Sized>(
        model: &M,
        cfg: ChainConfig,
        view: &ChainView,
    ) -> Result<Self, ChainError> {
        view.validate()?;
        let mut c = Self::new(model, cfg)?;
        if view.dim != c.dim {
            return Err(ChainError::Dimension(view.dim));
        }
        let n = view.len();
        c.reserve(n);
        for i in 0..n {
            c.push_state(model, view.state(i))?;
        }
        c.ids.copy_from_slice(view.ids);
        c.next_id = view.ids.iter().max().map_or(0, |m| m + 1);
        c.holding.copy_from_slice(view.holding);
        c.radius.copy_from_slice(view.radius);
        for i in 0..n {
            // Near-set sizes are not part of a snapshot; the row length is
            // the best available proxy.
            c.near_count[i] = view.row_offsets[i + 1] - view.row_offsets[i];
        }
        c.trans = super::storage::Transitions::from_csr(view.row_offsets, view.cols, view.probs);
        c.index =
            SpatialIndex::from_points(c.dim, view.states).ok_or(ChainError::Dimension(c.dim))?;
        // Built at the first `add_state` (see `ensure_rtree`).
        c.rtree = None;
        Ok(c)
    }

    /// The flat snapshot view (compacts the transition slab first).
    pub fn view(&mut self) -> ChainView<'_> {
        self.trans.compact();
        let (row_offsets, cols, probs) = self.trans.csr().expect("compacted");
        ChainView {
            dim: self.dim,
            states: &self.states,
            ids: &self.ids,
            holding: &self.holding,
            radius: &self.radius,
            row_offsets,
            cols,
            probs,
        }
    }

    /// Make the transitions plain CSR (so [`Self::compact_view`] works).
    pub fn compact(&mut self) {
        self.trans.compact();
    }

    /// The snapshot view if the chain is compact (see [`Self::compact`]).
    pub fn compact_view(&self) -> Option<ChainView<'_>> {
        let (row_offsets, cols, probs) = self.trans.csr()?;
        Some(ChainView {
            dim: self.dim,
            states: &self.states,
            ids: &self.ids,
            holding: &self.holding,
            radius: &self.radius,
            row_offsets,
            cols,
            probs,
        })
    }

    /// Number of states n.
    pub fn len(&self) -> usize {
        self.ids.len()
    }
    /// Whether the chain has no state.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
    /// State dimension d.
    pub fn dim(&self) -> usize {
        self.dim
    }
    /// Construction parameters.
    pub fn config(&self) -> &ChainConfig {
        &self.cfg
    }
    /// Work counters.
    pub fn stats(&self) -> ChainStats {
        self.stats
    }
    /// State of slot i.
    pub fn state(&self, i: usize) -> &[f64] {
        &self.states[i * self.dim..(i + 1) * self.dim]
    }
    /// All states, flat n × d.
    pub fn states(&self) -> &[f64] {
        &self.states
    }
    /// Stable ids by slot.
    pub fn ids(&self) -> &[u32] {
        &self.ids
    }
    /// Holding times by slot.
    pub fn holding(&self) -> &[f64] {
        &self.holding
    }
    /// Near radius used at the last connection, by slot.
    pub fn radius(&self) -> &[f64] {
        &self.radius
    }
    /// Size of the Near set at the last connection, by slot.
    pub fn near_count(&self) -> &[u32] {
        &self.near_count
    }
    /// Volume represented by slot i, the k-NN density estimate
    /// r(z)^d / |Near(z)| (up to the unit-ball constant); used to turn
    /// densities into masses on non-uniformly sampled states.
    pub fn cell_volume(&self, i: usize) -> f64 {
        let k = self.near_count[i].max(1) as f64;
        self.radius[i].powi(self.dim as i32) / k
    }
    /// Transition row of slot i.
    pub fn row(&self, i: usize) -> (&[u32], &[f64]) {
        self.trans.row(i)
    }
    /// Number of transitions.
    pub fn nnz(&self) -> usize {
        self.trans.nnz()
    }
    /// Mean out-degree nnz / n.
    pub fn mean_out_degree(&self) -> f64 {
        self.nnz() as f64 / self.len().max(1) as f64
    }
    /// Cached f(z) at slot i (under the reference control).
    pub fn drift_at(&self, i: usize) -> &[f64] {
        let ks = self.kern_stride();
        &self.kern[i * ks..i * ks + self.dim]
    }
    /// Cached F Fᵀ(z) at slot i.
    pub fn diffusion_at(&self, i: usize) -> &[f64] {
        let dd = self.dim * self.dim;
        &self.ff[i * dd..(i + 1) * dd]
    }
    /// Cached Cholesky factor of F Fᵀ(z) at slot i, if positive definite.
    pub fn chol_at(&self, i: usize) -> Option<&[f64]> {
        let dd = self.dim * self.dim;
        self.meta[i]
            .chol_ok
            .then(|| &self.chol[i * dd..(i + 1) * dd])
    }
    /// The reference control u₀ the chain was built for.
    pub fn reference_control(&self) -> &[f64] {
        &self.cfg.control[..self.control_len]
    }
    /// The k nearest states to `x` (slot, squared distance), into `out`.
    pub fn nearest(&self, x: &[f64], k: usize, out: &mut Vec<(u32, f64)>) {
        self.index.nearest(x, k, out);
    }
    /// Approximate bytes held by states, ids, holding times and transitions.
    pub fn bytes(&self) -> usize {
        self.states.capacity() * 8
            + self.ids.capacity() * 4
            + self.holding.capacity() * 8
            + self.radius.capacity() * 8
            + self.trans.bytes()
    }
}

/// Slots of the flat n × d `points` in Morton (Z-curve) order over their
/// bounding box, so that consecutive points are spatially close.
fn morton_order(d: usize, points: &[f64]) -> Vec<u32> {
    let n = points.len() / d.max(1);
    if d == 0 || n == 0 {
        return vec![];
    }
    let bits = (63 / d).min(16) as u32;
    let mut lo = [f64::INFINITY; MAX_INDEX_DIM];
    let mut hi = [f64::NEG_INFINITY; MAX_INDEX_DIM];
    for p in points.chunks_exact(d) {
        for c in 0..d {
            lo[c] = lo[c].min(p[c]);
            hi[c] = hi[c].max(p[c]);
        }
    }
    let levels = ((1u64 << bits) - 1) as f64;
    let mut keyed: Vec<(u64, u32)> = points
        .chunks_exact(d)
        .enumerate()
        .map(|(i, p)| {
            let mut q = [0u64; MAX_INDEX_DIM];
            for c in 0..d {
                let w = hi[c] - lo[c];
                let t = if w > 0.0 { (p[c] - lo[c]) / w } else { 0.0 };
                q[c] = (t * levels).clamp(0.0, levels) as u64;
            }
            let mut key = 0u64;
            for b in (0..bits).rev() {
                for qc in &q[..d] {
                    key = (key << 1) | ((qc >> b) & 1);
                }
            }
            (key, i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chain::sample::Sampler;
    use crate::model::linear::LinearSde;
    use crate::model::Bounds;
    use nalgebra::DMatrix;

    pub(crate) fn ou2(a1: f64, a2: f64, s: f64, half: f64) -> LinearSde {
        LinearSde::new(
            "ou2",
            DMatrix::from_row_slice(2, 2, &[-a1, 0.0, 0.0, -a2]),
            DMatrix::zeros(2, 0),
            DMatrix::from_row_slice(2, 2, &[s, 0.0, 0.0, s]),
            DMatrix::identity(2, 2),
            vec![0.1, 0.1],
            Bounds::new_box(&[-half, -half], &[half, half]).unwrap(),
        )
    }

    #[test]
    fn incremental_and_batch_rows_are_distributions_and_views_round_trip() {
        let m = ou2(0.5, 1.0, 0.3, 1.0);
        let mut rng = crate::rng::stream(1, 0);
        for cfg in [
            ChainConfig::gaussian(2),
            ChainConfig::moment_matched(2),
            ChainConfig::gaussian(2).with_near(NearRule::Radius { gamma: 1.5 }),
        ] {
            let mut c = Chain::new(&m, cfg.clone()).unwrap();
            let mut touched = vec![];
            c.grow(&m, &Sampler::Uniform, 400, &mut rng, &mut touched)
                .unwrap();
            assert_eq!(c.len(), 400);
            assert!(touched.len() > 400);
            let view = c.view();
            view.validate().unwrap();
            // ids stable and unique
            assert!(view.ids.windows(2).all(|w| w[0] < w[1]));
            let c2 = Chain::from_view(&m, cfg.clone(), &view).unwrap();
            assert_eq!(c2.len(), 400);
            assert_eq!(c2.row(17), c.row(17));
            let pts = Sampler::Uniform.sample_many(m.bounds(), 300, &mut rng);
            let mut b = Chain::batch(&m, cfg, &pts).unwrap();
            b.view().validate().unwrap();
            // batch with k-NN: out-degree = k(n) unless zero-probability
            // entries were dropped.
            assert!(b.mean_out_degree() > 3.0);
        }
    }

    #[test]
    fn near_lists_give_the_rows_of_a_fresh_query() {
        // Reconnection from the kept k-NN lists must give exactly what
        // ConnectState with a k-d tree query gives (Alg. 2.3), for every
        // reconnected slot, across growth of k = ⌈c log n⌉.
        let m = ou2(0.5, 1.0, 0.3, 1.0);
        let mut rng = crate::rng::stream(9, 0);
        for cfg in [ChainConfig::gaussian(2), ChainConfig::moment_matched(2)] {
            let pts = Sampler::Uniform.sample_many(m.bounds(), 200, &mut rng);
            let mut c = Chain::batch(&m, cfg, &pts).unwrap();
            let mut rec = vec![];
            let mut x = [0.0; 2];
            let mut checked = 0;
            let mut from_lists = 0;
            for step in 0..1500 {
                Sampler::Uniform.sample(m.bounds(), &mut rng, &mut x);
                let before = c.stats().connects;
                c.add_state(&m, &x, &mut rec).unwrap();
                assert_eq!(c.stats().connects - before, rec.len() as u64);
                if step % 50 != 0 {
                    continue;
                }
                let mut fresh = c.clone();
                for &j in &rec {
                    let j = j as usize;
                    from_lists += (c.meta[j].near_k == c.knn_k(c.len()) as u32) as usize;
                    fresh.reconnect(j).unwrap();
                    let (ca, pa) = c.row(j);
                    let (cb, pb) = fresh.row(j);
                    assert_eq!(ca, cb, "slot {j}");
                    for (a, b) in pa.iter().zip(pb) {
                        assert!((a - b).abs() <= 1e-12 * b.max(1e-300), "{a} vs {b}");
                    }
                    let (ha, hb) = (c.holding()[j], fresh.holding()[j]);
                    assert!((ha - hb).abs() <= 1e-12 * hb, "{ha} vs {hb}");
                    assert_eq!(c.near_count()[j], fresh.near_count()[j]);
                    checked += 1;
                }
                // every list of the current k is the exact k-NN set
                let k = c.knn_k(c.len());
                for i in 0..c.len() {
                    if c.meta[i].near_k as usize != k {
                        continue;
                    }
                    let mut d2: Vec<(f64, u32)> = (0..c.len())
                        .filter(|&j| j != i)
                        .map(|j| {
                            let s = (0..2).map(|a| (c.state(j)[a] - c.state(i)[a]).powi(2));
                            (s.sum(), j as u32)
                        })
                        .collect();
                    d2.sort_by(|a, b| a.0.total_cmp(&b.0));
                    let mut want: Vec<u32> = d2[..k].iter().map(|e| e.1).collect();
                    let mut got = c.near_lists.row(i).0.to_vec();
                    want.sort_unstable();
                    got.sort_unstable();
                    assert_eq!(got, want, "list of slot {i}");
                    // the reverse-query bound is the list's k-th distance
                    let kth = c.near_lists.row(i).1[k - 1];
                    assert_eq!(c.rtree.as_ref().unwrap().bound(i as u32), Some(kth));
                }
            }
            assert!(
                checked > 200 && from_lists > checked / 2,
                "{checked} {from_lists}"
            );
        }
    }

    /// ConnectState (Alg. 2.2) written out from the formulas, independent
    /// of the chain's caches, lists and trees: brute-force k nearest (ties
    /// by slot), r their largest distance, f and F Fᵀ from the model,
    /// Δt = r²/(‖FFᵀ‖₂ + r‖f‖), p ∝ exp(−½ yᵀ(FFᵀΔt)⁻¹y), y = Δz − fΔt
    /// (nalgebra inverse and eigenvalues), p < MIN_PROB dropped and the rest
    /// renormalised. Returns the row sorted by column, and Δt.
    fn reference_row<M: SdeModel>(
        m: &M,
        states: &[f64],
        d: usize,
        i: usize,
        k: usize,
    ) -> (Vec<u32>, Vec<f64>, f64) {
        use nalgebra::{DMatrix, DVector};
        let x = &states[i * d..(i + 1) * d];
        let mut near: Vec<(f64, u32)> = states
            .chunks_exact(d)
            .enumerate()
            .filter(|(j, _)| *j != i)
            .map(|(j, p)| {
                (
                    p.iter().zip(x).map(|(a, b)| (a - b) * (a - b)).sum(),
                    j as u32,
                )
            })
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        near.truncate(k);
        let r = near.last().unwrap().0.sqrt();
        let dims = m.dims();
        let mut f = vec![0.0; d];
        m.drift(x, &vec![0.0; dims.control], &mut f);
        let mut bigf = vec![0.0; d * dims.noise];
        m.diffusion(x, &mut bigf);
        let bf = DMatrix::from_column_slice(d, dims.noise, &bigf);
        let ff = &bf * bf.transpose();
        let ff_norm = ff
            .clone()
            .symmetric_eigenvalues()
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        let f = DVector::from_vec(f);
        let dt = r * r / (ff_norm + r * f.norm());
        let prec = (ff * dt).try_inverse().unwrap();
        let q: Vec<f64> = near
            .iter()
            .map(|&(_, j)| {
                let z = &states[j as usize * d..(j as usize + 1) * d];
                let y = DVector::from_fn(d, |c, _| z[c] - x[c]) - &f * dt;
                0.5 * (y.transpose() * &prec * &y)[(0, 0)]
            })
            .collect();
        let qmin = q.iter().copied().fold(f64::INFINITY, f64::min);
        let s: f64 = q.iter().map(|v| (qmin - v).exp()).sum();
        let mut row: Vec<(u32, f64)> = near
            .iter()
            .zip(&q)
            .map(|(&(_, j), v)| (j, (qmin - v).exp() / s))
            .filter(|e| e.1 >= MIN_PROB)
            .collect();
        let kept: f64 = row.iter().map(|e| e.1).sum();
        row.sort_by_key(|e| e.0);
        (
            row.iter().map(|e| e.0).collect(),
            row.iter().map(|e| e.1 / kept).collect(),
            dt,
        )
    }

    /// Chain row `i` sorted by column.
    fn sorted_row(c: &Chain, i: usize) -> (Vec<u32>, Vec<f64>) {
        let (cols, probs) = c.row(i);
        let mut e: Vec<(u32, f64)> = cols.iter().copied().zip(probs.iter().copied()).collect();
        e.sort_by_key(|e| e.0);
        (
            e.iter().map(|e| e.0).collect(),
            e.iter().map(|e| e.1).collect(),
        )
    }

    fn assert_row_matches<M: SdeModel>(c: &Chain, m: &M, i: usize, k: usize) {
        let d = c.dim();
        let (rc, rp, rdt) = reference_row(m, c.states(), d, i, k);
        let (cc, cp) = sorted_row(c, i);
        assert_eq!(cc, rc, "columns of slot {i} at n {}", c.len());
        for (a, b) in cp.iter().zip(&rp) {
            // exp(−q) with q up to ~30 for kept entries: rounding of q
            // (and of L⁻¹ vs the inverse) is ≪ 1e-9 relative.
            assert!((a - b).abs() <= 1e-9 * b, "slot {i}: {a} vs {b}");
        }
        let h = c.holding()[i];
        assert!(
            (h - rdt).abs() <= 1e-12 * rdt,
            "Δt of slot {i}: {h} vs {rdt}"
        );
    }

    #[test]
    fn batch_and_incremental_rows_equal_the_connect_state_formulas() {
        // Gaussian kernel, k-NN rule, ship (d = 4) and OU (d = 2): every row
        // of a batch chain, and every row (re)connected by each incremental
        // insertion (Alg. 2.3: the new state and all of Near(z)), equal
        // ConnectState written out from the formulas on brute-force k-NN.
        use crate::model::ship::{Ship, ShipParams};
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        let ou = ou2(0.5, 1.0, 0.3, 1.0);
        fn check<M: SdeModel>(m: &M, seed: u64) {
            let d = m.dims().state;
            let mut rng = crate::rng::stream(seed, 0);
            let pts = Sampler::Uniform.sample_many(m.bounds(), 300, &mut rng);
            let mut c = Chain::batch(m, ChainConfig::gaussian(d), &pts).unwrap();
            let k = c.knn_k(c.len());
            for i in 0..c.len() {
                assert_row_matches(&c, m, i, k);
            }
            let mut rec = vec![];
            let mut x = [0.0; MAX_STATE];
            let mut checked = 0;
            for _ in 0..400 {
                Sampler::Uniform.sample(m.bounds(), &mut rng, &mut x[..d]);
                c.add_state(m, &x[..d], &mut rec).unwrap();
                let k = c.knn_k(c.len());
                for &j in &rec {
                    assert_row_matches(&c, m, j as usize, k);
                    checked += 1;
                }
            }
            assert!(checked > 400 * k / 2, "{checked}");
        }
        check(&ship, 21);
        check(&ou, 22);
    }

    #[test]
    fn reconnection_shrinks_holding_times() {
        // Alg. 2.3: a state's Δt is recomputed with the current n whenever a
        // new sample lands near it, so Δt of the first states decreases.
        let m = ou2(0.5, 1.0, 0.3, 1.0);
        let mut rng = crate::rng::stream(4, 0);
        let mut c = Chain::new(&m, ChainConfig::gaussian(2)).unwrap();
        let mut t = vec![];
        c.grow(&m, &Sampler::Uniform, 50, &mut rng, &mut t).unwrap();
        let early: f64 = c.holding()[..10].iter().sum();
        c.grow(&m, &Sampler::Uniform, 5000, &mut rng, &mut t)
            .unwrap();
        let late: f64 = c.holding()[..10].iter().sum();
        assert!(late < 0.3 * early, "{late} vs {early}");
    }
}
