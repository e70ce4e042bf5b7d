//! New versions: a received snapshot is prepared in chunks within a time
//! budget per call while the filter runs on the active one — phase 1
//! validates its index structure and computes the observation means g(z)
//! (and, in the moving frame, Σ f(z, u₀) and Σ z); phase 2 computes the
//! control's transport rates (or, in the moving frame, the weights that
//! install the belief) — then the swap remaps the belief by state id as a
//! density ρ = φ/vol, new states taking the mean density of their Near set
//! (the thesis's `ApproximateDensity`, §3.5).

use std::time::{Duration, Instant};

use super::mass::gaussian_log_weight;
use super::update::gaussian_weights;
use super::{frame_of, Active, LiveChainFilter, Pending, Progress, SwapInfo, CHUNK};
use crate::chain::snapshot::{HeldSnapshot, SnapshotError, SnapshotView};
use crate::math::linalg::cholesky;
use crate::model::SdeModel;
use crate::MAX_STATE;

impl<M: SdeModel, S: AsRef<[u64]>> LiveChainFilter<M, S> {
    /// Hand over a received snapshot; it replaces a pending one (which is
    /// released). The active snapshot is untouched until the swap.
    pub fn offer(&mut self, snap: S) -> Result<(), SnapshotError> {
        let snap = HeldSnapshot::new(snap)?;
        let v = snap.view();
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
            prog: Progress {
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
            },
        });
        Ok(())
    }

    /// Prepare the pending version for at most about `budget` (one chunk at
    /// least) and swap to it once it is ready. A snapshot that fails
    /// validation is dropped with the error.
    pub fn advance(&mut self, budget: Duration) -> Result<Option<SwapInfo>, SnapshotError> {
        let Some(mut p) = self.pending.take() else {
            return Ok(None);
        };
        let t0 = Instant::now();
        let view = p.snap.view();
        let ready = self.obs_means_phase(&mut p.prog, &view, t0, budget)?
            && (!self.moving || self.frame_weights_phase(&mut p.prog, &view, t0, budget))
            && self.transport_phase(&mut p.prog, &view, t0, budget);
        p.prog.prepare_ns += t0.elapsed().as_nanos() as u64;
        if ready {
            Ok(Some(self.swap(p)))
        } else {
            self.pending = Some(p);
            Ok(None)
        }
    }

    /// Phase 1: validate rows and compute g(z) (and the moving frame's
    /// sums) chunk by chunk. True when done; false when the budget ran out
    /// after a chunk (even the last one: the next call starts phase 2).
    fn obs_means_phase(
        &mut self,
        p: &mut Progress,
        view: &SnapshotView,
        t0: Instant,
        budget: Duration,
    ) -> Result<bool, SnapshotError> {
        let m = self.dims.obs;
        let n = view.len();
        let g = &mut self.obs_mean[p.buf];
        if p.next == 0 {
            g.clear();
            g.resize(n * m, 0.0);
        }
        while p.next < n {
            let hi = (p.next + CHUNK).min(n);
            view.validate_rows(p.next, hi)?;
            for i in p.next..hi {
                self.model
                    .obs_mean(view.state(i), &mut g[i * m..(i + 1) * m]);
            }
            if self.moving {
                let (d, nu) = (self.dims.state, self.dims.control);
                let mut f = [0.0; MAX_STATE];
                for i in p.next..hi {
                    let z = view.state(i);
                    self.model.drift(z, &self.u_ref[..nu], &mut f[..d]);
                    for a in 0..d {
                        p.frame_sums.0[a] += f[a];
                        p.frame_sums.1[a] += z[a];
                    }
                }
            }
            p.next = hi;
            if t0.elapsed() >= budget {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// Phase 2 of a moving-frame version (no control transport on those):
    /// the log-weights ln N(z; c, P̂) + ln vol(z) that install the belief on
    /// the version (c the mean of its states, P̂ the belief covariance when
    /// the phase started), then their exponentials, sum and weighted mean
    /// (see `install_framed`), so the swap only normalises them. True when
    /// done.
    fn frame_weights_phase(
        &mut self,
        p: &mut Progress,
        view: &SnapshotView,
        t0: Instant,
        budget: Duration,
    ) -> bool {
        let d = self.dims.state;
        let n = view.len();
        if p.next_tr == 0 {
            // The belief is cached after each update.
            let g = self.belief();
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
                    let lw =
                        gaussian_log_weight(&l[..d * d], &c[..d], view.state(i), view.volume[i]);
                    self.pre_w[i] = lw;
                    p.lw_max = p.lw_max.max(lw);
                }
                p.next_tr = hi;
                if t0.elapsed() >= budget && p.next_tr < n {
                    return false;
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
                    return false;
                }
            }
        }
        p.next_tr = n;
        true
    }

    /// Phase 2: the control's transport rates of this version (off the
    /// per-observation path), reused by id from the active version where
    /// their targets survive, else solved; in pieces of 16 states. True
    /// when done (at once for a moving-frame version: its `next_tr` is n).
    fn transport_phase(
        &mut self,
        p: &mut Progress,
        view: &SnapshotView,
        t0: Instant,
        budget: Duration,
    ) -> bool {
        let n = view.len();
        if !p.mapped {
            self.transport[p.buf].reset(n);
            p.reuse = false;
            if let Some(act) = self.active.as_ref().filter(|a| a.lineage == view.lineage) {
                let old = act.snap.view();
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
            cur.prepare_state(view, z, &self.ctrl_slots, old);
            p.next_tr += 1;
            if p.next_tr.is_multiple_of(16) && t0.elapsed() >= budget && p.next_tr < n {
                return false;
            }
        }
        true
    }

    /// Moving frame: the version's masses from the weights prepared in
    /// phase 2 (so that the swap is one normalising pass), φ(z) ∝
    /// N(z; c, P̂)·vol(z) — the belief N(x̂, P̂) seen from the
    /// frame F = x̂ − c, c the mean of the version's states, with P̂ the
    /// belief covariance when phase 2 started (a few observations before
    /// the swap) — into `tmp`; sets the frame. False when P̂ was not
    /// positive definite (the caller installs from the Gaussian).
    fn install_framed(&mut self, p: &Progress, n: usize) -> bool {
        if p.chol.is_none() {
            return false;
        }
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

    /// Install the prepared version `p`: its masses into φ (remapped by id,
    /// from the prepared frame weights, or from the Gaussian belief), O(n_old
    /// + n_new).
    fn swap(&mut self, p: Pending<S>) -> SwapInfo {
        let t0 = Instant::now();
        let newv = p.snap.view();
        let n_new = newv.len();
        let mut mass_lost = 0.0;
        let mut from_gaussian = true;
        // tmp ← new masses
        self.tmp.clear();
        self.tmp.resize(n_new, 0.0);
        // Moving frame: installed from the prepared weights.
        let framed = self.moving && self.install_framed(&p.prog, n_new);
        if !framed {
            if let Some((lost, installed)) = self.remap_by_id(&newv) {
                mass_lost = lost;
                from_gaussian = !installed;
            }
        }
        if from_gaussian && !framed {
            let g = self.belief_now();
            let mut h = g;
            if self.moving {
                let (w, c) = frame_of(&self.model, &newv, &self.u_ref);
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
        let (version, delta, lineage) = (newv.version, newv.delta, newv.lineage);
        self.active = Some(Active {
            snap: p.snap,
            buf: p.prog.buf,
            lineage,
        });
        self.belief.set(None);
        self.mass_mean = None;
        self.versions += 1;
        SwapInfo {
            version,
            states: n_new,
            delta,
            mass_lost,
            from_gaussian,
            swap_ns: t0.elapsed().as_nanos() as u64,
            prepare_ns: p.prog.prepare_ns,
        }
    }

    /// `tmp` ← the belief on `newv` remapped from the active version of
    /// the same lineage: kept ids keep their density φ/vol, a new state
    /// gets the mean density over its Near set's kept states; normalised.
    /// Returns the mass on retired states and whether the remap installed
    /// a belief (false: no mass left), None without an active version of
    /// that lineage.
    fn remap_by_id(&mut self, newv: &SnapshotView) -> Option<(f64, bool)> {
        let act = self.active.as_ref().filter(|a| a.lineage == newv.lineage)?;
        let old = act.snap.view();
        let (n_old, n_new) = (old.len(), newv.len());
        let mut mass_lost = 0.0;
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
        if !(s > 0.0 && s.is_finite()) {
            return Some((mass_lost, false));
        }
        for v in &mut self.tmp {
            *v /= s;
        }
        Some((mass_lost, true))
    }
}
