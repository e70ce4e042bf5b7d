//! The four policies of paper §VI, plus the full-observation reference.
//!
//! * `ours`: the projection particle filter (Gaussian family) and the
//!   projected-belief MDP's grid policy, a_k = μ^p(nearest grid point of
//!   (mean, std) of θ̂_k).
//! * `ce`: certainty equivalence, the full-observation optimal threshold
//!   (eq. 22, order iff x < L*) applied to the bootstrap-PF posterior mean.
//! * `ce_mle`: the same threshold applied to the bootstrap PF's maximum
//!   likelihood particle (the paper does not say how its MLE is extracted;
//!   the particle maximising p(y_k | x) among the equally weighted predicted
//!   particles is the MLE over the particle set).
//! * `greedy`: argmin_a E[g_k(x_k, a, u_k) | I_k], the expectation over the
//!   demand in closed form and over x_k under the weighted bootstrap PF.
//! * `full_obs`: the threshold policy on the true state (the reference the
//!   paper's percentages are taken from).
//!
//! The bootstrap PF (N = 200, as the paper) resamples every step; every
//! controller preallocates its filter, so a step does not allocate.

use super::Inventory;
use crate::bootstrap::BootstrapPf;
use crate::family::ExpFamily;
use crate::gaussian::{Gaussian, GaussianParams};
use crate::policy::GridPolicy;
use crate::ppf::ProjectionPf;
use crate::rng::SimRng;
use crate::ProjectionError;
use std::time::Instant;

/// What a controller sees at step k: y_k, and the true x_k which only the
/// full-observation reference may read.
#[derive(Clone, Copy, Debug)]
pub struct Observation {
    pub y: f64,
    pub x_true: f64,
}

/// A policy acting on the observation stream.
pub trait Controller {
    /// The method name printed in the tables.
    fn name(&self) -> &'static str;
    /// Start a run at the known initial inventory.
    fn reset(&mut self, model: &Inventory, rng: &mut SimRng) -> Result<(), ProjectionError>;
    /// Filter y_k (the previous action `prev` was applied before it; None at
    /// k = 0) and return a_k.
    fn act(
        &mut self,
        model: &Inventory,
        obs: Observation,
        prev: Option<usize>,
        rng: &mut SimRng,
    ) -> Result<usize, ProjectionError>;
}

/// Order iff the estimate is below the threshold (eq. 22; ties do not order).
#[inline]
pub fn threshold_action(estimate: f64, threshold: f64) -> usize {
    usize::from(estimate < threshold)
}

/// The paper's greedy rule (§VI), argmin_a E_{x_k,u_k}[g_k(x_k, a_k Q, u_k) | I_k],
/// on the weighted particle belief {(x_i, w_i)}: the demand expectation in
/// closed form, E = Σ_i w_i E_u[g(x_i, a, u)]. Ties do not order.
pub fn greedy_action(model: &Inventory, particles: &[f64], weights: &[f64]) -> usize {
    let mut q = [0.0; 2];
    for (&x, &w) in particles.iter().zip(weights) {
        for (a, qa) in q.iter_mut().enumerate() {
            *qa += w * model.expected_cost(x, a);
        }
    }
    usize::from(q[1] < q[0])
}

/// The full-observation threshold policy on the true state.
pub struct FullObs {
    pub threshold: f64,
}

impl Controller for FullObs {
    fn name(&self) -> &'static str {
        "full_obs"
    }
    fn reset(&mut self, _: &Inventory, _: &mut SimRng) -> Result<(), ProjectionError> {
        Ok(())
    }
    fn act(
        &mut self,
        _: &Inventory,
        obs: Observation,
        _: Option<usize>,
        _: &mut SimRng,
    ) -> Result<usize, ProjectionError> {
        Ok(threshold_action(obs.x_true, self.threshold))
    }
}

/// How a bootstrap-PF controller turns the belief into an action.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BeliefRule {
    /// Threshold on the posterior mean (CE).
    CeMean { threshold: f64 },
    /// Threshold on the maximum-likelihood particle (CE-MLE).
    CeMle { threshold: f64 },
    /// Minimise the expected one-step cost (greedy).
    Greedy,
}

