//! Incremental insertion with exact k-NN Near lists (thesis Alg. 2.3):
//! one traversal of the reverse-query tree finds Near(z) and every state
//! whose list z enters; only rows whose list changed are recomputed.

use super::Chain;
use crate::chain::index::MAX_INDEX_DIM;
use crate::chain::kernel::KernelKind;
use crate::chain::ChainError;

impl Chain {
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
    ///
    /// About 90 lines: the one traversal (Near(z) and the reverse hits)
    /// and the reconnection of each hit share the hit list and the list
    /// flags; the steps follow Alg. 2.3 in order.
    pub(super) fn add_with_lists(
        &mut self,
        z: usize,
        reconnected: &mut Vec<u32>,
    ) -> Result<(), ChainError> {
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
            crate::chain::prefetch::line(&self.meta[j as usize]);
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
    pub(super) fn warm_rows(&self, near: &[u32]) {
        use crate::chain::prefetch::{line, range};
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
}
