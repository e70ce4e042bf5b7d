//! The bootstrap particle filter (paper §IV, Algorithm 3): predict through
//! the dynamics, weight by the likelihood, resample i.i.d. from the weighted
//! empirical belief every step. The certainty-equivalence baselines of §VI
//! read its posterior mean or its maximum-likelihood particle.

use crate::model::{normalize_log_weights, FilterModel};
use crate::rng::SimRng;
use crate::ProjectionError;
use rand::RngExt;

/// A bootstrap PF with `n` particles; buffers allocated once.
pub struct BootstrapPf {
    n: usize,
    d: usize,
    particles: Vec<f64>,
    spare: Vec<f64>,
    logw: Vec<f64>,
    w: Vec<f64>,
}

impl BootstrapPf {
    /// A filter with `n` particles of dimension `d`.
    pub fn new(n: usize, d: usize) -> Result<Self, ProjectionError> {
        if n == 0 || d == 0 {
            return Err(ProjectionError::invalid(
                "particle filter",
                "n and d must be at least 1",
            ));
        }
        Ok(Self {
            n,
            d,
            particles: vec![0.0; n * d],
            spare: vec![0.0; n * d],
            logw: vec![0.0; n],
            w: vec![1.0 / n as f64; n],
        })
    }

    /// Every particle at `x0` (a known initial state), equal weights.
    pub fn initialize_at(&mut self, x0: &[f64]) -> Result<(), ProjectionError> {
        ProjectionError::check_len("initial state", self.d, x0.len())?;
        for x in self.particles.chunks_exact_mut(self.d) {
            x.copy_from_slice(x0);
        }
        self.w.fill(1.0 / self.n as f64);
        Ok(())
    }

    /// The particles (n × d row-major).
    pub fn particles(&self) -> &[f64] {
        &self.particles
    }

    /// The normalised weights.
    pub fn weights(&self) -> &[f64] {
        &self.w
    }

    /// Propagate every particle with control `u` (step 2).
    pub fn predict<M: FilterModel>(&mut self, model: &M, u: &[f64], rng: &mut SimRng) {
        for x in self.particles.chunks_exact_mut(self.d) {
            model.sample_transition(x, u, rng);
        }
    }

    /// Weight by p(y | x) (step 3). On error the weights are unchanged.
    pub fn update<M: FilterModel>(&mut self, model: &M, y: &[f64]) -> Result<(), ProjectionError> {
        for (l, x) in self
            .logw
            .iter_mut()
            .zip(self.particles.chunks_exact(self.d))
        {
            *l = model.obs_log_likelihood(x, y);
        }
        normalize_log_weights(&self.logw, &mut self.w)?;
        Ok(())
    }

    /// Posterior mean Σ w_i x_i into `out`.
    pub fn mean(&self, out: &mut [f64]) {
        out[..self.d].fill(0.0);
        for (x, &w) in self.particles.chunks_exact(self.d).zip(&self.w) {
            for i in 0..self.d {
                out[i] += w * x[i];
            }
        }
    }

    /// The particle with the largest weight. After a prediction all
    /// particles have equal prior mass, so this maximises the likelihood
    /// p(y | x) over the predicted particles: the MLE over the particle set.
    pub fn max_weight_particle(&self) -> &[f64] {
        let mut best = 0;
        for i in 1..self.n {
            if self.w[i] > self.w[best] {
                best = i;
            }
        }
        &self.particles[best * self.d..(best + 1) * self.d]
    }

    /// Multinomial resampling (i.i.d. draws from the weighted belief, step
    /// 4) in O(n): sorted uniforms generated as normalised exponential
    /// spacings walk the cumulative weights once.
    pub fn resample(&mut self, rng: &mut SimRng) {
        let n = self.n;
        // Spacings E_1..E_{n+1}; the sorted uniforms are partial sums / total.
        let mut total = 0.0;
        for l in self.logw.iter_mut() {
            let u: f64 = rng.random();
            *l = -(1.0 - u).ln();
            total += *l;
        }
        let u: f64 = rng.random();
        total += -(1.0 - u).ln();
        let mut cum = self.w[0];
        let mut j = 0;
        let mut acc = 0.0;
        for i in 0..n {
            acc += self.logw[i];
            let target = acc / total;
            while target > cum && j + 1 < n {
                j += 1;
                cum += self.w[j];
            }
            self.spare[i * self.d..(i + 1) * self.d]
                .copy_from_slice(&self.particles[j * self.d..(j + 1) * self.d]);
        }
        std::mem::swap(&mut self.particles, &mut self.spare);
        self.w.fill(1.0 / n as f64);
    }
}
