//! The live inventory-control scenario `inventory` (Zhou, Fu & Marcus §VI):
//! a discrete-time system, one period per sensor sample,
//!
//! ```text
//! x_{k+1} = max(x_k + u_k − d_k, 0),   u_k ∈ {0, Q},  d_k ~ Exp(mean β)
//! y_k     = x_k + v_k,                  v_k ~ N(0, σ²)
//! g_k     = h·max(x_k + u_k − d_k, 0) + s·max(d_k − x_k − u_k, 0)
//! ```
//!
//! (the paper's h = 1, s = 10, Q = 10, β = 5, x_0 = 5 by default). Its
//! backends, selected by name:
//! - `filter.backend = "projection-pf"`: the projection particle filter on
//!   this model (Gaussian family, [`filter`]);
//! - `control.backend = "belief-mdp"`: the projected-belief MDP's policy
//!   table, solved offline by `beliefbus solve inventory` and looked up at
//!   the nearest grid point of the projected belief (mean, std) each period
//!   ([`control`]); `"ce-threshold"`: certainty equivalence, order iff the
//!   belief's mean is below the full-observation threshold L*;
//!
//! and its report section `scenario_metrics.inventory` ([`metrics`]): the
//! average cost per period, the same for the full-observation threshold
//! policy run on the same demands, and the difference.
//!
//! Pipeline view:
//! - state (x_k, d_{k−1}, g_{k−1}): the inventory, and the demand and cost
//!   of the period that ended at this sample (the report's figures and the
//!   full-observation shadow read them; the filter estimates x_k only);
//! - observation (y_k, u_{k−1}): the noisy count and the order the plant
//!   applied in the period before it, so the filter propagates with the
//!   plant's order even when a control arrives late;
//! - control u_k: the order quantity, 0 or Q.

pub mod control;
pub mod filter;
pub mod metrics;
pub mod plant;
pub mod policy;

use crate::backends::{ControlContext, FilterContext};
use crate::metrics::RunMetrics;
use crate::model::Dims;
use crate::{
    BuildContext, DiscreteSpec, Dynamics, Plant, Scenario, SensorChannel, SolveOutcome,
    SolveRequest, System,
};
use beliefbus_core::control::Controller;
use beliefbus_core::filter::BayesFilter;
use beliefbus_projection::inventory::Inventory;
use serde::{Deserialize, Serialize};

/// Filter backend name.
pub const PPF: &str = "projection-pf";
/// Controller names.
pub const BELIEF_MDP: &str = "belief-mdp";
pub const CE: &str = "ce-threshold";
/// State: inventory, last demand, last cost.
pub const STATE: usize = 3;

/// `[inventory]`: the model, its filter, the full-observation threshold
/// and the offline policy.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct InventoryParams {
    /// Holding cost per unit per period.
    pub h: f64,
    /// Shortage penalty per unit of lost sales.
    pub s: f64,
    /// Order quantity Q.
    pub q: f64,
    /// Mean of the exponential demand.
    pub demand_mean: f64,
    /// Observation noise σ.
    pub sigma: f64,
    /// Initial inventory (known to the filter).
    pub x0: f64,
    /// Full-observation order threshold L* (order iff x < L*): the `ce-threshold`
    /// controller's and the report's reference policy. 7.9 is our scan's
    /// optimum for the paper's parameters (`beliefbus experiment
    /// inventory-average` prints it).
    pub threshold: f64,
    /// `[inventory.filter]`: backend `projection-pf`.
    pub filter: InventoryFilterParams,
    /// `[inventory.policy]`: the offline policy of `belief-mdp`.
    pub policy: InventoryPolicyParams,
}

/// `[inventory.filter]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct InventoryFilterParams {
    /// Particles N.
    pub particles: usize,
}

/// `[inventory.policy]`: how `beliefbus solve inventory` solves the
/// projected-belief MDP (average cost, relative value iteration, on the
/// grid mean 0:0.5:mean_max × std 0:0.2:5) and where the file is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct InventoryPolicyParams {
    /// The policy file. Empty: `<cache>/beliefbus/policies/inventory-average-sigma<σ>.json`
    /// with `<cache>` = `$XDG_CACHE_HOME`, else `$HOME/.cache`, else the
    /// system's temporary directory. A relative path is relative to the
    /// working directory of `beliefbus run` / `beliefbus solve`.
    pub path: String,
    /// Monte Carlo samples N_s per grid point and action of the transitions.
    pub mc_samples: usize,
    /// Monte Carlo samples N_c per grid point and action of the one-step cost.
    pub cost_samples: usize,
    /// Seed of the Monte Carlo build (the `inventory-average` experiment's
    /// `--seed`: the same seed solves the same policy).
    pub seed: u64,
    /// The largest mean of the grid (the paper's 15).
    pub mean_max: f64,
}

impl Default for InventoryParams {
    fn default() -> Self {
        Self {
            h: 1.0,
            s: 10.0,
            q: 10.0,
            demand_mean: 5.0,
            sigma: 1.3,
            x0: 5.0,
            threshold: 7.9,
            filter: InventoryFilterParams { particles: 200 },
            policy: InventoryPolicyParams {
                path: String::new(),
                mc_samples: 500,
                cost_samples: 20_000,
                seed: 1,
                mean_max: 15.0,
            },
        }
    }
}

