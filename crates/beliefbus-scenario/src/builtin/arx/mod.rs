//! The live change-point ARX scenario `arx` (Chen, Lai & Wu §3.3–3.4,
//! after Chen & Lai 2007): a discrete-time system, one step per sensor
//! sample,
//!
//! ```text
//! y_t = θ_tᵀφ_t + ε_t,  φ_t = (−y_{t−1}, −y_{t−2}, u_{t−1}),  ε_t ~ N(0, 1)   (13), k = 2, h = 1
//! θ_t = θ_{t−1} w.p. 1 − ρ, else a fresh draw from N(μ, V)                    (t > t₀ = 3)
//! ```
//!
//! with μ = 0, V = I (the paper's V; μ our choice) and, by default, the AR
//! part kept in the stability region |a₁| + |a₂| < 1 (the Table III
//! setting). It brings its own backends, selected by name:
//! - `filter.backend = "rbpf-changepoint"`: the fast Rao-Blackwellised
//!   filter with per-particle Kalman statistics ([`filter`]);
//! - `control.backend = "arx-adaptive"`: rule (18) or (20) on the filter's
//!   belief ([`control`]), tracking the square wave y*;
//!
//! and its own report section `scenario_metrics.arx` ([`metrics`]):
//! tracking error, its ratio to an oracle that knows θ_t, the fraction of
//! steps driven by the previous step's control, and the detection delay of
//! each true change-point.
//!
//! Pipeline view (dimensions fixed, so every stage and message carry it):
//! - state x_t = (a₁, a₂, b₁, y_t, y_{t−1}, r_t) with r_t the time since
//!   the last change-point in seconds (steps × sample period; since the
//!   start before the first); the belief's r entry is the posterior
//!   *median* run length — the Bayes estimate under absolute loss, and
//!   what the detection delay needs (module [`metrics`]);
//! - observation (y_t, u_{t−1}): the output and the input the plant applied
//!   for it, so the filter's regressor is the plant's even when a control
//!   arrives late;
//! - control u_t (one input).

pub mod control;
pub mod filter;
pub mod metrics;
pub mod plant;

use crate::backends::{ControlContext, FilterContext};
use crate::metrics::RunMetrics;
use crate::model::Dims;
use crate::{BuildContext, DiscreteSpec, Dynamics, Plant, Scenario, SensorChannel, System};
use beliefbus_changepoint::arx::ThetaPrior;
use beliefbus_changepoint::resample::Scheme;
use beliefbus_core::control::Controller;
use beliefbus_core::filter::BayesFilter;
use serde::{Deserialize, Serialize};

/// Filter backend name.
pub const RBPF: &str = "rbpf-changepoint";
/// Controller name.
pub const ADAPTIVE: &str = "arx-adaptive";
/// State dimension: θ (3), y_t, y_{t−1}, r_t.
pub const STATE: usize = 6;
/// Index of b₁ in θ (and of u_t in φ_{t+1}).
pub const B1: usize = 2;
/// Index of the run length in the state.
pub const RUN_LENGTH: usize = 5;
/// t₀ = max(k, h) + 1: the first step the filter assimilates.
pub const T0: u64 = 3;

/// `[arx]`: the system, its filter and its controller.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ArxParams {
    /// Probability ρ that θ jumps at a step.
    pub rho: f64,
    /// Draw θ after a jump with |a₁| + |a₂| < 1 (Table III); false: N(0, I)
    /// unrestricted (Table IV, mostly unstable AR parts).
    pub stable_ar: bool,
    /// θ at the start, (a₁, a₂, b₁).
    pub initial_theta: [f64; 3],
    /// Reference y*_t: a square wave of this amplitude ...
    pub reference_amplitude: f64,
    /// ... and this period (steps).
    pub reference_period: u64,
    /// `[arx.filter]`: backend `rbpf-changepoint`.
    pub filter: ArxFilterParams,
    /// `[arx.control]`: backend `arx-adaptive`.
    pub control: ArxControlParams,
}

/// `[arx.filter]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ArxFilterParams {
    /// Particles M.
    pub particles: usize,
    /// Rejuvenate when the weights' cv² reaches this bound (eq. 8).
    pub cv2_bound: f64,
    /// Resampling scheme: "systematic", "residual" or "multinomial".
    pub scheme: String,
}

/// `[arx.control]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ArxControlParams {
    /// 18: certainty equivalence; 20: uncertainty adjusted (the paper's
    /// rule numbers).
    pub rule: u32,
    /// δ_t: below it (|b̂₁| for 18, √E b₁² for 20) the rule excites
    /// instead, u = y* + ω with ω ~ N(0, δ) (δ = var ω as in Table IV).
    pub delta: f64,
}

impl Default for ArxParams {
    fn default() -> Self {
        Self {
            rho: 0.001,
            stable_ar: true,
            initial_theta: [-0.5, 0.2, 1.0],
            reference_amplitude: 1.0,
            reference_period: 100,
            filter: ArxFilterParams {
                particles: 50,
                cv2_bound: 1.0,
                scheme: "systematic".into(),
            },
            control: ArxControlParams {
                rule: 20,
                delta: 0.25,
            },
        }
    }
}

/// Which control rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rule {
    /// (18), certainty equivalence.
    CertaintyEquivalence,
    /// (20), uncertainty adjusted.
    UncertaintyAdjusted,
}

