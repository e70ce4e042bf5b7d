//! ConnectState (thesis Alg. 2.2): the Near set of a slot (k-d tree query,
//! radius or k-NN rule, around z or the advected point) and its row from
//! the kernel, with the bookkeeping of the k-NN lists and the reverse-query
//! tree.

use super::{Chain, ADVECTED_SPREAD, MIN_PROB};
use crate::chain::index::MAX_INDEX_DIM;
use crate::chain::kernel::{
    gaussian_gather_at, holding_time, moment_matched_at, KernelKind, KernelOutcome, LocalDyn,
    ADVECTED_MEAN_ROW_WEIGHT, MAX_LP_NEIGHBOURS, MEAN_ROW_WEIGHT,
};
use crate::chain::knn_tree::KnnTree;
use crate::chain::{ChainError, NearRule};
use crate::MAX_STATE;

impl Chain {
    /// ConnectState (Alg. 2.2) for slot `i` with the current n. Leaves the
    /// Near set in `self.neigh`.
    pub(super) fn connect(&mut self, i: usize) -> Result<(), ChainError> {
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
    pub(super) fn keep_list(&mut self, i: usize, k: usize) {
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
    pub(super) fn query_centre(&self, i: usize) -> [f64; MAX_INDEX_DIM] {
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
    pub(super) fn connect_near(&mut self, i: usize, r: f64) -> Result<(), ChainError> {
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
        let (r, near_total) = self.widen_advected(i, q, r, dnorm);
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
        let holding = self.row_probabilities(i, x, mean, dt, r, kk)?;
        self.store_row(i, kk, holding);
        Ok(())
    }

    /// Advected form: the Near ball must hold the diffusion's spread
    /// √(‖FFᵀ‖τ) or the covariance cannot be matched (fixed τ, unlike
    /// the thesis's Δt ∝ r²). Widen it to ADVECTED_SPREAD standard
    /// deviations around `q` and keep an evenly strided subset by distance.
    /// Returns the radius and the size of the full Near set.
    fn widen_advected(&mut self, i: usize, q: &[f64], r: f64, dnorm: f64) -> (f64, usize) {
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
        (r, near_total)
    }

    /// The transition probabilities of slot `i` to its first `kk` Near
    /// states (`self.cbuf`, displacements in `self.dz`) into `self.pbuf`,
    /// by the configured kernel around `mean` over `dt`; returns the
    /// holding time (the moment-matched fit may change it).
    fn row_probabilities(
        &mut self,
        i: usize,
        x: &[f64],
        mean: &[f64],
        dt: f64,
        r: f64,
        kk: usize,
    ) -> Result<f64, ChainError> {
        let d = self.dim;
        let ks = self.kern_stride();
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
        Ok(holding)
    }

    /// Store the row of slot `i` (its first `kk` entries of `cbuf`/`pbuf`)
    /// with holding time `holding`.
    fn store_row(&mut self, i: usize, kk: usize, holding: f64) {
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
    }

    /// Build the reverse-query tree if the k-NN lists need it and it is not
    /// there (after `batch` or `from_view`): every state, each bounded by
    /// the k-th squared distance of its list when the list is of the
    /// current k (0 otherwise, as `keep_list` sets it).
    pub(super) fn ensure_rtree(&mut self) {
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

    /// Whether Near sets are kept as exact lists (k-NN rule, no advection).
    pub(super) fn lists_enabled(&self) -> bool {
        matches!(self.cfg.near, NearRule::Knn { .. }) && self.cfg.step.is_none()
    }

    pub(super) fn tally(&mut self, o: KernelOutcome) {
        match o {
            KernelOutcome::Gaussian => self.stats.gaussian += 1,
            KernelOutcome::Exact => self.stats.exact += 1,
            KernelOutcome::LeastSquares => self.stats.least_squares += 1,
            KernelOutcome::Absorbing => self.stats.absorbing += 1,
        }
    }
}
