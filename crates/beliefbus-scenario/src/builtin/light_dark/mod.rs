//! The live light-dark scenario `light-dark` (thesis 000 §4.7.2, the 1-D
//! single-beacon problem): an agent on [−2, 2] that sees itself only in
//! the light must find the light, localise, walk to the goal in the dark
//! and declare it,
//!
//! ```text
//! dx = u dt + σ dw,   y = x + G(x) v,   G = ε in the light |x − b| < e_b, 1/ε elsewhere
//! a move costs u² h; declaring ends the episode with +R in the goal |x − g| < e_g, −R outside
//! ```
//!
//! (b = 0.9, e_b = 0.1, g = −0.9, e_g = 0.1, R = 1000, σ = ε = 0.1 by
//! default), solved as the chain POMDP the `pomdp-light-dark` experiment
//! builds ([`model`]). A discrete-time system: one decision period h per
//! sensor sample. Its backends:
//! - `filter.backend = "chain-pomdp"`: the chain filter over the POMDP's
//!   states (predict with the applied control's chain rows, update with
//!   the continuous likelihood; [`filter`]);
//! - `control.backend = "pomdp"`: the α-vector policy solved offline by
//!   `beliefbus solve light-dark`, acting on the chain filter's
//!   distribution (argmax_α α·b), with a background solve that publishes
//!   improved policies the controller swaps in between decisions
//!   ([`control`], [`policy`]);
//!
//! and its report section `scenario_metrics.light-dark` ([`metrics`]):
//! episodes, the fraction that reached the goal, reward per episode,
//! policy-lookup time, policy swaps. Episodes restart at a draw from b₀
//! (uniform) after each declaration, or after `max_steps` moves.
//!
//! The plant ([`plant`]) is either the chain itself (`plant = "chain"`:
//! the model the policy was solved for, the experiment's evaluation) or
//! the SDE integrated over h (`plant = "sde"`: the continuous system the
//! chain approximates). Pipeline layout: [`encoding`].

pub mod control;
pub mod encoding;
pub mod filter;
pub mod flat;
pub mod metrics;
pub mod model;
pub mod plant;
pub mod policy;
pub mod prune;
pub mod swap;

use crate::backends::{ControlContext, FilterContext};
use crate::metrics::RunMetrics;
use crate::model::Dims;
use crate::{
    BuildContext, DiscreteSpec, Dynamics, Plant, Scenario, SensorChannel, SolveOutcome,
    SolveRequest, System,
};
use beliefbus_core::control::Controller;
use beliefbus_core::filter::BayesFilter;
use beliefbus_pomdp::chain_pomdp::ChainPomdp;
use encoding::{CONTROL, OBS, STATE};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Filter backend name.
pub const CHAIN_FILTER: &str = "chain-pomdp";
/// Controller name.
pub const POMDP: &str = "pomdp";

/// `[light-dark]`: the problem, its chain, the plant and the policy.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LightDarkParams {
    /// Centre b of the light.
    pub light: f64,
    /// Half-width e_b of the light (|x − b| < e_b is lit).
    pub light_width: f64,
    /// Centre g of the goal.
    pub goal: f64,
    /// Half-width e_g of the goal.
    pub goal_width: f64,
    /// Process noise σ (dx = u dt + σ dw).
    pub noise: f64,
    /// ε: observation noise ε in the light, 1/ε in the dark.
    pub epsilon: f64,
    /// Discount rate ρ per second (γ = exp(−ρh)).
    pub rate: f64,
    /// Reward R of a declaration in the goal (−R outside it).
    pub reward: f64,
    /// Regular chain states on [−2, 2] (cell centres; at most 54 on the
    /// live path).
    pub states: usize,
    /// Seed of the controls drawn beside {0, −1, 1} (⌊5 ln n⌋ in all;
    /// 29 = the `pomdp-light-dark` experiment's).
    pub control_seed: u64,
    /// The plant: "chain" (the POMDP's own chain, the model the policy was
    /// solved for) or "sde" (the SDE integrated over each period).
    pub plant: String,
    /// An episode without a declaration restarts after this many moves.
    pub max_steps: u64,
    /// `[light-dark.policy]`.
    pub policy: LightDarkPolicyParams,
}

