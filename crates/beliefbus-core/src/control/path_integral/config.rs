//! Settings of the path-integral controller, their validation and the
//! estimator options they imply.

use crate::control::implicit::estimator::{
    EstimatorOptions, GateMode, GateSampling, GradientMethod, MapKind,
};
use crate::control::implicit::newton::NewtonOptions;
use serde::{Deserialize, Serialize};

/// Receding or shrinking horizon.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum HorizonMode {
    /// `horizon_steps` steps from every t.
    Receding,
    /// Up to `final_time` (n = ⌈(t_f − t)/Δt⌉, capped at `horizon_steps`).
    Shrinking,
}

/// How the belief enters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum BeliefMode {
    /// Certainty equivalent: ψ at the belief mean.
    Mean,
    /// ψ averaged over `belief_samples` states drawn from the belief.
    Sampled,
}

/// How ∂ₓ log ψ is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum GradientConfig {
    /// Exact derivative of the linear-map estimator (one banded solve per
    /// control direction).
    Analytic,
    /// The paper's central differences with common random numbers.
    FiniteDifference,
    /// The likelihood-ratio form −E_w[∂ₓF] at fixed samples (u Δt ≈
    /// B⁻¹E_w[r₁], the first noise increment under the weights): no solve
    /// per direction, a value pass per sample.
    LikelihoodRatio,
}

/// How the previous plan is moved to the current time before it warm-starts
/// the minimisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum WarmShift {
    /// By the elapsed time in (fractional) path steps, interpolating the
    /// plan between its grid points.
    Interpolate,
    /// By round(elapsed/Δt) whole steps (the earlier behaviour: with a
    /// control period below Δt/2 the plan never moves).
    WholeSteps,
}

/// Which implicit-sampling map.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum MapConfig {
    Linear,
    Random,
}

/// Settings of the path-integral controller.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PathIntegralConfig {
    /// Path steps n of the horizon (the cap for a shrinking horizon).
    pub horizon_steps: usize,
    /// Path time step Δt in seconds.
    pub dt: f64,
    /// Implicit samples M per initial state (0: Laplace / most likely path).
    pub samples: usize,
    /// Antithetic pairs (ξ, −ξ): exact for linear-quadratic problems.
    pub antithetic: bool,
    pub horizon: HorizonMode,
    /// Final time t_f for the shrinking horizon (seconds).
    pub final_time: f64,
    pub belief: BeliefMode,
    /// States drawn from the belief when `belief = "sampled"`.
    pub belief_samples: usize,
    /// r in R = r I (running control cost ½ uᵀRu).
    pub control_cost: f64,
    /// Each control component is clamped to [−u_max, u_max].
    pub u_max: f64,
    /// κ of the soft limit κ·max(0, |u_c| − u_max)² per unit time on the
    /// controls the planned path implies (0: the paper's unconstrained F,
    /// only the final clamp). See `PathSetup::with_control_limit`.
    pub control_limit_weight: f64,
    /// δ of the C² quadratic–cubic blend of that penalty (force units; 0:
    /// the C¹ max(0, e)² kink). See `PathSetup::with_control_limit`.
    pub control_limit_blend: f64,
    /// Newton stops when ½gᵀH⁻¹g (the error of the minimum F to second
    /// order) ≤ newton_tol · max(1, |F|).
    pub newton_tol: f64,
    /// Seed of the sampler's random numbers.
    pub seed: u64,
    /// Per-control compute budget in µs (0: unlimited).
    pub budget_us: f64,
    pub gradient: GradientConfig,
    /// Finite-difference step h (state units), `gradient = "finite_difference"`.
    pub fd_step: f64,
    pub map: MapConfig,
    /// Newton iteration cap per minimisation.
    pub newton_max_iter: usize,
    /// At the cap, use the iterate reached instead of failing (real-time
    /// iteration: the warm start carries the refinement to the next call).
    pub newton_accept_at_cap: bool,
    /// How the previous plan is advanced to the current time.
    pub warm_shift: WarmShift,
}

