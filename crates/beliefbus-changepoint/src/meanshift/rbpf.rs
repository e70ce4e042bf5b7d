//! The fast Rao-Blackwellised particle filter for the mean-shift model
//! (Chen, Lai & Wu §3.2, §5.1).
//!
//! Each particle carries only its current segment (n = t − C_t + 1, S = Σ
//! y_j since C_t), its Beta count of past change-points when ρ is unknown,
//! and a log weight. At step t, with v_t = (n + σ⁻²)⁻¹:
//! - a_t(ρ) = ρ N(y_t; 0, 1 + σ²) (change at t) and
//!   b_t(ρ) = (1 − ρ) N(y_t; v_t S, 1 + v_t) (no change), eq. (10);
//! - I_t ~ Bernoulli(a_t(ρ̃)/(a_t(ρ̃) + b_t(ρ̃))), the data-adapted
//!   proposal (3), tilted by ρ̃ ≥ ρ if asked;
//! - w_t = w_{t−1}(a_t(ρ̃) + b_t(ρ̃))·a_t(ρ)/a_t(ρ̃) if I_t = 1, or
//!   ·b_t(ρ)/b_t(ρ̃) if I_t = 0, eq. (12) (= (11) when ρ̃ = ρ);
//! - with ρ ~ Beta(α, β) the prior probability of a change is replaced by
//!   the predictive (n₁ + α)/(t − 1 + α + β), eq. (29), n₁ the particle's
//!   count of changes in I_{1:t−1};
//! - estimate (9) with (5): μ̂_t = Σ W_j S_j/(n_j + σ⁻²), formed before
//!   resampling (optionally after: the paper does not say);
//! - if cv²(w) ≥ bound, eq. (8), resample the particles' (n, S, n₁) — the
//!   sufficient statistics of their whole I_{1:t} — and reset the weights.
//!
//! At t = 1 the no-change segment is the prior itself (n = 0, S = 0), so
//! a_1 + b_1 = p(y_1) and the tilted weight reduces to the paper's
//! w̃_1 = (ρ/ρ̃)1{I_1=1} + ((1−ρ)/(1−ρ̃))1{I_1=0}. The rejuvenation test
//! starts at t = 2 (the paper's steps start there; bound 0 then gives
//! n − 1 resamplings, the 9999 of Table 1).

use super::{check_probability, segment_mean, MeanShiftModel};
use crate::error::ChangepointError;
use crate::resample::{gather, resample, Scheme};
use crate::rng::SimRng;
use crate::weights::{cv2, log_add, log_normal_pdf, normalise};
use rand::RngExt;

/// What the filter assumes about ρ.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub enum RhoPrior {
    /// ρ known (the model's ρ).
    Known,
    /// ρ ~ Beta(α, β), integrated out per particle (eq. 29).
    Beta { alpha: f64, beta: f64 },
}

/// Filter settings.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct RbpfConfig {
    /// Number of particles M.
    pub particles: usize,
    /// Resample when cv² ≥ this bound; 0 = every step, ∞ = never.
    pub cv2_bound: f64,
    /// Resampling scheme.
    pub scheme: Scheme,
    /// Known ρ or a Beta prior on it.
    pub rho_prior: RhoPrior,
    /// Proposal change probability ρ̃ (None: ρ̃ = ρ). Known ρ only.
    pub tilt: Option<f64>,
    /// Form the estimate after rejuvenation instead of before (the paper
    /// does not say; before is the lower-variance choice and the default).
    pub estimate_after_resampling: bool,
}

impl Default for RbpfConfig {
    fn default() -> Self {
        Self {
            particles: 50,
            cv2_bound: 1.0,
            scheme: Scheme::Systematic,
            rho_prior: RhoPrior::Known,
            tilt: None,
            estimate_after_resampling: false,
        }
    }
}

/// The filter. All buffers are allocated in [`MeanShiftRbpf::new`]; a step
/// allocates nothing.
#[derive(Clone, Debug)]
pub struct MeanShiftRbpf {
    cfg: RbpfConfig,
    inv_sigma2: f64,
    /// log N(y; 0, 1 + σ²) needs 1 + σ².
    change_var: f64,
    rho: f64,
    /// Per particle: observations in the current segment.
    n: Vec<u32>,
    /// Per particle: sum of the current segment's observations.
    s: Vec<f64>,
    /// Per particle: number of change-points among I_{1:t−1} (Beta prior).
    n1: Vec<u32>,
    logw: Vec<f64>,
    w: Vec<f64>,
    anc: Vec<usize>,
    scratch_f: Vec<f64>,
    scratch_u: Vec<u32>,
    t: u64,
    resamplings: u64,
    rng: SimRng,
}

impl MeanShiftRbpf {
    /// A filter for `model` with settings `cfg`, drawing from `rng`.
    pub fn new(
        model: MeanShiftModel,
        cfg: RbpfConfig,
        rng: SimRng,
    ) -> Result<Self, ChangepointError> {
        let model = MeanShiftModel::new(model.sigma, model.rho)?;
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
        if let RhoPrior::Beta { alpha, beta } = cfg.rho_prior {
            for (name, value) in [("alpha", alpha), ("beta", beta)] {
                if !(value > 0.0 && value.is_finite()) {
                    return Err(ChangepointError::Positive { name, value });
                }
            }
            if cfg.tilt.is_some() {
                return Err(ChangepointError::TiltNeedsKnownRho);
            }
        }
        if let Some(rt) = cfg.tilt {
            check_probability("tilt", rt)?;
        }
        let m = cfg.particles;
        Ok(Self {
            cfg,
            inv_sigma2: 1.0 / (model.sigma * model.sigma),
            change_var: 1.0 + model.sigma * model.sigma,
            rho: model.rho,
            n: vec![0; m],
            s: vec![0.0; m],
            n1: vec![0; m],
            logw: vec![0.0; m],
            w: vec![1.0 / m as f64; m],
            anc: vec![0; m],
            scratch_f: vec![0.0; m],
            scratch_u: vec![0; m],
            t: 0,
            resamplings: 0,
            rng,
        })
    }

