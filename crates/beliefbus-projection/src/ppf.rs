//! The projection particle filter (paper §IV, Algorithm 4).
//!
//! ```text
//! resample   x^i_{k−1} ~ f(·, θ̂_{k−1})                  (step 5 of k−1)
//! predict    x^i_{k|k−1} ~ p(· | x^i_{k−1}, a_{k−1})     (step 2)
//! update     w^i_k ∝ p(y_k | x^i_{k|k−1})                (step 3; the paper
//!            prints x^i_k, a typo for the predicted particle)
//! project    θ̂_k: Σ_i w^i_k c(x^i_{k|k−1}) = E_θ̂k[c]     (step 4, eq. 14)
//! ```
//!
//! Draws from f(·, θ̂) outside the model's state space are moved into it
//! ([`FilterModel::constrain`]). The *updated* density is projected, so the belief handed to the policy is
//! a member of the family; between steps only θ̂ is carried, and resampling
//! from the continuous f(·, θ̂) replaces duplicated particles (no sample
//! impoverishment). All buffers are allocated in [`ProjectionPf::new`].

use crate::family::ExpFamily;
use crate::model::{normalize_log_weights, FilterModel};
use crate::rng::SimRng;
use crate::ProjectionError;

/// A projection particle filter with `n` particles over family `F`.
pub struct ProjectionPf<F: ExpFamily> {
    family: F,
    n: usize,
    d: usize,
    particles: Vec<f64>,
    logw: Vec<f64>,
    w: Vec<f64>,
    params: F::Params,
}

impl<F: ExpFamily> ProjectionPf<F> {
    /// A filter with `n` particles whose belief starts at `initial` (θ̂_0's
    /// prior; call [`Self::initialize`] then [`Self::update`] with y_0).
    pub fn new(family: F, n: usize, initial: &F::Params) -> Result<Self, ProjectionError> {
        if n == 0 {
            return Err(ProjectionError::invalid(
                "particle count",
                "must be at least 1",
            ));
        }
        let d = family.state_dim();
        Ok(Self {
            n,
            d,
            particles: vec![0.0; n * d],
            logw: vec![0.0; n],
            w: vec![1.0 / n as f64; n],
            params: initial.clone(),
            family,
        })
    }

    /// The family projected onto.
    pub fn family(&self) -> &F {
        &self.family
    }

    /// The current projected belief θ̂.
    pub fn params(&self) -> &F::Params {
        &self.params
    }

    /// The particles of the last prediction (n × d row-major).
    pub fn particles(&self) -> &[f64] {
        &self.particles
    }

    /// The normalised weights of the last update.
    pub fn weights(&self) -> &[f64] {
        &self.w
    }

    /// Set the belief to `params` (the prior of a new run).
    pub fn reset(&mut self, params: &F::Params) {
        self.params.clone_from(params);
    }

    /// Draw the particles from f(·, θ̂) without propagating them: the
    /// initial sample x_0^i (Algorithm 4 step 1), before the update with y_0.
    pub fn initialize<M: FilterModel>(&mut self, model: &M, rng: &mut SimRng) {
        for x in self.particles.chunks_exact_mut(self.d) {
            self.family.sample(&self.params, rng, x);
            model.constrain(x);
        }
        self.w.fill(1.0 / self.n as f64);
    }

    /// Resample from f(·, θ̂_{k−1}) and propagate each particle with
    /// control `u` (steps 5 and 2).
    pub fn predict<M: FilterModel>(&mut self, model: &M, u: &[f64], rng: &mut SimRng) {
        for x in self.particles.chunks_exact_mut(self.d) {
            self.family.sample(&self.params, rng, x);
            model.constrain(x);
            model.sample_transition(x, u, rng);
        }
        self.w.fill(1.0 / self.n as f64);
    }

    /// Weight the predicted particles by p(y | x) and project (steps 3–4).
    /// On error (e.g. every likelihood zero) θ̂ is left unchanged.
    pub fn update<M: FilterModel>(
        &mut self,
        model: &M,
        y: &[f64],
    ) -> Result<&F::Params, ProjectionError> {
        ProjectionError::check_len("observation", model.obs_dim(), y.len())?;
        for (l, x) in self
            .logw
            .iter_mut()
            .zip(self.particles.chunks_exact(self.d))
        {
            *l = model.obs_log_likelihood(x, y);
        }
        normalize_log_weights(&self.logw, &mut self.w)?;
        self.family
            .project(&self.particles, &self.w, &mut self.params)?;
        Ok(&self.params)
    }
}
