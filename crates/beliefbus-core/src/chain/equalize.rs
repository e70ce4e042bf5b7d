//! The time-equalised chain M_n^δ (thesis §3.3, eq. 3.8–3.9; paper 001
//! eq. 8) and its propagation operators.
//!
//! ```text
//! p^δ(z | z)  = 1 − δ/Δt(z),     p^δ(z' | z) = (δ/Δt(z)) p(z' | z),     δ ≤ min_z Δt(z)
//! ```
//!
//! Every state then moves on the common clock δ, which the Bayes recursion
//! (eq. 3.6) needs. δ is chosen as δ_max / 2^j (δ_max: the caller's
//! observation period, or any upper bound), the largest such value below
//! every holding time. **Exponential backup** (§3.3.2) under incremental
//! construction: whenever states are (re)connected, δ is halved until it is
//! below the holding time of *every* touched state — the thesis checks only
//! the new state, but reconnected neighbours' Δt shrink too, and one halving
//! may not be enough (notes §1.6 flags). A halving means the p^δ of all
//! states must be recomputed ([`PropagationKernel::rebuild`]); without one,
//! only the touched rows change. The power-of-two form keeps Δ/δ an integer
//! for observations every δ_max.
//!
//! [`PropagationKernel`] stores P^δ in both orientations as flat CSR:
//! incoming edges (for the forward map φ⁻ = (P^δ)ᵀ φ, a gather — no write
//! conflicts, one pass) and optionally outgoing rows (for the backward map
//! P^δ v of the smoother). With the rows it also keeps *push rows*: each
//! row of P^δ with its self-loop folded in as an ordinary (column, weight)
//! entry, first, and left out where p^δ(z|z) = 0 (the advected chain's
//! states without a self-loop), as interleaved (weight, column) pairs. The
//! filter's sparse step ([`PropagationKernel::forward_sparse`]) walks only
//! the rows of the states carrying mass, in one uniform loop that marks the
//! receiving states by an epoch stamp and appends them without a branch.

use super::storage::ChainView;
use super::ChainError;

/// The common time step δ of the equalised chain and its backup rule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeEqualized {
    delta_max: f64,
    delta: f64,
    /// Times δ was halved (each forces a full recomputation of p^δ).
    pub halvings: u64,
}

impl TimeEqualized {
    /// Start with δ = δ_max.
    pub fn new(delta_max: f64) -> Result<Self, ChainError> {
        if !(delta_max.is_finite() && delta_max > 0.0) {
            return Err(ChainError::Delta(delta_max));
        }
        Ok(Self {
            delta_max,
            delta: delta_max,
            halvings: 0,
        })
    }

    /// The current δ.
    pub fn delta(&self) -> f64 {
        self.delta
    }

    /// The upper bound δ_max.
    pub fn delta_max(&self) -> f64 {
        self.delta_max
    }

    /// Batch rule: δ = δ_max/2^j, the largest with δ ≤ min Δt over all
    /// states. Returns whether δ changed.
    pub fn fit(&mut self, holding: &[f64]) -> bool {
        let min = holding.iter().copied().fold(f64::INFINITY, f64::min);
        let old = self.delta;
        self.delta = self.delta_max;
        self.shrink_below(min);
        self.delta != old
    }

    /// Exponential backup after (re)connecting the `touched` slots: halve δ
    /// until δ ≤ Δt(z) for every touched z. Returns whether δ changed (then
    /// every p^δ must be recomputed).
    pub fn backup(&mut self, holding: &[f64], touched: &[u32]) -> bool {
        let min = touched
            .iter()
            .map(|&i| holding[i as usize])
            .fold(f64::INFINITY, f64::min);
        let old = self.delta;
        self.shrink_below(min);
        self.delta != old
    }

    fn shrink_below(&mut self, min: f64) {
        if !(min > 0.0) {
            return;
        }
        while self.delta > min {
            self.delta *= 0.5;
            self.halvings += 1;
        }
    }

