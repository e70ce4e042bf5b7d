//! Backend `arx-adaptive`: the adaptive control rules of Chen & Lai (2007)
//! §IIIB on the `rbpf-changepoint` belief, choosing u_t so that
//! y_{t+1} = b₁u_t + γᵀψ_t + ε_{t+1} tracks y*_{t+1}.
//!
//! The belief's θ block (θ̂_t, P_t) gives the predictive (21) of θ_{t+1}
//! exactly in its first two moments:
//!
//! ```text
//! E_t θ_{t+1}      = (1 − ρ) θ̂_t + ρ μ
//! E_t θ_{t+1}θ_{t+1}ᵀ = (1 − ρ)(P_t + θ̂_t θ̂_tᵀ) + ρ (V + μ μᵀ)
//! ```
//!
//! (Σ_j W_j(V_j + μ_jμ_jᵀ) = P_t + θ̂_tθ̂_tᵀ), which is all rules (18) and
//! (20) read; ψ_t = (−y_t, −y_{t−1}, ·) comes from the belief's known
//! entries. Below δ the rule excites, u = y* + ω, ω ~ N(0, δ) from the
//! controller's own stream; before t₀ every step is excitation, as in the
//! `arx-control` experiment. The step t is the sensor sample's sequence
//! number + 1 ([`Controller::set_step`]), so y* is in phase with the plant.

use super::{ArxSystem, Rule, B1, T0};
use crate::backends::ControlContext;
use crate::rng::SimRng;
use beliefbus_changepoint::arx::control::{certainty_equivalence, uncertainty_adjusted};
use beliefbus_changepoint::arx::ThetaPrior;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::control::{ControlError, ControlInfo, Controller};
use rand_distr::{Distribution, Normal};

/// The controller.
#[derive(Debug)]
pub struct ArxAdaptive {
    sys: ArxSystem,
    prior: ThetaPrior<3>,
    omega: Normal<f64>,
    rng: SimRng,
    /// Step t of the next belief (sample seq + 1).
    step: u64,
}

/// The predictive moments of θ_{t+1} from the belief's θ block.
pub fn predictive(g: &Gaussian, rho: f64, prior: &ThetaPrior<3>) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut mean = [0.0; 3];
    let mut second = [[0.0; 3]; 3];
    for a in 0..3 {
        mean[a] = (1.0 - rho) * g.mean[a] + rho * prior.mu[a];
        for b in 0..3 {
            second[a][b] = (1.0 - rho) * (g.cov_at(a, b) + g.mean[a] * g.mean[b])
                + rho * (prior.v[a][b] + prior.mu[a] * prior.mu[b]);
        }
    }
    (mean, second)
}

impl ArxAdaptive {
    /// From `[arx.control]`; the excitation stream is `ctx.seed`.
    pub fn new(sys: &ArxSystem, ctx: &ControlContext) -> Result<Self, String> {
        let delta = sys.params.control.delta;
        Ok(Self {
            sys: sys.clone(),
            prior: sys.theta_prior(),
            omega: Normal::new(0.0, delta.sqrt()).map_err(|e| format!("control.delta: {e}"))?,
            rng: crate::rng::stream(ctx.seed, 0),
            step: 1,
        })
    }
}

impl Controller for ArxAdaptive {
    fn name(&self) -> &'static str {
        super::ADAPTIVE
    }
    fn control_dim(&self) -> usize {
        1
    }
    /// The target is the scenario's reference signal.
    fn set_goal(&mut self, _goal: &[f64]) {}
    fn reset(&mut self) {}
    fn set_step(&mut self, k: u64) {
        self.step = k + 1;
    }
    fn compute(
        &mut self,
        _t: f64,
        belief: &Gaussian,
        u: &mut [f64],
    ) -> Result<ControlInfo, ControlError> {
        if belief.dim != super::STATE {
            return Err(ControlError::Dimension {
                got: belief.dim,
                expected: super::STATE,
            });
        }
        if !belief.is_finite() {
            return Err(ControlError::NonFinite);
        }
        let p = &self.sys.params;
        let target = p.reference(self.step + 1);
        let omega = self.omega.sample(&mut self.rng);
        let psi = [-belief.mean[3], -belief.mean[4], 0.0];
        let (mean, second) = predictive(belief, p.rho, &self.prior);
        let v = if self.step < T0 {
            target + omega
        } else {
            let d = p.control.delta;
            match self.sys.rule {
                Rule::CertaintyEquivalence => {
                    certainty_equivalence(&mean, &psi, B1, target, d, omega)
                }
                Rule::UncertaintyAdjusted => {
                    uncertainty_adjusted(&mean, &second, &psi, B1, target, d, omega)
                }
            }
        };
        if !v.is_finite() {
            return Err(ControlError::Numerical("control rule"));
        }
        u[0] = v;
        // E_t(y_{t+1} − y*)² under the predictive, w = φ_{t+1} with u_t = v.
        let w = [psi[0], psi[1], v];
        let mut cost = 1.0 + target * target;
        for a in 0..3 {
            cost -= 2.0 * target * mean[a] * w[a];
            for b in 0..3 {
                cost += w[a] * second[a][b] * w[b];
            }
        }
        Ok(ControlInfo {
            cost,
            samples: 0,
            ess: 0.0,
        })
    }
}
