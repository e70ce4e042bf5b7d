//! The re-centred chain filter: one chain built once in a local frame,
//! carried along with the belief by a frame displacement c, and the belief
//! re-installed on it at a fixed rate — no chain build per observation.
//!
//! Mass φ at the local state z stands for the world state x = c + z. The
//! chain is built for the model itself on states around the local origin;
//! the frame moves with what the chain does not model,
//!
//! ```text
//! dc/dt = f(z̄ + c, u) − f(z̄, u₀),     z̄ = Σ φ(z) z   (local mass mean)
//! ```
//!
//! exact for every state when f(z + c, u) − f(z, u₀) does not depend on z:
//! an affine drift (linear SDEs; the drifting ship of paper 001 eq. 10–11
//! inside the disc, whose positions integrate the velocities, so a
//! Galilean frame carries every state alike), first order otherwise. The
//! diffusion must not depend on the state (additive noise) for the chain's
//! rows to hold wherever the frame is. One Heun step per prediction, as in
//! the live filter's moving frame ([`crate::filter::live_chain`]).
//!
//! ```text
//! predict over Δ:  φ ← ((P^δ)ᵀ)^{⌊Δ/δ⌋} φ (then a fraction of a step),  c ← c + ∫ dc/dt
//! update:          φ(z) ∝ p(y | c + z) φ(z)     (g evaluated at the world state)
//! estimate:        x̂ = c + Σ φ z,   P̂ = Σ φ (z − z̄)(z − z̄)ᵀ
//! install N(x̂, P̂): φ(z) ∝ N(z; m_q, P̂) / q(z)   (importance, q = N(m_q, Σ_q))
//!                  φ(z) ∝ N(z; m_q, P̂) · vol(z)  (cell volumes)
//!                  then c = x̂ − Σ φ z, so the mean does not jump
//! ```
//!
//! q is the law the chain's states were drawn from (thesis §2.2's sampling
//! density, here a Gaussian in the local frame). Cell volumes r(z)^d/|Near|
//! estimate 1/(n q(z)) from k-NN distances, noisily with a few hundred
//! states; the importance weight uses q itself (measured on the ship:
//! `docs/ship-state-counts.md`). The install runs before the prediction
//! every `every` predictions, and additionally whenever the mass's
//! effective number of states 1/Σφ² falls below `ess_fraction` × n. Between
//! installs the chain carries the belief's non-Gaussian shape; at an
//! install it is summarised by its first two moments (an assumed-density
//! step with the chain as quadrature).
//!
//! An update that no state explains is retried once on the predicted
//! Gaussian installed with its covariance inflated ×4, and counted
//! ([`RecentredChainFilter::respreads`]); collapses (kept effective support
//! below 1 %, or refused) count as in the batch filter.

use std::cell::Cell;

use crate::belief::{Gaussian, WeightedMoments};
use crate::chain::{Chain, ChainError, PropagationKernel, TimeEqualized};
use crate::filter::live_chain::mass::{gaussian_log_weight, ObsTerms};
use crate::filter::{check_measurement, check_predict, BayesFilter, FilterError, UpdateInfo};
use crate::math::linalg::cholesky;
use crate::model::{Dims, Measurement, SdeModel};
use crate::{MAX_CONTROL, MAX_OBS, MAX_STATE};

/// How a Gaussian belief is put on the chain's states.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Install {
    /// φ ∝ N(z; m, P)/q(z), q the states' sampling law.
    Importance,
    /// φ ∝ N(z; m, P)·vol(z), the chain's k-NN cell volumes.
    Volume,
}

/// Settings of a [`RecentredChainFilter`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecentredConfig {
    /// Re-install the belief every this many predictions (≥ 1).
    pub every: usize,
    /// Re-install also when 1/Σφ² < `ess_fraction` · n (0: never).
    pub ess_fraction: f64,
    pub install: Install,
    /// Corrections of the installed covariance (see `install`; 0: none).
    pub cov_match: usize,
}

impl Default for RecentredConfig {
    fn default() -> Self {
        // the ship's measured choice (docs/ship-state-counts.md, section 4)
        Self {
            every: 10,
            ess_fraction: 0.0,
            install: Install::Importance,
            cov_match: 2,
        }
    }
}

/// Variance inflation of the re-spread after an update no state explains.
const RESPREAD_VAR: f64 = 4.0;
/// Kept effective support below which an update counts as collapsed.
const COLLAPSE_FRACTION: f64 = crate::filter::regularise::DEFAULT_COLLAPSE_FRACTION;