impl ArxParams {
    /// Checked settings.
    fn validate(&self) -> Result<(Scheme, Rule), String> {
        if !(self.rho > 0.0 && self.rho < 1.0) {
            return Err(format!("rho must be in (0, 1), got {}", self.rho));
        }
        if self.initial_theta.iter().any(|v| !v.is_finite()) {
            return Err("initial_theta must be finite".into());
        }
        if !(self.reference_amplitude.is_finite()) || self.reference_period < 2 {
            return Err("reference_amplitude must be finite and reference_period >= 2".into());
        }
        let f = &self.filter;
        if !(1..=100_000).contains(&f.particles) {
            return Err(format!(
                "filter.particles must be in 1..=100000, got {}",
                f.particles
            ));
        }
        if f.cv2_bound.is_nan() || f.cv2_bound < 0.0 {
            return Err(format!(
                "filter.cv2_bound must be >= 0, got {}",
                f.cv2_bound
            ));
        }
        let scheme: Scheme = f.scheme.parse().map_err(|_| {
            format!(
                "filter.scheme must be systematic, residual or multinomial, got {:?}",
                f.scheme
            )
        })?;
        let rule = match self.control.rule {
            18 => Rule::CertaintyEquivalence,
            20 => Rule::UncertaintyAdjusted,
            r => return Err(format!("control.rule must be 18 or 20, got {r}")),
        };
        if !(self.control.delta.is_finite() && self.control.delta >= 0.0) {
            return Err(format!(
                "control.delta must be >= 0, got {}",
                self.control.delta
            ));
        }
        Ok((scheme, rule))
    }

    /// y*_t, t = 1, 2, …: +A on the first half of each period, −A on the
    /// second (the `arx-control` experiment's reference).
    pub fn reference(&self, t: u64) -> f64 {
        let p = self.reference_period;
        if t % p < p / 2 {
            self.reference_amplitude
        } else {
            -self.reference_amplitude
        }
    }
}

/// The scenario.
pub struct ArxScenario;

/// The built system: checked parameters and the sample period.
#[derive(Clone, Debug)]
pub struct ArxSystem {
    pub params: ArxParams,
    pub scheme: Scheme,
    pub rule: Rule,
    pub sample_dt: f64,
}

impl ArxSystem {
    /// The law of θ after a change-point, N(0, I).
    pub fn theta_prior(&self) -> ThetaPrior<3> {
        ThetaPrior::standard()
    }
}

impl Scenario for ArxScenario {
    type Params = ArxParams;
    const NAME: &'static str = "arx";
    const SUMMARY: &'static str =
        "change-point ARX (paper 002 eq. 13, k=2 h=1), discrete time: RBPF and adaptive control rules (18)/(20)";
    const CONFIG: &'static str = include_str!("../../../../../configs/arx.toml");
    fn defaults(_ctx: &BuildContext) -> ArxParams {
        ArxParams::default()
    }
    /// Inlined, so the reference lists `[arx.filter]` and `[arx.control]`
    /// key by key.
    fn params_schema() -> Option<schemars::Schema> {
        crate::inline_schema::<ArxParams>()
    }
    fn build(p: ArxParams, ctx: &BuildContext) -> Result<Box<dyn System>, String> {
        let (scheme, rule) = p.validate()?;
        if !(ctx.sample_dt.is_finite() && ctx.sample_dt > 0.0) {
            return Err(format!(
                "the sample period must be positive, got {}",
                ctx.sample_dt
            ));
        }
        Ok(Box::new(ArxSystem {
            params: p,
            scheme,
            rule,
            sample_dt: ctx.sample_dt,
        }))
    }
}

impl System for ArxSystem {
    fn dynamics(&self) -> Dynamics {
        Dynamics::Discrete(DiscreteSpec {
            name: "arx",
            dims: Dims {
                state: STATE,
                noise: 1,
                obs: 2,
                control: 1,
            },
            // ε_t's σ; the applied input is recorded exactly.
            obs_std: vec![1.0, 0.0],
        })
    }
    /// θ: `rmse_position` is the parameter estimation error.
    fn position_axes(&self) -> &[usize] {
        &[0, 1, 2]
    }
    fn initial_state(&self) -> Vec<f64> {
        let th = self.params.initial_theta;
        vec![th[0], th[1], th[2], 0.0, 0.0, 0.0]
    }
    /// θ ~ N(0, I) as after a change-point; the other entries are known at
    /// the first observation (their std is nominal). The filter uses the
    /// scenario's law of θ, not these.
    fn prior(&self) -> (Vec<f64>, Vec<f64>) {
        (vec![0.0; STATE], vec![1.0; STATE])
    }
    fn sensor_channels(&self) -> Vec<SensorChannel> {
        vec![SensorChannel {
            id: 0,
            name: "output_and_input",
            components: vec![0, 1],
        }]
    }
    fn plant(&self, x0: &[f64], seed: u64, _max_dt: f64) -> Result<Box<dyn Plant>, String> {
        Ok(Box::new(plant::ArxLivePlant::new(self, x0, seed)?))
    }
    fn filter_backends(&self) -> Vec<&'static str> {
        vec![RBPF]
    }
    fn filter_backend(
        &self,
        name: &str,
        ctx: &FilterContext,
    ) -> Option<Result<Box<dyn BayesFilter>, String>> {
        (name == RBPF).then(|| {
            filter::ArxRbpfFilter::new(self, ctx).map(|f| Box::new(f) as Box<dyn BayesFilter>)
        })
    }
    fn controller_backends(&self) -> Vec<&'static str> {
        vec![ADAPTIVE]
    }
    fn controller(
        &self,
        name: &str,
        ctx: &ControlContext,
    ) -> Option<Result<Box<dyn Controller>, String>> {
        (name == ADAPTIVE).then(|| {
            control::ArxAdaptive::new(self, ctx).map(|c| Box::new(c) as Box<dyn Controller>)
        })
    }
    fn run_metrics(&self) -> Option<Box<dyn RunMetrics>> {
        Some(Box::new(metrics::ArxMetrics::new(self)))
    }
}

#[cfg(test)]
mod tests;