    /// p^δ(z | z) = 1 − δ/Δt(z) (1 for an absorbing state).
    pub fn stay(&self, holding: f64) -> f64 {
        (1.0 - self.delta / holding).max(0.0)
    }

    /// Split an interval of length `dt` into whole δ steps and a remaining
    /// fraction of a step.
    pub fn steps(&self, dt: f64) -> (usize, f64) {
        let q = dt / self.delta;
        let whole = (q + 1e-9).floor();
        let frac = (q - whole).max(0.0);
        (whole as usize, if frac < 1e-9 { 0.0 } else { frac })
    }
}

/// P^δ of a chain snapshot as flat CSR, in the orientations the filter and
/// smoother need.
#[derive(Clone, Debug, Default)]
pub struct PropagationKernel {
    n: usize,
    delta: f64,
    stay: Vec<f64>,
    in_off: Vec<u32>,
    in_src: Vec<u32>,
    in_w: Vec<f64>,
    /// Position in the incoming arrays of each CSR edge (row order).
    row_map: Vec<u32>,
    backward: bool,
    row_off: Vec<u32>,
    row_cols: Vec<u32>,
    row_w: Vec<f64>,
    /// Push rows (with the rows): row z = [(p^δ(z|z), z) if > 0] ++ the
    /// CSR row's (p^δ(z'|z), z').
    push_off: Vec<u32>,
    push: Vec<PushEdge>,
}

/// One entry of a push row: weight and target slot, interleaved so a row
/// is one contiguous run of memory.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct PushEdge {
    w: f64,
    col: u32,
}

impl PropagationKernel {
    /// Build P^δ for `view`. δ should not exceed any holding time (see
    /// [`TimeEqualized`]); where it does, the jump rate is capped at 1 so
    /// the matrix stays stochastic.
    pub fn build(view: &ChainView, delta: f64, with_backward: bool) -> Self {
        let mut k = Self::default();
        k.rebuild(view, delta, with_backward);
        k
    }

    /// Rebuild in place (reusing allocations).
    pub fn rebuild(&mut self, view: &ChainView, delta: f64, with_backward: bool) {
        let n = view.len();
        let nnz = view.nnz();
        self.n = n;
        self.delta = delta;
        self.backward = with_backward;
        self.stay.clear();
        self.stay
            .extend(view.holding.iter().map(|&h| (1.0 - delta / h).max(0.0)));
        // incoming CSR by counting sort on the column
        self.in_off.clear();
        self.in_off.resize(n + 1, 0);
        for &c in view.cols {
            self.in_off[c as usize + 1] += 1;
        }
        for i in 0..n {
            self.in_off[i + 1] += self.in_off[i];
        }
        self.in_src.clear();
        self.in_src.resize(nnz, 0);
        self.in_w.clear();
        self.in_w.resize(nnz, 0.0);
        self.row_map.clear();
        self.row_map.resize(nnz, 0);
        let mut fill: Vec<u32> = self.in_off[..n].to_vec();
        for i in 0..n {
            let s = view.row_offsets[i] as usize;
            let e = view.row_offsets[i + 1] as usize;
            let scale = (delta / view.holding[i]).min(1.0);
            for edge in s..e {
                let c = view.cols[edge] as usize;
                let pos = fill[c] as usize;
                fill[c] += 1;
                self.in_src[pos] = i as u32;
                self.in_w[pos] = scale * view.probs[edge];
                self.row_map[edge] = pos as u32;
            }
        }
        if with_backward {
            self.row_off.clear();
            self.row_off.extend_from_slice(view.row_offsets);
            self.row_cols.clear();
            self.row_cols.extend_from_slice(view.cols);
            self.row_w.clear();
            self.row_w.resize(nnz, 0.0);
            for edge in 0..nnz {
                self.row_w[edge] = self.in_w[self.row_map[edge] as usize];
            }
            self.push_off.clear();
            self.push_off.reserve(n + 1);
            self.push_off.push(0);
            self.push.clear();
            self.push.reserve(nnz + n);
            for i in 0..n {
                if self.stay[i] > 0.0 {
                    self.push.push(PushEdge {
                        w: self.stay[i],
                        col: i as u32,
                    });
                }
                let (s, e) = (
                    view.row_offsets[i] as usize,
                    view.row_offsets[i + 1] as usize,
                );
                self.push.extend((s..e).map(|edge| PushEdge {
                    w: self.row_w[edge],
                    col: view.cols[edge],
                }));
                self.push_off.push(self.push.len() as u32);
            }
        }
    }

