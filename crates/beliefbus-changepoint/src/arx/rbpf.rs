//! The fast particle filter for the change-point ARX model (Chen, Lai & Wu
//! §3.3): each particle carries its last change-point C and the Kalman
//! statistics (μ_{C,t}, V_{C,t}) of (14) since then.
//!
//! Per step, with the regressor φ_t (common to all particles):
//! - a_t(ρ) = ρ N(y_t − μᵀφ_t; 0, 1 + φ_tᵀVφ_t) — the prior's predictive;
//!   (16) prints y_t, which is this with μ = 0 (we keep the centred form);
//! - b_t(ρ) = (1 − ρ) N(y_t − μ_Cᵀφ_t; 0, 1 + φ_tᵀV_Cφ_t), eq. (16);
//! - I_t ~ a_t(ρ̃)/(a_t(ρ̃) + b_t(ρ̃)), weights (11)/(12) as for the
//!   mean-shift filter;
//! - I_t = 1: (μ, V) ← the prior updated by (y_t, φ_t); I_t = 0: the
//!   particle's own (μ, V) updated by the rank-one recursions under (14);
//! - θ̂_t^(B) = Σ W_j μ_j, eq. (15), before rejuvenation at cv² ≥ bound.
//!
//! The first step (t = t₀, where I_{t₀} = 1) gives every particle the prior
//! updated by (y_{t₀}, φ_{t₀}) and weight 1.

use super::linalg::{dot, kalman_update, predictive, Matrix, Vector};
use super::ThetaPrior;
use crate::error::ChangepointError;
use crate::meanshift::check_probability;
use crate::resample::{gather, resample, Scheme};
use crate::rng::SimRng;
use crate::weights::{cv2, log_add, log_normal_pdf, normalise};
use rand::RngExt;

/// Filter settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArxRbpfConfig {
    pub particles: usize,
    /// Resample when cv² ≥ bound (0 = always, ∞ = never).
    pub cv2_bound: f64,
    pub scheme: Scheme,
    /// Change probability ρ.
    pub rho: f64,
    /// Proposal ρ̃ (None: ρ̃ = ρ).
    pub tilt: Option<f64>,
}

impl Default for ArxRbpfConfig {
    fn default() -> Self {
        Self {
            particles: 50,
            cv2_bound: 1.0,
            scheme: Scheme::Systematic,
            rho: 0.001,
            tilt: None,
        }
    }
}

/// Moments of the one-step predictive law (21) of θ_{t+1}:
/// (1 − ρ) Σ_j W_j N(μ_j, V_j) + ρ N(μ, V).
#[derive(Clone, Copy, Debug)]
pub struct Predictive<const D: usize> {
    /// E_t θ_{t+1}.
    pub mean: Vector<D>,
    /// E_t θ_{t+1}θ_{t+1}ᵀ.
    pub second: Matrix<D>,
}

/// The filter; buffers allocated once in [`ArxRbpf::new`].
#[derive(Clone, Debug)]
pub struct ArxRbpf<const D: usize> {
    cfg: ArxRbpfConfig,
    prior: ThetaPrior<D>,
    c: Vec<u64>,
    mu: Vec<Vector<D>>,
    v: Vec<Matrix<D>>,
    logw: Vec<f64>,
    w: Vec<f64>,
    anc: Vec<usize>,
    scratch_f: Vec<f64>,
    scratch_c: Vec<u64>,
    scratch_mu: Vec<Vector<D>>,
    scratch_v: Vec<Matrix<D>>,
    t: u64,
    resamplings: u64,
    rng: SimRng,
}

impl<const D: usize> ArxRbpf<D> {
    /// A filter with prior `prior` and settings `cfg`.
    pub fn new(
        prior: ThetaPrior<D>,
        cfg: ArxRbpfConfig,
        rng: SimRng,
    ) -> Result<Self, ChangepointError> {
        let prior = ThetaPrior::new(prior.mu, prior.v)?;
        check_probability("rho", cfg.rho)?;
        if let Some(rt) = cfg.tilt {
            check_probability("tilt", rt)?;
        }
        if cfg.particles < 1 {
            return Err(ChangepointError::TooSmall {
                name: "particles",
                value: cfg.particles,
                min: 1,
            });
        }
        if cfg.cv2_bound.is_nan() || cfg.cv2_bound < 0.0 {
            return Err(ChangepointError::NonNegative {
                name: "cv2_bound",
                value: cfg.cv2_bound,
            });
        }
        let m = cfg.particles;
        Ok(Self {
            cfg,
            prior,
            c: vec![0; m],
            mu: vec![prior.mu; m],
            v: vec![prior.v; m],
            logw: vec![0.0; m],
            w: vec![1.0 / m as f64; m],
            anc: vec![0; m],
            scratch_f: vec![0.0; m],
            scratch_c: vec![0; m],
            scratch_mu: vec![prior.mu; m],
            scratch_v: vec![prior.v; m],
            t: 0,
            resamplings: 0,
            rng,
        })
    }

