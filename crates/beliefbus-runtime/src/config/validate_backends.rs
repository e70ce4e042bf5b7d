//! Validation of the backends a config names: a built-in backend needs an
//! SDE model, a scenario's own backend is built once here so that a bad
//! setting in its section is a config error before anything starts.

use super::*;

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
}
