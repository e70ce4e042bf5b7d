//! Validation of the backends a config names: a built-in backend needs an
//! SDE model, a scenario's own backend is built once here so that a bad
//! setting in its section is a config error before anything starts; and
//! the `[control]` section's own keys against the model.

use super::validate::{len_is, positive};
use super::*;
use crate::control::cost::TrackingCost;
use crate::control::path_integral::{PathIntegralConfigError, PathIntegralController};
use crate::model::SdeModel;

impl PipelineConfig {
    /// The SDE model a built-in backend (`name` at `key`) needs; refused on
    /// a discrete-time scenario, naming the backends it offers.
    pub(super) fn sde_for(
        &self,
        key: &str,
        name: &str,
        dynamics: &crate::scenario::Dynamics,
    ) -> Result<DynModel, ConfigError> {
        dynamics.sde().ok_or_else(|| {
            let sys = self.system();
            let offers = if key == "filter.backend" {
                crate::scenario::registry::supported_filters(sys)
            } else {
                crate::scenario::registry::supported_controllers(sys)
            };
            ConfigError::new(
                key,
                format!(
                    "scenario {} is discrete-time and the built-in backend \"{name}\" needs an \
                     SDE model; scenario {} offers: {}",
                    self.run.scenario,
                    self.run.scenario,
                    offers.join(", ")
                ),
            )
        })
    }

    /// A scenario's own filter: offered by the scenario, and buildable.
    pub(super) fn validate_scenario_filter(&self, name: &str) -> Result<(), ConfigError> {
        let sys = self.system();
        let ctx = crate::scenario::FilterContext {
            seed: self.run.seed,
            sample_dt: self.sample_dt(),
            start: self.prior(),
            resumed: false,
            t0: 0.0,
        };
        match sys.filter_backend(name, &ctx) {
            Some(Ok(_)) => Ok(()),
            Some(Err(e)) => Err(ConfigError::new(
                "filter.backend",
                format!("scenario {}, backend \"{name}\": {e}", self.run.scenario),
            )),
            None => Err(ConfigError::new(
                "filter.backend",
                format!(
                    "unknown backend \"{name}\"; scenario {} offers: {}",
                    self.run.scenario,
                    crate::scenario::registry::supported_filters(sys).join(", ")
                ),
            )),
        }
    }

    /// A scenario's own controller: offered by the scenario, and buildable.
    pub(super) fn validate_scenario_controller(&self, name: &str) -> Result<(), ConfigError> {
        let sys = self.system();
        let ctx = crate::scenario::ControlContext {
            seed: self.run.seed,
            sample_dt: self.sample_dt(),
        };
        match sys.controller(name, &ctx) {
            Some(Ok(_)) => Ok(()),
            Some(Err(e)) => Err(ConfigError::new(
                "control.backend",
                format!("scenario {}, controller \"{name}\": {e}", self.run.scenario),
            )),
            None => Err(ConfigError::new(
                "control.backend",
                format!(
                    "unknown backend \"{name}\"; scenario {} offers: {}",
                    self.run.scenario,
                    crate::scenario::registry::supported_controllers(sys).join(", ")
                ),
            )),
        }
    }

    pub(super) fn validate_control(
        &self,
        dynamics: &crate::scenario::Dynamics,
    ) -> Result<(), ConfigError> {
        // Long on purpose: one flat check per `[control]` key, in key order.
        let c = &self.control;
        if !(c.max_belief_age_us.is_finite() && c.max_belief_age_us >= 0.0) {
            return Err(ConfigError::new(
                "control.max_belief_age_us",
                "must be >= 0",
            ));
        }
        let max_queue = <crate::ipc::Belief as crate::ipc::Message>::QOS.max_buffer;
        if !(1..=max_queue).contains(&c.belief_queue) {
            return Err(ConfigError::new(
                "control.belief_queue",
                format!("must be between 1 and {max_queue}"),
            ));
        }
        match &c.backend {
            ControlBackend::None => return Ok(()),
            ControlBackend::Scenario(name) => return self.validate_scenario_controller(name),
            ControlBackend::Mppi | ControlBackend::Implicit => {}
        }
        let model = self.sde_for("control.backend", c.backend.name(), dynamics)?;
        let dims = model.dims();
        if dims.control == 0 {
            return Err(ConfigError::new(
                "control.backend",
                format!(
                    "scenario {} has no control input; use \"none\"",
                    self.run.scenario
                ),
            ));
        }
        let route = c
            .route
            .as_ref()
            .ok_or_else(|| ConfigError::new("control.route", "is required by this backend"))?;
        if route.waypoints.is_empty() {
            return Err(ConfigError::new(
                "control.route.waypoints",
                "needs at least one waypoint",
            ));
        }
        let axes = self.system().position_axes().len();
        if let Some((i, w)) = route
            .waypoints
            .iter()
            .enumerate()
            .find(|(_, w)| w.len() != axes || w.iter().any(|v| !v.is_finite()))
        {
            return Err(ConfigError::new(
                format!("control.route.waypoints[{i}]"),
                format!(
                    "needs {axes} finite entries (scenario {}'s position axes), got {w:?}",
                    self.run.scenario
                ),
            ));
        }
        positive("control.route.reach_radius", route.reach_radius)?;
        let cost = c
            .cost
            .as_ref()
            .ok_or_else(|| ConfigError::new("control.cost", "is required by this backend"))?;
        len_is("control.cost.q", &cost.q, dims.state, "state dimension")?;
        len_is("control.cost.qf", &cost.qf, dims.state, "state dimension")?;
        for (key, v) in [("control.cost.q", &cost.q), ("control.cost.qf", &cost.qf)] {
            if v.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
                return Err(ConfigError::new(key, "weights must be finite and >= 0"));
            }
        }
        if let Some(b) = &cost.barrier {
            if b.axes.0 >= dims.state || b.axes.1 >= dims.state || b.axes.0 == b.axes.1 {
                return Err(ConfigError::new(
                    "control.cost.barrier.axes",
                    "must be two distinct state components",
                ));
            }
            positive("control.cost.barrier.radius", b.radius)?;
        }
        match c.backend {
            ControlBackend::Mppi => c
                .mppi
                .validate(dims.control)
                .map_err(|e| ConfigError::new(format!("control.mppi.{}", e.key), e.problem)),
            ControlBackend::Implicit => {
                if let Err(PathIntegralConfigError::Invalid { key, problem }) =
                    c.implicit.validate()
                {
                    return Err(ConfigError::new(format!("control.implicit.{key}"), problem));
                }
                let affine = self.system().control_affine().ok_or_else(|| {
                    ConfigError::new(
                        "control.backend",
                        format!(
                            "scenario {} has no control-affine view (System::control_affine), \
                             which the implicit path-integral controller needs; use \"mppi\"",
                            self.run.scenario
                        ),
                    )
                })?;
                // Condition (8) and the model's structure, checked at start.
                let tc = TrackingCost::new(&cost.q, &cost.qf, cost.barrier);
                PathIntegralController::new(affine, tc, c.implicit.clone())
                    .map(|_| ())
                    .map_err(|e| {
                        ConfigError::new(
                            "control.backend",
                            format!("scenario {}: {e}", self.run.scenario),
                        )
                    })
            }
            ControlBackend::None | ControlBackend::Scenario(_) => Ok(()),
        }
    }
}