    /// Replace the jump probabilities (CSR edge order of the view the kernel
    /// was built from) keeping δ and the holding times: used to tilt the
    /// kernel for a control different from the reference one.
    pub fn set_jump_probs(&mut self, holding: &[f64], row_offsets: &[u32], probs: &[f64]) {
        for i in 0..self.n {
            let scale = (self.delta / holding[i]).min(1.0);
            let (s, e) = (row_offsets[i] as usize, row_offsets[i + 1] as usize);
            // the push row's jump entries follow its self-loop entry, if any
            let p0 = if self.backward {
                self.push_off[i + 1] as usize - (e - s)
            } else {
                0
            };
            for edge in s..e {
                let w = scale * probs[edge];
                self.in_w[self.row_map[edge] as usize] = w;
                if self.backward {
                    self.row_w[edge] = w;
                    self.push[p0 + edge - s].w = w;
                }
            }
        }
    }

    /// Number of states.
    pub fn len(&self) -> usize {
        self.n
    }
    /// Whether empty.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    /// δ.
    pub fn delta(&self) -> f64 {
        self.delta
    }
    /// p^δ(z | z) by slot.
    pub fn stay(&self) -> &[f64] {
        &self.stay
    }
    /// Incoming edges as CSR: (offsets n + 1, source slots, p^δ weights).
    pub fn incoming(&self) -> (&[u32], &[u32], &[f64]) {
        (&self.in_off, &self.in_src, &self.in_w)
    }
    /// Whether the backward (row) orientation is stored.
    pub fn has_backward(&self) -> bool {
        self.backward
    }

    /// φ⁻ = (P^δ)ᵀ φ: out(z) = p^δ(z|z) φ(z) + Σ_{z'} p^δ(z|z') φ(z').
    pub fn forward(&self, phi: &[f64], out: &mut [f64]) {
        let n = self.n;
        assert!(phi.len() >= n && out.len() >= n);
        let phi = &phi[..n];
        for z in 0..n {
            let s = self.in_off[z] as usize;
            let e = self.in_off[z + 1] as usize;
            let mut acc = self.stay[z] * phi[z];
            for (w, &src) in self.in_w[s..e].iter().zip(&self.in_src[s..e]) {
                // SAFETY: `rebuild` writes only row indices i < n into
                // `in_src` (it enumerates the rows of a view with n rows),
                // and `phi` has length n.
                acc += w * unsafe { *phi.get_unchecked(src as usize) };
            }
            out[z] = acc;
        }
    }

    /// A fraction θ ∈ [0, 1] of one step: out = (1 − θ) φ + θ (P^δ)ᵀ φ,
    /// i.e. the equalised chain with step θδ (valid since θδ ≤ δ).
    pub fn forward_fraction(&self, theta: f64, phi: &[f64], out: &mut [f64]) {
        self.forward(phi, out);
        for z in 0..self.n {
            out[z] = (1.0 - theta) * phi[z] + theta * out[z];
        }
    }