    /// Assimilate (y_t, φ_t); returns θ̂_t^(B). The first call is t₀.
    pub fn step(&mut self, y: f64, phi: &Vector<D>) -> Result<Vector<D>, ChangepointError> {
        if !y.is_finite() {
            return Err(ChangepointError::NonFinite {
                name: "y",
                value: y,
            });
        }
        if let Some(&bad) = phi.iter().find(|x| !x.is_finite()) {
            return Err(ChangepointError::NonFinite {
                name: "phi",
                value: bad,
            });
        }
        self.t += 1;
        let t = self.t;
        // The change branch is the same for every particle.
        let mut mu0 = self.prior.mu;
        let mut v0 = self.prior.v;
        let (r0, s0) = kalman_update(&mut mu0, &mut v0, phi, y);
        if t == 1 {
            self.c.fill(t);
            self.mu.fill(mu0);
            self.v.fill(v0);
            self.logw.fill(0.0);
            self.w.fill(1.0 / self.cfg.particles as f64);
            return Ok(mu0);
        }
        let l_change = log_normal_pdf(r0, 0.0, s0);
        let rho = self.cfg.rho;
        let (lp, lq) = (rho.ln(), (-rho).ln_1p());
        let tilt = self.cfg.tilt.map(|rt| (rt.ln(), (-rt).ln_1p()));
        for j in 0..self.cfg.particles {
            let (r, s) = predictive(&self.mu[j], &self.v[j], phi, y);
            let l_stay = log_normal_pdf(r, 0.0, s);
            let la = lp + l_change;
            let lb = lq + l_stay;
            let (la_q, lb_q) = match tilt {
                Some((lr, l1r)) => (lr + l_change, l1r + l_stay),
                None => (la, lb),
            };
            let lz = log_add(la_q, lb_q);
            let log_p_change = la_q - lz;
            if self.rng.random::<f64>() < log_p_change.exp() {
                self.logw[j] += la - log_p_change;
                self.c[j] = t;
                self.mu[j] = mu0;
                self.v[j] = v0;
            } else {
                self.logw[j] += lb - (lb_q - lz);
                kalman_update(&mut self.mu[j], &mut self.v[j], phi, y);
            }
        }
        let lse = normalise(&self.logw, &mut self.w);
        if !lse.is_finite() {
            return Err(ChangepointError::WeightsVanished { step: t });
        }
        for l in self.logw.iter_mut() {
            *l -= lse;
        }
        let est = self.estimate();
        if self.cfg.cv2_bound == 0.0 || cv2(&self.w) >= self.cfg.cv2_bound {
            self.rejuvenate();
        }
        Ok(est)
    }

    /// θ̂^(B) = Σ W_j μ_j, eq. (15).
    pub fn estimate(&self) -> Vector<D> {
        let mut e = [0.0; D];
        for j in 0..self.cfg.particles {
            for i in 0..D {
                e[i] += self.w[j] * self.mu[j][i];
            }
        }
        e
    }

    /// Moments of the predictive (21) of θ_{t+1}.
    pub fn predictive(&self) -> Predictive<D> {
        let rho = self.cfg.rho;
        let mut mean = [0.0; D];
        let mut second = [[0.0; D]; D];
        for j in 0..self.cfg.particles {
            let (m, p, w) = (&self.mu[j], &self.v[j], self.w[j] * (1.0 - rho));
            for a in 0..D {
                mean[a] += w * m[a];
                for b in 0..D {
                    second[a][b] += w * (m[a] * m[b] + p[a][b]);
                }
            }
        }
        let (m, p) = (&self.prior.mu, &self.prior.v);
        for a in 0..D {
            mean[a] += rho * m[a];
            for b in 0..D {
                second[a][b] += rho * (m[a] * m[b] + p[a][b]);
            }
        }
        Predictive { mean, second }
    }

    /// P(a change-point in [s, t] | data) = Σ_j W_j 1{C_j ≥ s}; the
    /// initial segment (C = first step) does not count as a change.
    pub fn prob_change_since(&self, s: u64) -> f64 {
        (0..self.cfg.particles)
            .filter(|&j| self.c[j] >= s.max(2))
            .map(|j| self.w[j])
            .sum()
    }

    /// The normalised weights W_j (uniform right after a rejuvenation).
    pub fn weights(&self) -> &[f64] {
        &self.w
    }

    /// Particle j's (C, μ, V).
    pub fn particle(&self, j: usize) -> Option<(u64, &Vector<D>, &Matrix<D>)> {
        Some((*self.c.get(j)?, self.mu.get(j)?, self.v.get(j)?))
    }

    /// One-step prediction of y_{t+1} given φ_{t+1}: θ̂_{t+1|t}ᵀφ.
    pub fn predict_y(&self, phi: &Vector<D>) -> f64 {
        dot(&self.predictive().mean, phi)
    }

    fn rejuvenate(&mut self) {
        resample(
            self.cfg.scheme,
            &self.w,
            &mut self.rng,
            &mut self.anc,
            &mut self.scratch_f,
        );
        gather(&mut self.c, &mut self.scratch_c, &self.anc);
        gather(&mut self.mu, &mut self.scratch_mu, &self.anc);
        gather(&mut self.v, &mut self.scratch_v, &self.anc);
        self.logw.fill(0.0);
        self.w.fill(1.0 / self.cfg.particles as f64);
        self.resamplings += 1;
    }

    /// Rejuvenations so far.
    pub fn resamplings(&self) -> u64 {
        self.resamplings
    }

    /// Steps assimilated so far (the first is t₀).
    pub fn t(&self) -> u64 {
        self.t
    }
}
