//! The Bayes update on the active version and its recoveries:
//!
//! ```text
//! φ(z) ∝ p(y | z) φ(z),  p(y | z) = Π_{i∈mask} N(y_i; g_i(z), σ_i²)
//! ```
//!
//! with the posterior flushed below a relative threshold, its moments
//! accumulated in the same pass, a re-spread from the inflated predicted
//! Gaussian (then from the chain's volumes) when no state with mass
//! explains y, and the optional re-anchoring of a collapsed posterior.
//!
//! An update *collapses* (counted in `collapses`, see
//! [`crate::filter::regularise`]) when it needed a re-spread or refused,
//! or when the reweighting kept less than a fraction f of the predicted
//! mass's effective support, ρ = (Σφ p)² / (Σφ · Σφ p²) < f — the PF's
//! ESS/N, independent of how finely the chain resolves the belief.

use super::mass::{gaussian_log_weight, ObsTerms};
use super::{frame_of, LiveChainFilter, FLUSH, RESPREAD_INFLATE};
use crate::belief::{Gaussian, WeightedMoments};
use crate::chain::snapshot::SnapshotView;
use crate::filter::{check_measurement, FilterError, UpdateInfo};
use crate::math::linalg::cholesky;
use crate::model::{Measurement, SdeModel};
use crate::{MAX_OBS, MAX_STATE};