/// The re-centred chain filter (see the module doc).
pub struct RecentredChainFilter<M: SdeModel> {
    model: M,
    dims: Dims,
    chain: Chain,
    eq: TimeEqualized,
    kern: PropagationKernel,
    cfg: RecentredConfig,
    /// Mean of the sampling law and log q(z) of every state (up to a constant).
    q_mean: [f64; MAX_STATE],
    log_q: Vec<f64>,
    u0: [f64; MAX_CONTROL],
    c: [f64; MAX_STATE],
    phi: Vec<f64>,
    tmp: Vec<f64>,
    t: f64,
    since: usize,
    /// Local mass mean and covariance of the current φ.
    local: Cell<Option<Gaussian>>,
    installs: u64,
    respreads: u64,
    collapses: u64,
}

impl<M: SdeModel> RecentredChainFilter<M> {
    /// A filter on `chain` (built for `model` on states drawn from
    /// `sampling`, in the local frame) with δ ≤ `delta_max`. The belief
    /// starts on the sampling law's mean; call [`BayesFilter::reset`].
    pub fn new(
        model: M,
        mut chain: Chain,
        sampling: &Gaussian,
        delta_max: f64,
        cfg: RecentredConfig,
    ) -> Result<Self, ChainError> {
        let dims = model.dims();
        let d = dims.state;
        if chain.dim() != d || sampling.dim != d {
            return Err(ChainError::Dimension(chain.dim()));
        }
        if cfg.every == 0 || !(0.0..=1.0).contains(&cfg.ess_fraction) {
            return Err(ChainError::Config(
                "re-centred chain: every must be ≥ 1 and ess_fraction in [0, 1]",
            ));
        }
        let mut eq = TimeEqualized::new(delta_max)?;
        eq.fit(chain.holding());
        let kern = PropagationKernel::build(&chain.view(), eq.delta(), false);
        let n = chain.len();
        let mut l = [0.0; MAX_STATE * MAX_STATE];
        l[..d * d].copy_from_slice(sampling.cov());
        if !cholesky(&mut l[..d * d], d) {
            return Err(ChainError::Config(
                "re-centred chain: the sampling covariance must be positive definite",
            ));
        }
        let log_q = (0..n)
            .map(|i| gaussian_log_weight(&l[..d * d], &sampling.mean[..d], chain.state(i), 1.0))
            .collect();
        let mut q_mean = [0.0; MAX_STATE];
        q_mean[..d].copy_from_slice(&sampling.mean[..d]);
        let mut u0 = [0.0; MAX_CONTROL];
        u0[..dims.control].copy_from_slice(chain.reference_control());
        let mut f = Self {
            model,
            dims,
            chain,
            eq,
            kern,
            cfg,
            q_mean,
            log_q,
            u0,
            c: [0.0; MAX_STATE],
            phi: vec![0.0; n],
            tmp: vec![0.0; n],
            t: 0.0,
            since: 0,
            local: Cell::new(None),
            installs: 0,
            respreads: 0,
            collapses: 0,
        };
        f.install(sampling).then_some(f).ok_or(ChainError::Config(
            "re-centred chain: the sampling law puts no mass on the states",
        ))
    }

    /// The chain (local frame).
    pub fn chain(&self) -> &Chain {
        &self.chain
    }
    /// The frame displacement c (world = c + local).
    pub fn frame(&self) -> &[f64] {
        &self.c[..self.dims.state]
    }
    /// The equalised step δ.
    pub fn delta(&self) -> f64 {
        self.eq.delta()
    }
    /// Installs of a Gaussian belief so far (re-installs and resets).
    pub fn installs(&self) -> u64 {
        self.installs
    }
    /// Updates no state explained (retried on the inflated prediction).
    pub fn respreads(&self) -> u64 {
        self.respreads
    }
    /// Updates that collapsed (see the module doc).
    pub fn collapses(&self) -> u64 {
        self.collapses
    }

    /// Put N(g) on the states (see the module doc); false (φ unchanged)
    /// when the covariance is not positive definite or no state gets mass.
    /// With `cov_match` > 0 the Gaussian's covariance is corrected that many
    /// times, P ← P + (P̂ − S), S the installed mass's covariance, so that
    /// the mass keeps P̂: a weighted covariance of a few effective states
    /// is biased low (≈ (1 − 1/ESS) P̂), and re-installed at every step that
    /// shrinkage compounds into an over-confident filter.
    fn install(&mut self, g: &Gaussian) -> bool {
        let d = self.dims.state;
        if !g.is_finite() || !self.weights_for(g.cov()) {
            return false;
        }
        let mut p = [0.0; MAX_STATE * MAX_STATE];
        p[..d * d].copy_from_slice(g.cov());
        for _ in 0..self.cfg.cov_match {
            let s = self.local_moments();
            let mut next = p;
            for k in 0..d * d {
                next[k] += g.cov()[k] - s.cov()[k];
            }
            if !self.weights_for(&next[..d * d]) {
                // keep the last weights (weights_for left φ unchanged)
                break;
            }
            p = next;
        }
        let lm = self.local_moments();
        for a in 0..d {
            self.c[a] = g.mean[a] - lm.mean[a];
        }
        self.since = 0;
        self.installs += 1;
        true
    }