/// `[light-dark.policy]`: the offline solve, where its file is, and the
/// background solve that improves it during a run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LightDarkPolicyParams {
    /// The policy file. Empty: `<cache>/beliefbus/policies/light-dark.alpha`
    /// with `<cache>` = `$XDG_CACHE_HOME`, else `$HOME/.cache`, else the
    /// system's temporary directory.
    pub path: String,
    /// Solver time budget of `beliefbus solve light-dark` (s).
    pub solve_s: f64,
    /// Target gap V̄(b₀) − V̲(b₀) of the solves.
    pub precision: f64,
    /// The controller's background solve: seconds per round (0: off).
    /// Each round continues from the policy in use and publishes its
    /// result when V̲(b₀) improved; the controller swaps it in.
    pub refine_round_s: f64,
    /// At most this many background rounds.
    pub refine_rounds: u64,
    /// Nice level (0..=19) of the background solve's thread. 19 keeps it
    /// out of every other task's way; on a machine busy with other work it
    /// may then get almost no CPU and no improved policy arrives during a
    /// short run (CFS gives nice 19 about 1.5 % of a core against one
    /// nice-0 task), so a lower value trades that away.
    #[serde(default = "default_refine_nice")]
    pub refine_nice: i32,
    /// Most α-vectors the on-line table holds (the lookup costs this many
    /// dot products at most, whatever the solver's set grew to).
    #[serde(default = "default_lookup_capacity")]
    pub lookup_capacity: usize,
    /// Simulated episodes whose beliefs choose the table's vectors.
    #[serde(default = "default_prune_episodes")]
    pub prune_episodes: u64,
}

fn default_lookup_capacity() -> usize {
    128
}

fn default_prune_episodes() -> u64 {
    600
}

fn default_refine_nice() -> i32 {
    19
}

impl Default for LightDarkParams {
    fn default() -> Self {
        Self {
            light: 0.9,
            light_width: 0.1,
            goal: -0.9,
            goal_width: 0.1,
            noise: 0.1,
            epsilon: 0.1,
            rate: 0.1,
            reward: 1000.0,
            states: 20,
            control_seed: 0x1d,
            plant: "chain".into(),
            max_steps: 200,
            policy: LightDarkPolicyParams {
                path: String::new(),
                solve_s: 5.0,
                precision: 1e-2,
                refine_round_s: 2.0,
                refine_rounds: 20,
                refine_nice: default_refine_nice(),
                lookup_capacity: default_lookup_capacity(),
                prune_episodes: default_prune_episodes(),
            },
        }
    }
}

/// Which plant simulates the truth.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlantKind {
    Chain,
    Sde,
}

impl LightDarkParams {
    /// Whether x is in the goal.
    pub fn in_goal(&self, x: f64) -> bool {
        (x - self.goal).abs() < self.goal_width
    }

    /// The observation model.
    pub fn obs(&self) -> model::LightObs {
        model::LightObs {
            light: self.light,
            light_width: self.light_width,
            eps: self.epsilon,
        }
    }

    fn validate(&self) -> Result<PlantKind, String> {
        let pos = |x: f64| x.is_finite() && x > 0.0;
        let inside = |x: f64| x.is_finite() && x.abs() < model::HALF;
        if !(inside(self.light) && inside(self.goal)) {
            return Err("light and goal must lie inside (-2, 2)".into());
        }
        for (k, v) in [
            ("light_width", self.light_width),
            ("goal_width", self.goal_width),
            ("noise", self.noise),
            ("epsilon", self.epsilon),
            ("rate", self.rate),
            ("reward", self.reward),
            ("policy.solve_s", self.policy.solve_s),
            ("policy.precision", self.policy.precision),
        ] {
            if !pos(v) {
                return Err(format!("{k} must be positive and finite, got {v}"));
            }
        }
        if !(self.policy.refine_round_s.is_finite() && self.policy.refine_round_s >= 0.0) {
            return Err(format!(
                "policy.refine_round_s must be >= 0, got {}",
                self.policy.refine_round_s
            ));
        }
        if !(0..=19).contains(&self.policy.refine_nice) {
            return Err(format!(
                "policy.refine_nice must be in 0..=19, got {}",
                self.policy.refine_nice
            ));
        }
        if self.policy.lookup_capacity == 0 || self.policy.prune_episodes == 0 {
            return Err(format!(
                "policy.lookup_capacity and policy.prune_episodes must be >= 1, got {} and {}",
                self.policy.lookup_capacity, self.policy.prune_episodes
            ));
        }
        if !(3..=encoding::MAX_CHAIN).contains(&self.states) {
            return Err(format!(
                "states must be in 3..={} (the chain distribution rides in the belief message), got {}",
                encoding::MAX_CHAIN,
                self.states
            ));
        }
        if self.max_steps == 0 {
            return Err("max_steps must be >= 1".into());
        }
        match self.plant.as_str() {
            "chain" => Ok(PlantKind::Chain),
            "sde" => Ok(PlantKind::Sde),
            other => Err(format!("plant must be \"chain\" or \"sde\", got {other:?}")),
        }
    }
}

/// The scenario.
pub struct LightDarkScenario;