    /// Sparse form of [`Self::forward_fraction`] over the support: for
    /// every slot z in `active` (each slot with φ ≠ 0 must be listed, once)
    /// pushes (1 − θ) φ(z) to z and θ φ(z) along z's push row (P^δ with its
    /// self-loop) into `out`, which must be all zero on entry, and zeroes
    /// φ(z) — so on return `phi` is all zero and `out` holds
    /// (1 − θ) φ + θ (P^δ)ᵀ φ. The slots receiving mass are written to
    /// `next` (once each, in order of first arrival; for θ = 1 a slot
    /// without self-loop that receives nothing is left out). `seen` is the
    /// epoch stamp of each slot: every entry must differ from `epoch` on
    /// entry, and the received slots carry `epoch` on return (the caller
    /// advances `epoch` per call, so nothing is cleared). Cost
    /// O(|active| · out-degree) instead of O(nnz), no allocation once
    /// `next` has capacity n + 1. Requires the backward (row) orientation.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_sparse(
        &self,
        theta: f64,
        phi: &mut [f64],
        active: &[u32],
        out: &mut [f64],
        next: &mut Vec<u32>,
        seen: &mut [u32],
        epoch: u32,
    ) {
        assert!(self.backward, "kernel built without rows");
        let n = self.n;
        assert!(phi.len() >= n && out.len() >= n && seen.len() >= n);
        next.clear();
        next.reserve(n + 1);
        let base = next.as_mut_ptr();
        let mut len = 0usize;
        let keep = 1.0 - theta;
        for &z in active {
            let zi = z as usize;
            assert!(zi < n, "active slot {zi} out of range");
            let v = phi[zi];
            if v == 0.0 {
                continue;
            }
            phi[zi] = 0.0;
            // SAFETY (this block and the loop below): every index is a slot
            // < n — zi checked above, and `col` was written by `rebuild`
            // from a view column, which indexed `in_off` (length n + 1) there
            // so it is < n; `out` and `seen` have length ≥ n. `next` has
            // capacity ≥ n + 1 and `len` counts distinct slots (each slot's
            // stamp is set to `epoch` when it is first counted), so
            // len ≤ n and the write at `base + len` is in bounds.
            unsafe {
                if keep > 0.0 {
                    *base.add(len) = z;
                    len += (*seen.get_unchecked(zi) != epoch) as usize;
                    *seen.get_unchecked_mut(zi) = epoch;
                    *out.get_unchecked_mut(zi) += keep * v;
                }
                let s = *self.push_off.get_unchecked(zi) as usize;
                let e = *self.push_off.get_unchecked(zi + 1) as usize;
                let tv = theta * v;
                for edge in self.push.get_unchecked(s..e) {
                    let c = edge.col as usize;
                    // branch-free append: write, count it if not yet seen
                    *base.add(len) = edge.col;
                    len += (*seen.get_unchecked(c) != epoch) as usize;
                    *seen.get_unchecked_mut(c) = epoch;
                    *out.get_unchecked_mut(c) += edge.w * tv;
                }
            }
        }
        // SAFETY: the first `len` entries were written above, len ≤ n + 1
        // ≤ capacity.
        unsafe { next.set_len(len) };
    }

    /// P^δ v: out(z) = p^δ(z|z) v(z) + Σ_{z'} p^δ(z'|z) v(z'). Requires
    /// the backward orientation.
    pub fn backward(&self, v: &[f64], out: &mut [f64]) {
        assert!(self.backward, "kernel built without backward rows");
        let n = self.n;
        for z in 0..n {
            let s = self.row_off[z] as usize;
            let e = self.row_off[z + 1] as usize;
            let mut acc = self.stay[z] * v[z];
            for (w, &c) in self.row_w[s..e].iter().zip(&self.row_cols[s..e]) {
                acc += w * v[c as usize];
            }
            out[z] = acc;
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.stay.capacity() * 8
            + self.in_off.capacity() * 4
            + self.in_src.capacity() * 4
            + self.in_w.capacity() * 8
            + self.row_map.capacity() * 4
            + self.row_off.capacity() * 4
            + self.row_cols.capacity() * 4
            + self.row_w.capacity() * 8
            + self.push_off.capacity() * 4
            + self.push.capacity() * std::mem::size_of::<PushEdge>()
    }
}

#[cfg(test)]
#[path = "equalize_tests.rs"]
mod tests;