    /// Back to t = 0 with a new generator (buffers reused).
    pub fn reset(&mut self, rng: SimRng) {
        self.n.fill(0);
        self.s.fill(0.0);
        self.n1.fill(0);
        self.logw.fill(0.0);
        self.w.fill(1.0 / self.cfg.particles as f64);
        self.t = 0;
        self.resamplings = 0;
        self.rng = rng;
    }

    /// Assimilate y_t; returns the filtered mean E(μ_t | Y_{1:t}).
    pub fn step(&mut self, y: f64) -> Result<f64, ChangepointError> {
        if !y.is_finite() {
            return Err(ChangepointError::NonFinite {
                name: "y",
                value: y,
            });
        }
        self.t += 1;
        let t = self.t;
        let l_change = log_normal_pdf(y, 0.0, self.change_var);
        let (ln_rho, ln_1m_rho) = (self.rho.ln(), (-self.rho).ln_1p());
        let tilt = self.cfg.tilt.map(|rt| (rt.ln(), (-rt).ln_1p()));
        for j in 0..self.cfg.particles {
            let v = 1.0 / (self.n[j] as f64 + self.inv_sigma2);
            let l_stay = log_normal_pdf(y, v * self.s[j], 1.0 + v);
            let (lp, lq) = match self.cfg.rho_prior {
                RhoPrior::Known => (ln_rho, ln_1m_rho),
                RhoPrior::Beta { alpha, beta } => {
                    let den = (t - 1) as f64 + alpha + beta;
                    let n1 = self.n1[j] as f64;
                    (
                        ((n1 + alpha) / den).ln(),
                        (((t - 1) as f64 - n1 + beta) / den).ln(),
                    )
                }
            };
            let la = lp + l_change;
            let lb = lq + l_stay;
            // Proposal terms a_t(ρ̃), b_t(ρ̃); untilted they are a_t, b_t.
            let (la_q, lb_q) = match tilt {
                Some((lr, l1r)) => (lr + l_change, l1r + l_stay),
                None => (la, lb),
            };
            let lz = log_add(la_q, lb_q);
            let log_p_change = la_q - lz;
            if self.rng.random::<f64>() < log_p_change.exp() {
                self.logw[j] += la - log_p_change;
                self.n[j] = 1;
                self.s[j] = y;
                self.n1[j] += 1;
            } else {
                self.logw[j] += lb - (lb_q - lz);
                self.n[j] += 1;
                self.s[j] += y;
            }
        }
        let lse = normalise(&self.logw, &mut self.w);
        if !lse.is_finite() {
            return Err(ChangepointError::WeightsVanished { step: t });
        }
        // Keep log weights near 0 so they never drift out of range.
        for l in self.logw.iter_mut() {
            *l -= lse;
        }
        let est = self.estimate();
        if t >= 2 && (self.cfg.cv2_bound == 0.0 || cv2(&self.w) >= self.cfg.cv2_bound) {
            self.rejuvenate();
            if self.cfg.estimate_after_resampling {
                return Ok(self.estimate());
            }
        }
        Ok(est)
    }

    /// Filtered mean from the current weights (eq. 9 with 5).
    pub fn estimate(&self) -> f64 {
        let mut e = 0.0;
        for j in 0..self.cfg.particles {
            e += self.w[j] * segment_mean(self.n[j], self.s[j], self.inv_sigma2);
        }
        e
    }

    /// Posterior probability that a change-point occurred at some time in
    /// [s, t] (s ≥ 2; a change at time 1 is indistinguishable from the
    /// initial draw): Σ_j W_j 1{C_t^(j) ≥ s}.
    pub fn prob_change_since(&self, s: u64) -> f64 {
        let mut p = 0.0;
        for j in 0..self.cfg.particles {
            let c = self.t + 1 - self.n[j] as u64;
            if c >= s.max(2) {
                p += self.w[j];
            }
        }
        p
    }

    /// Posterior mean of ρ (Beta prior only; the known ρ otherwise).
    pub fn rho_mean(&self) -> f64 {
        match self.cfg.rho_prior {
            RhoPrior::Known => self.rho,
            RhoPrior::Beta { alpha, beta } => {
                let den = self.t as f64 + alpha + beta;
                (0..self.cfg.particles)
                    .map(|j| self.w[j] * (self.n1[j] as f64 + alpha) / den)
                    .sum()
            }
        }
    }

    fn rejuvenate(&mut self) {
        resample(
            self.cfg.scheme,
            &self.w,
            &mut self.rng,
            &mut self.anc,
            &mut self.scratch_f,
        );
        gather(&mut self.n, &mut self.scratch_u, &self.anc);
        gather(&mut self.n1, &mut self.scratch_u, &self.anc);
        gather(&mut self.s, &mut self.scratch_f, &self.anc);
        self.logw.fill(0.0);
        self.w.fill(1.0 / self.cfg.particles as f64);
        self.resamplings += 1;
    }

    /// Number of rejuvenations so far.
    pub fn resamplings(&self) -> u64 {
        self.resamplings
    }

    /// Steps assimilated so far.
    pub fn t(&self) -> u64 {
        self.t
    }

    /// Current normalised weights.
    pub fn weights(&self) -> &[f64] {
        &self.w
    }

    /// The settings.
    pub fn config(&self) -> &RbpfConfig {
        &self.cfg
    }
}