/// The scenario.
pub struct InventoryScenario;

/// The built system.
#[derive(Clone, Debug)]
pub struct InventorySystem {
    pub params: InventoryParams,
    pub model: Inventory,
}

impl InventoryParams {
    fn validate(&self) -> Result<Inventory, String> {
        let model = Inventory::new(
            self.h,
            self.s,
            self.q,
            self.demand_mean,
            self.sigma,
            self.x0,
        )
        .map_err(|e| e.to_string())?;
        if !(self.threshold.is_finite() && self.threshold >= 0.0) {
            return Err(format!("threshold must be >= 0, got {}", self.threshold));
        }
        if !(1..=100_000).contains(&self.filter.particles) {
            return Err(format!(
                "filter.particles must be in 1..=100000, got {}",
                self.filter.particles
            ));
        }
        let p = &self.policy;
        if p.mc_samples == 0 || p.cost_samples == 0 {
            return Err("policy.mc_samples and policy.cost_samples must be >= 1".into());
        }
        if !(p.mean_max.is_finite() && p.mean_max > 0.0) {
            return Err(format!("policy.mean_max must be > 0, got {}", p.mean_max));
        }
        Ok(model)
    }
}

impl Scenario for InventoryScenario {
    type Params = InventoryParams;
    const NAME: &'static str = "inventory";
    const SUMMARY: &'static str =
        "inventory control under noisy counts (paper 004 sec. VI), discrete time: projection PF and projected-belief MDP policy";
    const CONFIG: &'static str = include_str!("../../../../../configs/inventory.toml");
    fn defaults(_ctx: &BuildContext) -> InventoryParams {
        InventoryParams::default()
    }
    fn params_schema() -> Option<schemars::Schema> {
        crate::inline_schema::<InventoryParams>()
    }
    fn build(p: InventoryParams, _ctx: &BuildContext) -> Result<Box<dyn System>, String> {
        let model = p.validate()?;
        Ok(Box::new(InventorySystem { params: p, model }))
    }
}

impl System for InventorySystem {
    fn dynamics(&self) -> Dynamics {
        Dynamics::Discrete(DiscreteSpec {
            name: "inventory",
            dims: Dims {
                state: STATE,
                noise: 1,
                obs: 2,
                control: 1,
            },
            // The count's σ; the applied order is recorded exactly.
            obs_std: vec![self.params.sigma, 0.0],
        })
    }
    /// The inventory: `rmse_position` is the filter's error on x_k.
    fn position_axes(&self) -> &[usize] {
        &[0]
    }
    /// The count itself.
    fn raw_position(&self, y: &[f64], out: &mut [f64]) -> bool {
        out[0] = y[0];
        true
    }
    fn initial_state(&self) -> Vec<f64> {
        vec![self.params.x0, 0.0, 0.0]
    }
    /// x_0 is known: a nominal std of 10⁻⁶ (the config asks for positive
    /// ones); the other entries are the period's demand and cost, nominal.
    fn prior(&self) -> (Vec<f64>, Vec<f64>) {
        let b = self.params.demand_mean;
        (vec![self.params.x0, b, 0.0], vec![1e-6, b, 1e-6])
    }
    fn sensor_channels(&self) -> Vec<SensorChannel> {
        vec![SensorChannel {
            id: 0,
            name: "count_and_order",
            components: vec![0, 1],
        }]
    }
    fn plant(&self, x0: &[f64], seed: u64, _max_dt: f64) -> Result<Box<dyn Plant>, String> {
        Ok(Box::new(plant::InventoryPlant::new(self, x0, seed)?))
    }
    fn filter_backends(&self) -> Vec<&'static str> {
        vec![PPF]
    }
    fn filter_backend(
        &self,
        name: &str,
        ctx: &FilterContext,
    ) -> Option<Result<Box<dyn BayesFilter>, String>> {
        (name == PPF).then(|| {
            filter::InventoryPpf::new(self, ctx).map(|f| Box::new(f) as Box<dyn BayesFilter>)
        })
    }
    fn controller_backends(&self) -> Vec<&'static str> {
        vec![BELIEF_MDP, CE]
    }
    fn controller(
        &self,
        name: &str,
        _ctx: &ControlContext,
    ) -> Option<Result<Box<dyn Controller>, String>> {
        match name {
            BELIEF_MDP => {
                Some(control::BeliefMdp::new(self).map(|c| Box::new(c) as Box<dyn Controller>))
            }
            CE => Some(Ok(Box::new(control::CeThreshold::new(self)))),
            _ => None,
        }
    }
    fn run_metrics(&self) -> Option<Box<dyn RunMetrics>> {
        Some(Box::new(metrics::InventoryMetrics::new(self)))
    }
    fn solve(&self, req: SolveRequest) -> Option<Result<SolveOutcome, String>> {
        Some(policy::solve(self, req))
    }
}

#[cfg(test)]
mod tests;
