//! The bootstrap particle filter on μ_t for the mean-shift model (Gordon et
//! al. 1993): propagate each μ^(j) by the prior transition (keep it with
//! probability 1 − ρ, else draw N(0, σ²)), weight by N(y_t; μ^(j), 1) and
//! resample every step. It is the baseline that does not adapt to the data
//! and does not integrate μ out; used to compare per-step cost at equal M.

use super::MeanShiftModel;
use crate::error::ChangepointError;
use crate::resample::{gather, resample, Scheme};
use crate::rng::SimRng;
use crate::weights::{log_normal_pdf, normalise};
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};

/// Bootstrap PF with preallocated buffers.
#[derive(Clone, Debug)]
pub struct MeanShiftBootstrap {
    model: MeanShiftModel,
    scheme: Scheme,
    mu: Vec<f64>,
    logw: Vec<f64>,
    w: Vec<f64>,
    anc: Vec<usize>,
    scratch: Vec<f64>,
    started: bool,
    rng: SimRng,
}

impl MeanShiftBootstrap {
    /// M particles.
    pub fn new(
        model: MeanShiftModel,
        particles: usize,
        scheme: Scheme,
        rng: SimRng,
    ) -> Result<Self, ChangepointError> {
        let model = MeanShiftModel::new(model.sigma, model.rho)?;
        if particles < 1 {
            return Err(ChangepointError::TooSmall {
                name: "particles",
                value: particles,
                min: 1,
            });
        }
        Ok(Self {
            model,
            scheme,
            mu: vec![0.0; particles],
            logw: vec![0.0; particles],
            w: vec![0.0; particles],
            anc: vec![0; particles],
            scratch: vec![0.0; particles],
            started: false,
            rng,
        })
    }

    /// Assimilate y_t; returns the weighted mean of μ_t.
    pub fn step(&mut self, y: f64) -> Result<f64, ChangepointError> {
        if !y.is_finite() {
            return Err(ChangepointError::NonFinite {
                name: "y",
                value: y,
            });
        }
        let sigma = self.model.sigma;
        for j in 0..self.mu.len() {
            if !self.started || self.rng.random::<f64>() < self.model.rho {
                let z: f64 = StandardNormal.sample(&mut self.rng);
                self.mu[j] = sigma * z;
            }
            self.logw[j] = log_normal_pdf(y, self.mu[j], 1.0);
        }
        self.started = true;
        if !normalise(&self.logw, &mut self.w).is_finite() {
            return Err(ChangepointError::WeightsVanished { step: 0 });
        }
        let est: f64 = self.w.iter().zip(&self.mu).map(|(w, m)| w * m).sum();
        resample(
            self.scheme,
            &self.w,
            &mut self.rng,
            &mut self.anc,
            &mut self.scratch,
        );
        gather(&mut self.mu, &mut self.scratch, &self.anc);
        Ok(est)
    }
}
