//! The exact filter for the mean-shift model: the posterior over the
//! current segment (equivalently the last change-point C_t), O(t) per step.
//!
//! With p_t(c) = P(C_t = c | Y_{1:t}) and the segment predictive
//! N(y_t; v S_c, 1 + v), v = (n_c + σ⁻²)⁻¹ of eq. (10):
//! - p_t(c) ∝ (1 − ρ) N(y_t; v S_c, 1 + v) p_{t−1}(c) for c < t,
//! - p_t(t) ∝ ρ N(y_t; 0, 1 + σ²),
//!
//! and E(μ_t | Y_{1:t}) = Σ_c p_t(c) S_c/(n_c + σ⁻²), eq. (9) without
//! Monte Carlo. At t = 1 "no change since μ₀" and "change at 1" are the
//! same segment, so the filter starts from that one segment. Optional
//! pruning drops segments whose posterior falls below a relative threshold
//! (used only to make 10⁴-step reference runs cheap; tests use none).

use super::{segment_mean, MeanShiftModel};
use crate::error::ChangepointError;
use crate::weights::{log_add, log_normal_pdf};

/// One candidate segment: observations, their sum and log posterior.
#[derive(Clone, Copy, Debug)]
struct Segment {
    n: u32,
    s: f64,
    logp: f64,
}

/// The exact (or pruned) run-length filter.
#[derive(Clone, Debug)]
pub struct ExactMeanShift {
    inv_sigma2: f64,
    change_var: f64,
    ln_rho: f64,
    ln_1m_rho: f64,
    prune_below: f64,
    segs: Vec<Segment>,
    t: u64,
}

impl ExactMeanShift {
    /// Exact filter (no pruning).
    pub fn new(model: MeanShiftModel) -> Result<Self, ChangepointError> {
        Self::with_pruning(model, f64::NEG_INFINITY)
    }

    /// Drop segments whose log posterior is below `log_threshold` (e.g.
    /// −40: probability < 4e-18) after each step.
    pub fn with_pruning(
        model: MeanShiftModel,
        log_threshold: f64,
    ) -> Result<Self, ChangepointError> {
        let model = MeanShiftModel::new(model.sigma, model.rho)?;
        Ok(Self {
            inv_sigma2: 1.0 / (model.sigma * model.sigma),
            change_var: 1.0 + model.sigma * model.sigma,
            ln_rho: model.rho.ln(),
            ln_1m_rho: (-model.rho).ln_1p(),
            prune_below: log_threshold,
            segs: Vec::new(),
            t: 0,
        })
    }

    /// Assimilate y_t; returns E(μ_t | Y_{1:t}).
    pub fn step(&mut self, y: f64) -> Result<f64, ChangepointError> {
        if !y.is_finite() {
            return Err(ChangepointError::NonFinite {
                name: "y",
                value: y,
            });
        }
        self.t += 1;
        if self.t == 1 {
            self.segs.push(Segment {
                n: 1,
                s: y,
                logp: 0.0,
            });
            return Ok(self.mean());
        }
        let mut lse = f64::NEG_INFINITY;
        for g in self.segs.iter_mut() {
            let v = 1.0 / (g.n as f64 + self.inv_sigma2);
            g.logp += self.ln_1m_rho + log_normal_pdf(y, v * g.s, 1.0 + v);
            g.n += 1;
            g.s += y;
            lse = log_add(lse, g.logp);
        }
        // The previous posterior sums to 1, so the new segment's mass is ρ p(y | fresh).
        let new = self.ln_rho + log_normal_pdf(y, 0.0, self.change_var);
        lse = log_add(lse, new);
        self.segs.push(Segment {
            n: 1,
            s: y,
            logp: new,
        });
        for g in self.segs.iter_mut() {
            g.logp -= lse;
        }
        if self.prune_below > f64::NEG_INFINITY {
            let thr = self.prune_below;
            self.segs.retain(|g| g.logp >= thr);
            let z = self
                .segs
                .iter()
                .fold(f64::NEG_INFINITY, |a, g| log_add(a, g.logp));
            for g in self.segs.iter_mut() {
                g.logp -= z;
            }
        }
        Ok(self.mean())
    }

    /// E(μ_t | Y_{1:t}).
    pub fn mean(&self) -> f64 {
        self.segs
            .iter()
            .map(|g| g.logp.exp() * segment_mean(g.n, g.s, self.inv_sigma2))
            .sum()
    }

    /// P(a change-point in [s, t] | Y_{1:t}), s ≥ 2.
    pub fn prob_change_since(&self, s: u64) -> f64 {
        self.segs
            .iter()
            .filter(|g| self.t + 1 - g.n as u64 >= s.max(2))
            .map(|g| g.logp.exp())
            .sum()
    }

    /// Number of segments currently carried.
    pub fn support(&self) -> usize {
        self.segs.len()
    }
}