    /// φ ← the install weights of N(m_q, cov) (φ unchanged and false when
    /// `cov` is not positive definite).
    fn weights_for(&mut self, cov: &[f64]) -> bool {
        let d = self.dims.state;
        let mut l = [0.0; MAX_STATE * MAX_STATE];
        l[..d * d].copy_from_slice(&cov[..d * d]);
        if !cholesky(&mut l[..d * d], d) {
            return false;
        }
        let n = self.chain.len();
        let mut lmax = f64::NEG_INFINITY;
        for i in 0..n {
            let z = self.chain.state(i);
            let lw = match self.cfg.install {
                Install::Importance => {
                    gaussian_log_weight(&l[..d * d], &self.q_mean[..d], z, 1.0) - self.log_q[i]
                }
                Install::Volume => gaussian_log_weight(
                    &l[..d * d],
                    &self.q_mean[..d],
                    z,
                    self.chain.cell_volume(i),
                ),
            };
            self.tmp[i] = lw;
            lmax = lmax.max(lw);
        }
        if !lmax.is_finite() {
            self.tmp.fill(0.0);
            return false;
        }
        let mut s = 0.0;
        for i in 0..n {
            let w = (self.tmp[i] - lmax).exp();
            self.tmp[i] = w;
            s += w;
        }
        let inv = 1.0 / s;
        for i in 0..n {
            self.phi[i] = self.tmp[i] * inv;
            self.tmp[i] = 0.0;
        }
        self.invalidate();
        true
    }

    /// Local mean and covariance of φ (cached until φ changes).
    fn local_moments(&self) -> Gaussian {
        if let Some(g) = self.local.get() {
            return g;
        }
        let d = self.dims.state;
        let mut acc = WeightedMoments::new(&self.q_mean[..d]);
        for (i, &w) in self.phi.iter().enumerate() {
            if w != 0.0 {
                acc.add(w, self.chain.state(i));
            }
        }
        let g = acc.gaussian();
        self.local.set(Some(g));
        g
    }

    /// The update's last pass: φ ← tmp·inv (tmp zeroed), Σφ² and the local
    /// moments. `D` is the state dimension (0: read at run time).
    fn normalise_pass<const D: usize>(&mut self, inv: f64) -> (f64, WeightedMoments) {
        let d = self.dims.state;
        let mut acc = WeightedMoments::new(&self.q_mean[..d]);
        let mut s2 = 0.0;
        for i in 0..self.phi.len() {
            let p = self.tmp[i] * inv;
            self.phi[i] = p;
            self.tmp[i] = 0.0;
            if p != 0.0 {
                s2 += p * p;
                if D == 0 {
                    acc.add(p, self.chain.state(i));
                } else {
                    acc.add_fixed::<D>(p, self.chain.state(i));
                }
            }
        }
        (s2, acc)
    }

    fn invalidate(&mut self) {
        self.local.set(None);
    }

    /// c over `dt` with `u` held: one Heun step of dc/dt (module doc).
    fn move_frame(&mut self, u: &[f64], dt: f64) {
        let d = self.dims.state;
        let nu = self.dims.control;
        let zb = self.local_moments().mean;
        let rate = |c: &[f64; MAX_STATE], z: &[f64; MAX_STATE], r: &mut [f64; MAX_STATE]| {
            let (mut x, mut f0) = ([0.0; MAX_STATE], [0.0; MAX_STATE]);
            for a in 0..d {
                x[a] = z[a] + c[a];
            }
            self.model.drift(&x[..d], u, &mut r[..d]);
            self.model.drift(&z[..d], &self.u0[..nu], &mut f0[..d]);
            for a in 0..d {
                r[a] -= f0[a];
            }
            f0
        };
        let (mut k1, mut k2) = ([0.0; MAX_STATE], [0.0; MAX_STATE]);
        let f0 = rate(&self.c, &zb, &mut k1);
        let (mut c1, mut z1) = (self.c, zb);
        for a in 0..d {
            c1[a] += k1[a] * dt;
            z1[a] += f0[a] * dt;
        }
        rate(&c1, &z1, &mut k2);
        for a in 0..d {
            let r = 0.5 * (k1[a] + k2[a]);
            if r.is_finite() {
                self.c[a] += r * dt;
            }
        }
    }

