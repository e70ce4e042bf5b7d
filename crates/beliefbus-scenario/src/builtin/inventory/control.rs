//! The inventory controllers, acting on the `projection-pf` belief.
//!
//! - `belief-mdp` (paper §IV): a_k = μ^p(nearest grid point of (m̂_k, σ̂_k)),
//!   the projected belief's mean and standard deviation looked up in the
//!   solved policy table ([`GridPolicy::act`]: per-axis rounding, O(1), no
//!   allocation); u_k = a_k Q. The policy file is loaded and checked
//!   against the scenario's parameters when the controller is built, i.e.
//!   at config validation: a missing or stale file is a config error that
//!   names the `beliefbus solve` command to run.
//! - `ce-threshold`: certainty equivalence, order iff m̂_k < L* (eq. 22 on
//!   the belief's mean), the paper's CE baseline.

use super::InventorySystem;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::control::{ControlError, ControlInfo, Controller};
use beliefbus_projection::inventory::policies::threshold_action;
use beliefbus_projection::GridPolicy;
use std::time::Instant;

/// The belief's grid coordinates (mean, std) of the inventory entry.
#[inline]
fn coords(belief: &Gaussian) -> Result<[f64; 2], ControlError> {
    if belief.dim != super::STATE {
        return Err(ControlError::Dimension {
            got: belief.dim,
            expected: super::STATE,
        });
    }
    let (m, v) = (belief.mean[0], belief.cov_at(0, 0));
    if !(m.is_finite() && v.is_finite()) {
        return Err(ControlError::NonFinite);
    }
    Ok([m, v.max(0.0).sqrt()])
}

/// `belief-mdp`.
pub struct BeliefMdp {
    policy: GridPolicy,
    q: f64,
}

impl BeliefMdp {
    /// Load and check the policy file.
    pub fn new(sys: &InventorySystem) -> Result<Self, String> {
        Ok(Self {
            policy: sys.load_policy()?,
            q: sys.params.q,
        })
    }

    /// The order for `belief`.
    #[inline]
    pub fn order(&self, belief: &Gaussian) -> Result<f64, ControlError> {
        let c = coords(belief)?;
        let a = self
            .policy
            .act(&c)
            .map_err(|_| ControlError::Numerical("policy lookup"))?;
        Ok(a as f64 * self.q)
    }
}

impl Controller for BeliefMdp {
    fn name(&self) -> &'static str {
        super::BELIEF_MDP
    }
    fn control_dim(&self) -> usize {
        1
    }
    /// The goal is the policy's (minimum average cost).
    fn set_goal(&mut self, _goal: &[f64]) {}
    fn reset(&mut self) {}
    fn compute(
        &mut self,
        _t: f64,
        belief: &Gaussian,
        u: &mut [f64],
    ) -> Result<ControlInfo, ControlError> {
        u[0] = self.order(belief)?;
        Ok(ControlInfo {
            cost: f64::NAN,
            samples: 0,
            ess: 0.0,
        })
    }
}

/// `ce-threshold`.
pub struct CeThreshold {
    threshold: f64,
    q: f64,
}

impl CeThreshold {
    pub fn new(sys: &InventorySystem) -> Self {
        Self {
            threshold: sys.params.threshold,
            q: sys.params.q,
        }
    }
}

impl Controller for CeThreshold {
    fn name(&self) -> &'static str {
        super::CE
    }
    fn control_dim(&self) -> usize {
        1
    }
    fn set_goal(&mut self, _goal: &[f64]) {}
    fn reset(&mut self) {}
    fn compute(
        &mut self,
        _t: f64,
        belief: &Gaussian,
        u: &mut [f64],
    ) -> Result<ControlInfo, ControlError> {
        let [m, _] = coords(belief)?;
        u[0] = threshold_action(m, self.threshold) as f64 * self.q;
        Ok(ControlInfo {
            cost: f64::NAN,
            samples: 0,
            ess: 0.0,
        })
    }
}

/// Mean time (ns) of one `belief-mdp` decision (coordinates of the belief
/// and the table lookup) over `n` beliefs spread over the grid's range.
pub fn time_lookup(policy: &GridPolicy, n: usize) -> f64 {
    let ctl = BeliefMdp {
        policy: policy.clone(),
        q: 1.0,
    };
    let span = policy
        .grid
        .axes
        .first()
        .map_or(1.0, |a| a.value(a.count - 1));
    let mut g = Gaussian::zeros(super::STATE);
    let mut total = 0.0;
    let start = Instant::now();
    for i in 0..n {
        // A cheap deterministic sweep (no RNG in the timed loop).
        let f = (i as f64 * 0.618_033_988_75).fract();
        g.mean[0] = f * span;
        g.set_cov(0, 0, 6.0 * f * (1.0 - f));
        total += ctl.order(std::hint::black_box(&g)).unwrap_or(0.0);
    }
    std::hint::black_box(total);
    start.elapsed().as_secs_f64() * 1e9 / n.max(1) as f64
}