impl<M: SdeModel, S: AsRef<[u64]>> LiveChainFilter<M, S> {
    /// Restart from N(mean, cov) at `t` (on the active chain, else in the
    /// fallback).
    pub fn reset(&mut self, t: f64, prior: &Gaussian) {
        self.t = t;
        self.last = *prior;
        self.fallback.reset(t, prior);
        if let Some(act) = self.active.as_ref() {
            let view = act.snap.view();
            if self.moving {
                let (_, c) = frame_of(&self.model, &view, &self.u_ref);
                for k in 0..self.dims.state {
                    self.frame_d[k] = prior.mean[k] - c[k];
                }
            }
            let h = self.in_mass_coordinates(prior);
            gaussian_weights(&view, &h, &mut self.phi);
            self.pending_d = [0.0; MAX_STATE];
        }
        self.belief.set(None);
        self.mass_mean = None;
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
        let respreads = self.respreads;
        let view = act.snap.view();
        let g_z = &self.obs_mean[act.buf];
        let (m, d) = (self.dims.obs, self.dims.state);
        let (lk, cst) = ObsTerms::new(&self.model, meas);
        let sh = self.shift();
        let y = self.observation_on_mass(&view, meas, &sh);
        let (phi, aux, tmp) = (&mut self.phi, &mut self.aux, &mut self.tmp);
        let mut r = weigh(&self.model, g_z, phi, aux, tmp, &lk, &y[..m]);
        if r.is_none() {
            // Re-spread from the predicted Gaussian, std inflated.
            let h = self.respread_gaussian(&view);
            gaussian_weights(&view, &h, &mut self.phi);
            self.pending_d = [0.0; MAX_STATE];
            self.respreads += 1;
            let (phi, aux, tmp) = (&mut self.phi, &mut self.aux, &mut self.tmp);
            r = weigh(&self.model, g_z, phi, aux, tmp, &lk, &meas.y[..m]);
        }
        if r.is_none() {
            // Last resort: φ ∝ vol(z), the chain's uniform density.
            let s: f64 = view.volume.iter().map(|v| v.max(0.0)).sum();
            for (p, v) in self.phi.iter_mut().zip(view.volume) {
                *p = if s > 0.0 { v.max(0.0) / s } else { 1.0 };
            }
            self.pending_d = [0.0; MAX_STATE];
            self.respreads += 1;
            let (phi, aux, tmp) = (&mut self.phi, &mut self.aux, &mut self.tmp);
            r = weigh(&self.model, g_z, phi, aux, tmp, &lk, &meas.y[..m]);
        }
        let Some((lmax, sum, tmax, kept)) = r else {
            // No state of the chain at all (cannot happen on a parsed
            // snapshot): keep the prediction.
            self.collapses += 1;
            self.mass_mean = None;
            self.last = self.moments(&view);
            self.belief.set(None);
            return Err(FilterError::Degenerate);
        };
        if self.respreads > respreads || kept < self.collapse_fraction {
            self.collapses += 1;
        }
        let inv = 1.0 / sum;
        let thr = FLUSH.max(self.flush_rel * tmax * inv);
        let centre = &self.last.mean[..d];
        let (tmp, phi) = (&self.tmp, &mut self.phi);
        let (acc, s2, heaviest) = match d {
            2 => flush_pass::<2>(&view, tmp, phi, centre, thr, inv),
            3 => flush_pass::<3>(&view, tmp, phi, centre, thr, inv),
            4 => flush_pass::<4>(&view, tmp, phi, centre, thr, inv),
            _ => flush_pass::<0>(&view, tmp, phi, centre, thr, inv),
        };
        let mut g = acc.gaussian();
        if 1.0 / s2 < self.reanchor_ess {
            if let Some(h) = self.reanchor_gaussian(&view, &g, heaviest) {
                gaussian_weights(&view, &h, &mut self.phi);
                self.reanchors += 1;
                g = h;
            }
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

    /// The observation as the mass sees it: the mass sits at z, the belief
    /// at z + D (D = `sh`, the displacement not yet transported and the
    /// frame's), so y − (g(x̂ + D) − g(x̂)) is compared with g(z).
    fn observation_on_mass(
        &self,
        view: &SnapshotView,
        meas: &Measurement,
        sh: &[f64; MAX_STATE],
    ) -> [f64; MAX_OBS] {
        let (m, d) = (self.dims.obs, self.dims.state);
        let mut y = [0.0; MAX_OBS];
        y[..m].copy_from_slice(&meas.y[..m]);
        if sh[..d].iter().all(|v| *v == 0.0) {
            return y;
        }
        // The linearisation point: the mass mean of the last posterior
        // (one prediction old: the error is second order in D).
        let x0 = match self.mass_mean {
            Some(m) => m,
            None => {
                let mut m = self.moments(view).mean;
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
        y
    }

    /// `g` (belief coordinates) in the mass's coordinates: the mass at z
    /// stands for z + F.
    fn in_mass_coordinates(&self, g: &Gaussian) -> Gaussian {
        let mut h = *g;
        for k in 0..self.dims.state {
            h.mean[k] -= self.frame_d[k];
        }
        h
    }

    /// The Gaussian a degenerate update re-spreads from (mass coordinates):
    /// the moments of the current mass, or the last posterior when no mass
    /// is left, with the std inflated by `RESPREAD_INFLATE`.
    fn respread_gaussian(&self, view: &SnapshotView) -> Gaussian {
        let mass: f64 = self.phi.iter().sum();
        let mut g = if mass > 0.0 && mass.is_finite() {
            self.moments(view)
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
        self.in_mass_coordinates(&g)
    }

    /// The posterior's support collapsed to a few states (effective number
    /// 1/Σφ² below `reanchor_ess`): the chain cannot resolve it, and a
    /// belief held on one or two states neither moves with the next
    /// observations nor admits its error (NEES ≫ d). The mass is re-spread
    /// from N(x̂, P̂ + C/4), C the second moment of the displacements from
    /// the heaviest state z* to its Near set (its transition row): the
    /// chain's local resolution. Returns that belief (the mean is the
    /// posterior's), None when it is not finite (the posterior is kept).
    /// Counted in [`Self::reanchors`].
    fn reanchor_gaussian(&self, view: &SnapshotView, g: &Gaussian, zs: usize) -> Option<Gaussian> {
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
        h.is_finite().then_some(h)
    }
}

/// The posterior φ = tmp·inv with masses below `thr` flushed to zero, and
/// in the same pass its moments (centred at `centre`), Σφ² and the
/// heaviest state. `D` is the state dimension when known at compile time
/// (0: read at run time); the sums are the same either way.
fn flush_pass<const D: usize>(
    view: &SnapshotView,
    tmp: &[f64],
    phi: &mut [f64],
    centre: &[f64],
    thr: f64,
    inv: f64,
) -> (WeightedMoments, f64, usize) {
    let mut acc = WeightedMoments::new(centre);
    let mut s2 = 0.0;
    let mut heaviest = (0.0, 0usize);
    for z in 0..phi.len() {
        let mut w = tmp[z] * inv;
        if w < thr {
            w = 0.0;
        } else {
            s2 += w * w;
            if D == 0 {
                acc.add(w, view.state(z));
            } else {
                acc.add_fixed::<D>(w, view.state(z));
            }
            if w > heaviest.0 {
                heaviest = (w, z);
            }
        }
        phi[z] = w;
    }
    (acc, s2, heaviest.1)
}

/// tmp ← φ(z)·p(y|z)/exp(l_max) over the states with mass (`g_z` their
/// observation means, `aux` scratch); returns (l_max, Σ tmp, max tmp, ρ)
/// with ρ = (Σφp)²/(Σφ·Σφp²) the fraction of effective support kept, or
/// None when nothing is left (degenerate).
fn weigh<M: SdeModel>(
    model: &M,
    g_z: &[f64],
    phi: &[f64],
    aux: &mut Vec<f64>,
    tmp: &mut Vec<f64>,
    lk: &ObsTerms,
    y: &[f64],
) -> Option<(f64, f64, f64, f64)> {
    let m = model.dims().obs;
    let n = phi.len();
    aux.clear();
    aux.resize(n, f64::NEG_INFINITY);
    let mut r = [0.0; MAX_OBS];
    let mut lmax = f64::NEG_INFINITY;
    for z in 0..n {
        if phi[z] == 0.0 {
            continue;
        }
        let l = lk.log_lik(model, y, &g_z[z * m..(z + 1) * m], &mut r[..m]);
        aux[z] = l;
        lmax = lmax.max(l);
    }
    let (mut sum, mut tmax, mut mass, mut sq) = (0.0, 0.0f64, 0.0, 0.0);
    tmp.clear();
    tmp.resize(n, 0.0);
    if lmax.is_finite() {
        for z in 0..n {
            let a = aux[z] - lmax;
            let e = if a > -700.0 { a.exp() } else { 0.0 };
            let w = phi[z] * e;
            tmp[z] = w;
            sum += w;
            // φ·p² (scaled like w): the likelihood's second moment.
            sq += w * e;
            mass += phi[z];
            tmax = tmax.max(w);
        }
    }
    let kept = sum * sum / (mass * sq);
    (sum > 0.0 && sum.is_finite()).then_some((lmax, sum, tmax, kept))
}

/// φ(z) ∝ N(z; g)·vol(z) on the states of `view` (mass coordinates), into
/// `out`; a singular covariance puts all mass on the nearest state.
pub(super) fn gaussian_weights(view: &SnapshotView, g: &Gaussian, out: &mut [f64]) {
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
        let lw = gaussian_log_weight(&l[..d * d], &g.mean[..d], view.state(i), view.volume[i]);
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