    /// The weighting pass: tmp ← φ·p(y | c + z)·e^{−shift}; returns
    /// (Σ, Σφ, Σφp², max log p).
    fn weigh(&mut self, meas: &Measurement, shift: f64) -> (f64, f64, f64, f64) {
        let (d, m) = (self.dims.state, self.dims.obs);
        let (lik, _) = ObsTerms::new(&self.model, meas);
        let (mut x, mut g, mut r) = ([0.0; MAX_STATE], [0.0; MAX_OBS], [0.0; MAX_OBS]);
        let (mut sum, mut mass, mut sq, mut lmax) = (0.0, 0.0, 0.0, f64::NEG_INFINITY);
        for i in 0..self.phi.len() {
            let p = self.phi[i];
            if p == 0.0 {
                self.tmp[i] = 0.0;
                continue;
            }
            let z = self.chain.state(i);
            for a in 0..d {
                x[a] = self.c[a] + z[a];
            }
            self.model.obs_mean(&x[..d], &mut g[..m]);
            let l = lik.log_lik(&self.model, &meas.y[..m], &g[..m], &mut r[..m]);
            lmax = lmax.max(l);
            let a = l - shift;
            let e = if a > -700.0 { a.exp() } else { 0.0 };
            let w = p * e;
            self.tmp[i] = w;
            sum += w;
            mass += p;
            sq += w * e;
        }
        (sum, mass, sq, lmax)
    }
}

impl<M: SdeModel> BayesFilter for RecentredChainFilter<M> {
    fn name(&self) -> &'static str {
        "chain-recentred"
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.t
    }

    fn reset(&mut self, t: f64, prior: &Gaussian) {
        self.t = t;
        self.install(prior);
    }

    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        check_predict(self.t, t, u, self.dims)?;
        let dt = t - self.t;
        if dt == 0.0 {
            return Ok(());
        }
        self.since += 1;
        let low_ess = self.cfg.ess_fraction > 0.0 && {
            let s2: f64 = self.phi.iter().map(|w| w * w).sum();
            s2 * self.cfg.ess_fraction * (self.phi.len() as f64) > 1.0
        };
        if self.since >= self.cfg.every || low_ess {
            let b = self.belief();
            self.install(&b);
        }
        self.move_frame(u, dt);
        let (whole, frac) = self.eq.steps(dt);
        for _ in 0..whole {
            self.kern.forward(&self.phi, &mut self.tmp);
            std::mem::swap(&mut self.phi, &mut self.tmp);
        }
        if frac > 0.0 {
            self.kern.forward_fraction(frac, &self.phi, &mut self.tmp);
            std::mem::swap(&mut self.phi, &mut self.tmp);
        }
        self.t = t;
        self.invalidate();
        Ok(())
    }

    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        let (_, cst) = ObsTerms::new(&self.model, meas);
        let mut w = self.weigh(meas, 0.0);
        let mut shift = 0.0;
        if !(w.0 > 1e-250 && w.0.is_finite() && w.2 > 1e-250) && w.3.is_finite() {
            shift = w.3;
            w = self.weigh(meas, shift);
        }
        if !(w.0 > 0.0 && w.0.is_finite()) {
            // No state explains y: retry on the inflated prediction.
            self.respreads += 1;
            self.collapses += 1;
            let mut g = self.belief();
            g.cov_mut().iter_mut().for_each(|v| *v *= RESPREAD_VAR);
            if !self.install(&g) {
                return Err(FilterError::Degenerate);
            }
            w = self.weigh(meas, 0.0);
            shift = 0.0;
            if w.3.is_finite() {
                shift = w.3;
                w = self.weigh(meas, shift);
            }
            if !(w.0 > 0.0 && w.0.is_finite()) {
                self.tmp.fill(0.0);
                return Err(FilterError::Degenerate);
            }
        } else if w.0 * w.0 < COLLAPSE_FRACTION * w.1 * w.2 {
            self.collapses += 1;
        }
        let inv = 1.0 / w.0;
        let (s2, acc) = match self.dims.state {
            2 => self.normalise_pass::<2>(inv),
            4 => self.normalise_pass::<4>(inv),
            _ => self.normalise_pass::<0>(inv),
        };
        self.local.set(Some(acc.gaussian()));
        Ok(UpdateInfo {
            log_evidence: shift + w.0.ln() + cst,
            ess: 1.0 / s2,
            resampled: false,
        })
    }

    fn belief(&self) -> Gaussian {
        let mut g = self.local_moments();
        for a in 0..self.dims.state {
            g.mean[a] += self.c[a];
        }
        g
    }

    fn ess_collapses(&self) -> Option<u64> {
        Some(self.collapses)
    }
}