impl Default for PathIntegralConfig {
    fn default() -> Self {
        Self {
            horizon_steps: 50,
            dt: 0.04,
            samples: 8,
            antithetic: true,
            horizon: HorizonMode::Receding,
            final_time: 0.0,
            belief: BeliefMode::Mean,
            belief_samples: 4,
            control_cost: 0.1,
            u_max: 3.0,
            control_limit_weight: 10.0,
            control_limit_blend: 0.0,
            newton_tol: 1e-9,
            seed: 1,
            budget_us: 500.0,
            gradient: GradientConfig::Analytic,
            fd_step: 1e-4,
            map: MapConfig::Linear,
            newton_max_iter: 30,
            newton_accept_at_cap: false,
            warm_shift: WarmShift::Interpolate,
        }
    }
}

/// A bad [`PathIntegralConfig`] value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PathIntegralConfigError {
    #[error("{key}: {problem}")]
    Invalid { key: &'static str, problem: String },
}

fn invalid(key: &'static str, problem: impl Into<String>) -> PathIntegralConfigError {
    PathIntegralConfigError::Invalid {
        key,
        problem: problem.into(),
    }
}

/// Most belief draws.
pub const MAX_BELIEF_SAMPLES: usize = 64;

impl PathIntegralConfig {
    /// Check every field.
    pub fn validate(&self) -> Result<(), PathIntegralConfigError> {
        if self.horizon_steps == 0 || self.horizon_steps > 10_000 {
            return Err(invalid("horizon_steps", "must be in 1..=10000"));
        }
        if !(self.dt > 0.0 && self.dt.is_finite()) {
            return Err(invalid("dt", "must be positive and finite"));
        }
        if self.samples > 100_000 {
            return Err(invalid("samples", "at most 100000"));
        }
        if self.belief_samples == 0 || self.belief_samples > MAX_BELIEF_SAMPLES {
            return Err(invalid(
                "belief_samples",
                format!("must be in 1..={MAX_BELIEF_SAMPLES}"),
            ));
        }
        if self.horizon == HorizonMode::Shrinking
            && !(self.final_time > 0.0 && self.final_time.is_finite())
        {
            return Err(invalid(
                "final_time",
                "a shrinking horizon needs a positive final time",
            ));
        }
        if !(self.control_cost > 0.0 && self.control_cost.is_finite()) {
            return Err(invalid("control_cost", "must be positive and finite"));
        }
        if !(self.u_max > 0.0) || self.u_max.is_nan() {
            return Err(invalid("u_max", "must be positive"));
        }
        if !(self.control_limit_weight >= 0.0 && self.control_limit_weight.is_finite()) {
            return Err(invalid("control_limit_weight", "must be ≥ 0 and finite"));
        }
        if !(self.control_limit_blend >= 0.0 && self.control_limit_blend.is_finite()) {
            return Err(invalid("control_limit_blend", "must be ≥ 0 and finite"));
        }
        if !(self.newton_tol > 0.0 && self.newton_tol < 1.0) {
            return Err(invalid("newton_tol", "must be in (0, 1)"));
        }
        if !(self.budget_us >= 0.0 && self.budget_us.is_finite()) {
            return Err(invalid("budget_us", "must be ≥ 0 (0: unlimited)"));
        }
        if !(self.fd_step > 0.0 && self.fd_step.is_finite()) {
            return Err(invalid("fd_step", "must be positive"));
        }
        if self.gradient != GradientConfig::FiniteDifference && self.map == MapConfig::Random {
            return Err(invalid(
                "gradient",
                "the analytic and likelihood-ratio gradients need map = \"linear\"",
            ));
        }
        if self.newton_max_iter == 0 {
            return Err(invalid("newton_max_iter", "must be ≥ 1"));
        }
        Ok(())
    }

    pub(super) fn estimator_options(&self, samples: usize) -> EstimatorOptions {
        EstimatorOptions {
            samples,
            antithetic: self.antithetic,
            map: match self.map {
                MapConfig::Linear => MapKind::Linear,
                MapConfig::Random => MapKind::Random,
            },
            gradient: match self.gradient {
                GradientConfig::Analytic => GradientMethod::Analytic,
                GradientConfig::FiniteDifference => {
                    GradientMethod::FiniteDifference { h: self.fd_step }
                }
                GradientConfig::LikelihoodRatio => GradientMethod::LikelihoodRatio,
            },
            gate_mode: GateMode::AllBasins,
            gate_sampling: GateSampling::Marginal,
            newton: NewtonOptions {
                max_iter: self.newton_max_iter,
                tol_decrement: self.newton_tol,
                reuse_factor: true,
                accept_at_cap: self.newton_accept_at_cap,
                ..NewtonOptions::default()
            },
        }
    }
}