/// The bootstrap-PF baselines.
pub struct BootstrapController {
    pf: BootstrapPf,
    rule: BeliefRule,
}

impl BootstrapController {
    /// A baseline with `n` particles.
    pub fn new(n: usize, rule: BeliefRule) -> Result<Self, ProjectionError> {
        Ok(Self {
            pf: BootstrapPf::new(n, 1)?,
            rule,
        })
    }
}

impl Controller for BootstrapController {
    fn name(&self) -> &'static str {
        match self.rule {
            BeliefRule::CeMean { .. } => "ce",
            BeliefRule::CeMle { .. } => "ce_mle",
            BeliefRule::Greedy => "greedy",
        }
    }

    fn reset(&mut self, model: &Inventory, _: &mut SimRng) -> Result<(), ProjectionError> {
        self.pf.initialize_at(&[model.x0])
    }

    fn act(
        &mut self,
        model: &Inventory,
        obs: Observation,
        prev: Option<usize>,
        rng: &mut SimRng,
    ) -> Result<usize, ProjectionError> {
        use crate::model::Pomdp;
        if let Some(a) = prev {
            self.pf.resample(rng);
            self.pf.predict(model, model.action_control(a), rng);
        }
        self.pf.update(model, &[obs.y])?;
        Ok(match self.rule {
            BeliefRule::CeMean { threshold } => {
                let mut m = [0.0];
                self.pf.mean(&mut m);
                threshold_action(m[0], threshold)
            }
            BeliefRule::CeMle { threshold } => {
                threshold_action(self.pf.max_weight_particle()[0], threshold)
            }
            BeliefRule::Greedy => greedy_action(model, self.pf.particles(), self.pf.weights()),
        })
    }
}

/// Our method: projection PF + grid policy. Accumulates the time of the
/// on-line decision (weighting, projection, nearest-grid lookup) per step.
pub struct ProjectedController<'p> {
    pf: ProjectionPf<Gaussian>,
    policy: &'p GridPolicy,
    prior: GaussianParams,
    coords: [f64; 2],
    /// Σ seconds spent in update + projection + lookup, and steps counted.
    pub decide_s: f64,
    pub steps: u64,
}

impl<'p> ProjectedController<'p> {
    /// `n` particles, acting with `policy` (which must be laid on the
    /// Gaussian (mean, std) grid).
    pub fn new(
        model: &Inventory,
        n: usize,
        policy: &'p GridPolicy,
    ) -> Result<Self, ProjectionError> {
        let family = Gaussian::new(1)?;
        ProjectionError::check_len(
            "policy grid dimension",
            family.grid_dim(),
            policy.grid.dim(),
        )?;
        if policy.family != family.name() {
            return Err(ProjectionError::invalid(
                "policy family",
                format!("{} (expected gaussian)", policy.family),
            ));
        }
        // x_0 is known: the prior is the point mass at x_0.
        let prior = family.params(&[model.x0], &[0.0])?;
        Ok(Self {
            pf: ProjectionPf::new(family, n, &prior)?,
            policy,
            prior,
            coords: [0.0; 2],
            decide_s: 0.0,
            steps: 0,
        })
    }

    /// The projected belief θ̂_k.
    pub fn belief(&self) -> &GaussianParams {
        self.pf.params()
    }
}

impl Controller for ProjectedController<'_> {
    fn name(&self) -> &'static str {
        "ours"
    }

    fn reset(&mut self, model: &Inventory, rng: &mut SimRng) -> Result<(), ProjectionError> {
        self.pf.reset(&self.prior);
        self.pf.initialize(model, rng);
        Ok(())
    }

    fn act(
        &mut self,
        model: &Inventory,
        obs: Observation,
        prev: Option<usize>,
        rng: &mut SimRng,
    ) -> Result<usize, ProjectionError> {
        use crate::model::Pomdp;
        if let Some(a) = prev {
            self.pf.predict(model, model.action_control(a), rng);
        }
        let t = Instant::now();
        self.pf.update(model, &[obs.y])?;
        self.pf
            .family()
            .grid_coords(self.pf.params(), &mut self.coords);
        let a = self.policy.act(&self.coords)?;
        self.decide_s += t.elapsed().as_secs_f64();
        self.steps += 1;
        Ok(a)
    }
}