/// The built system: the parameters and the chain POMDP.
#[derive(Clone, Debug)]
pub struct LightDarkSystem {
    pub params: LightDarkParams,
    pub plant_kind: PlantKind,
    pub pomdp: Arc<ChainPomdp>,
    /// [`model::model_key`] of `pomdp`.
    pub key: String,
}

impl Scenario for LightDarkScenario {
    type Params = LightDarkParams;
    const NAME: &'static str = "light-dark";
    const SUMMARY: &'static str =
        "1-D light-dark (thesis 000 sec. 4.7.2), discrete time: chain filter and alpha-vector POMDP policy with live swaps";
    const CONFIG: &'static str = include_str!("../../../../../configs/light-dark.toml");
    fn defaults(_ctx: &BuildContext) -> LightDarkParams {
        LightDarkParams::default()
    }
    fn params_schema() -> Option<schemars::Schema> {
        crate::inline_schema::<LightDarkParams>()
    }
    fn build(p: LightDarkParams, _ctx: &BuildContext) -> Result<Box<dyn System>, String> {
        Ok(Box::new(LightDarkSystem::new(p)?))
    }
}

impl LightDarkSystem {
    pub fn new(params: LightDarkParams) -> Result<Self, String> {
        let plant_kind = params.validate()?;
        let cp = model::build(&params)?;
        let key = model::model_key(&cp, &params.obs());
        Ok(Self {
            params,
            plant_kind,
            pomdp: Arc::new(cp),
            key,
        })
    }

    /// The action whose control is nearest `v` (the chain's controls are
    /// 1-D; the terminal action is never nearest).
    pub fn nearest_action(&self, v: f64) -> usize {
        let cp = &self.pomdp;
        let mut best = (cp.offset, f64::INFINITY);
        for (i, c) in cp.controls.iter().enumerate() {
            let d = (c[0] - v).abs();
            if d < best.1 {
                best = (cp.offset + i, d);
            }
        }
        best.0
    }
}

impl System for LightDarkSystem {
    fn dynamics(&self) -> Dynamics {
        Dynamics::Discrete(DiscreteSpec {
            name: "light-dark",
            dims: Dims {
                state: STATE,
                noise: 1,
                obs: OBS,
                control: CONTROL,
            },
            // The dark's σ; the applied velocity and the episode flag are exact.
            obs_std: vec![1.0 / self.params.epsilon, 0.0, 0.0],
        })
    }
    fn position_axes(&self) -> &[usize] {
        &[0]
    }
    fn raw_position(&self, y: &[f64], out: &mut [f64]) -> bool {
        out[0] = y[0];
        true
    }
    /// Nominal: each episode starts at a draw from b₀ (uniform).
    fn initial_state(&self) -> Vec<f64> {
        vec![0.0; STATE]
    }
    /// b₀ uniform on [−2, 2]: mean 0, std 4/√12.
    fn prior(&self) -> (Vec<f64>, Vec<f64>) {
        (
            vec![0.0; STATE],
            vec![2.0 * model::HALF / 12f64.sqrt(), 1e-6, 1e-6],
        )
    }
    fn sensor_channels(&self) -> Vec<SensorChannel> {
        vec![SensorChannel {
            id: 0,
            name: "position_velocity_episode",
            components: vec![0, 1, 2],
        }]
    }
    fn plant(&self, _x0: &[f64], seed: u64, max_dt: f64) -> Result<Box<dyn Plant>, String> {
        Ok(Box::new(plant::LightDarkPlant::new(self, seed, max_dt)))
    }
    fn filter_backends(&self) -> Vec<&'static str> {
        vec![CHAIN_FILTER]
    }
    fn filter_backend(
        &self,
        name: &str,
        ctx: &FilterContext,
    ) -> Option<Result<Box<dyn BayesFilter>, String>> {
        (name == CHAIN_FILTER).then(|| {
            Ok(Box::new(filter::ChainBeliefFilter::new(self, ctx)) as Box<dyn BayesFilter>)
        })
    }
    fn controller_backends(&self) -> Vec<&'static str> {
        vec![POMDP]
    }
    fn controller(
        &self,
        name: &str,
        _ctx: &ControlContext,
    ) -> Option<Result<Box<dyn Controller>, String>> {
        (name == POMDP).then(|| {
            control::PomdpController::new(self).map(|c| Box::new(c) as Box<dyn Controller>)
        })
    }
    fn run_metrics(&self) -> Option<Box<dyn RunMetrics>> {
        Some(Box::new(metrics::LightDarkMetrics::new()))
    }
    fn solve(&self, req: SolveRequest) -> Option<Result<SolveOutcome, String>> {
        Some(policy::solve(self, req))
    }
}

#[cfg(test)]
mod tests;
