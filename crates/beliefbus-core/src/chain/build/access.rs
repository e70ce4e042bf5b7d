//! Reconnection, ids, views and snapshots of a chain, and its read
//! accessors.

use super::{Chain, ChainStats};
use crate::chain::index::SpatialIndex;
use crate::chain::storage::{ChainView, Transitions};
use crate::chain::{ChainConfig, ChainError};
use crate::model::SdeModel;

impl Chain {
    /// ConnectState (Alg. 2.2) again for slot `i` with the current n (e.g.
    /// after some of its neighbours were retired; see [`crate::chain::retire`]).
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
        c.trans = Transitions::from_csr(view.row_offsets, view.cols, view.probs);
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
