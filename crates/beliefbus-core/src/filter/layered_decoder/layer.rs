//! One time layer of the layered chain: its states and the log of their
//! cell volumes v(x) = 1/(n ρ(x)), ρ the known sampling density (uniform,
//! or the Gaussian-plus-uniform mixture around a belief, thesis §3.3.3).

use super::LN_2PI;
use crate::belief::Gaussian;
use crate::chain::linalg::{cholesky, forward_sub};
use crate::chain::Sampler;
use crate::filter::FilterError;
use crate::model::Bounds;
use crate::rng::SimRng;
use crate::MAX_STATE;

/// States of one time layer with the log of their cell volumes.
#[derive(Clone, Debug)]
pub struct Layer {
    pub dim: usize,
    /// Flat n × dim.
    pub states: Vec<f64>,
    /// log v(x) for every state (ln of 1/(n ρ(x)), ρ the sampling density).
    pub log_vol: Vec<f64>,
}

impl Layer {
    /// The single known state `x` (the root (t₀, x₀) of Alg. 3.2).
    pub fn point(x: &[f64]) -> Self {
        Self {
            dim: x.len(),
            states: x.to_vec(),
            log_vol: vec![0.0],
        }
    }

    /// `n` states uniform on `bounds`: v = μ(S)/n.
    pub fn uniform(bounds: &Bounds, n: usize, rng: &mut SimRng) -> Self {
        let states = Sampler::Uniform.sample_many(bounds, n, rng);
        let lv = (bounds.volume() / n as f64).ln();
        Self {
            dim: bounds.dim(),
            states,
            log_vol: vec![lv; n],
        }
    }

    /// `n` states from the mixture (1 − u) N(m, κ² P) + u Unif(S) of
    /// [`Sampler::around`]; v(x) = 1/(n ρ(x)) with the mixture's density
    /// (the Gaussian part's truncation to S is ignored: its mass outside S
    /// is negligible when the belief lies well inside S, and it only scales
    /// v near the boundary). Fails when the inflated covariance is not
    /// positive definite or u ∉ [0, 1].
    pub fn around(
        belief: &Gaussian,
        inflate: f64,
        uniform_fraction: f64,
        bounds: &Bounds,
        n: usize,
        rng: &mut SimRng,
    ) -> Result<Self, FilterError> {
        let sampler = Sampler::around(belief, inflate, uniform_fraction)
            .ok_or(FilterError::Numerical("belief covariance for sampling"))?;
        let states = sampler.sample_many(bounds, n, rng);
        let d = belief.dim;
        let mut chol = [0.0; MAX_STATE * MAX_STATE];
        for (c, v) in chol[..d * d].iter_mut().zip(belief.cov()) {
            *c = v * inflate * inflate;
        }
        cholesky(&mut chol[..d * d], d);
        let log_det: f64 = (0..d).map(|i| chol[i + i * d].ln()).sum::<f64>();
        let u_dens = uniform_fraction / bounds.volume();
        let mut r = [0.0; MAX_STATE];
        let log_vol = states
            .chunks_exact(d)
            .map(|x| {
                for i in 0..d {
                    r[i] = x[i] - belief.mean()[i];
                }
                forward_sub(&chol[..d * d], d, &mut r[..d]);
                let q: f64 = r[..d].iter().map(|v| v * v).sum();
                let g = (-0.5 * q - log_det - 0.5 * d as f64 * LN_2PI).exp();
                let rho = (1.0 - uniform_fraction) * g + u_dens;
                -(n as f64 * rho).ln()
            })
            .collect();
        Ok(Self {
            dim: d,
            states,
            log_vol,
        })
    }

    pub fn len(&self) -> usize {
        self.log_vol.len()
    }

    pub fn is_empty(&self) -> bool {
        self.log_vol.is_empty()
    }

    pub fn state(&self, i: usize) -> &[f64] {
        &self.states[i * self.dim..(i + 1) * self.dim]
    }
}
