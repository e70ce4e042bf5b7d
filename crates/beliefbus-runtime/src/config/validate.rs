//! Validation of a loaded config: every value, and the consistency across
//! sections (dimensions against the scenario's model, the capabilities
//! each backend needs, cores against the machine).

use super::*;

impl RefineConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        positive("refine.period_ms", self.period_ms)?;
        positive("refine.work_ms", self.work_ms)?;
        if self.work_ms > self.period_ms {
            return Err(ConfigError::new(
                "refine.work_ms",
                "must not exceed refine.period_ms",
            ));
        }
        positive("refine.publish_period_ms", self.publish_period_ms)?;
        positive("refine.inflate", self.inflate)?;
        positive("refine.knn_c", self.knn_c)?;
        if !(self.horizon_s.is_finite() && self.horizon_s >= 0.0) {
            return Err(ConfigError::new("refine.horizon_s", "must be >= 0"));
        }
        for (k, v) in [
            ("refine.uniform_fraction", self.uniform_fraction),
            ("refine.min_std_fraction", self.min_std_fraction),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(ConfigError::new(k, "must be in [0, 1]"));
            }
        }
        if !(self.retire_fraction > 0.0 && self.retire_fraction < 1.0) {
            return Err(ConfigError::new(
                "refine.retire_fraction",
                "must be in (0, 1)",
            ));
        }
        if !(100..=1_000_000).contains(&self.max_states) {
            return Err(ConfigError::new(
                "refine.max_states",
                "must be between 100 and 1000000",
            ));
        }
        if !(50..=self.max_states).contains(&self.initial_states) {
            return Err(ConfigError::new(
                "refine.initial_states",
                "must be between 50 and refine.max_states",
            ));
        }
        super::placement::validate(self)
    }
}

impl PipelineConfig {
    /// The controls an actuator of this run may apply: the model's control
    /// dimension, inside the controller's limits (`control.mppi.u_min` /
    /// `u_max`, ±`control.implicit.u_max`; any finite value without a
    /// controller).
    pub fn control_limits(&self) -> Result<crate::ipc::ControlLimits, ConfigError> {
        use crate::ipc::ControlLimits;
        let dim = self.dims()?.control;
        Ok(match self.control.backend {
            ControlBackend::Mppi => {
                ControlLimits::new(&self.control.mppi.u_min, &self.control.mppi.u_max)
            }
            ControlBackend::Implicit => {
                let m = self.control.implicit.u_max;
                ControlLimits::new(&vec![-m; dim], &vec![m; dim])
            }
            // A scenario's controller: any finite control.
            ControlBackend::None | ControlBackend::Scenario(_) => ControlLimits::finite(dim),
        })
    }

    /// Where the stages meet: `run.prefix` and `run.instance`.
    pub fn bus(&self) -> crate::ipc::BusConfig {
        crate::ipc::BusConfig {
            prefix: self.run.prefix.clone(),
            instance: self.run.instance.clone(),
        }
    }

    /// Sensor sample period (s).
    pub fn sample_dt(&self) -> f64 {
        1.0 / self.plant.sensor_rate_hz
    }

    /// The scenario the config resolved to.
    ///
    /// # Panics
    /// On a config that was not produced by loading ([`super::load`] and
    /// friends resolve the scenario before anything can use it).
    pub fn system(&self) -> &dyn System {
        self.scenario
            .as_ref()
            .expect("a loaded config has its scenario resolved")
            .system
            .as_ref()
    }

    /// The scenario's parameter section deserialized as `P` (`None`: the
    /// config has none, the scenario uses its defaults).
    pub fn scenario_params<P: serde::de::DeserializeOwned>(
        &self,
    ) -> Result<Option<P>, ConfigError> {
        let Some(t) = self.scenario.as_ref().and_then(|s| s.params.clone()) else {
            return Ok(None);
        };
        toml::Value::Table(t)
            .try_into()
            .map(Some)
            .map_err(|e: toml::de::Error| ConfigError::new(&self.run.scenario, e.message()))
    }

    /// The registry the scenario was found in.
    pub fn registry(&self) -> Registry {
        self.scenario
            .as_ref()
            .map_or_else(Registry::builtin, |s| s.registry.clone())
    }

    /// The scenario's SDE model (an error for a discrete-time scenario).
    pub fn model(&self) -> Result<DynModel, ConfigError> {
        self.dynamics()?.sde().ok_or_else(|| {
            ConfigError::new(
                "run.scenario",
                format!(
                    "scenario {} is discrete-time: it has no SDE model",
                    self.run.scenario
                ),
            )
        })
    }

    /// How the scenario's system evolves.
    pub fn dynamics(&self) -> Result<crate::scenario::Dynamics, ConfigError> {
        match &self.scenario {
            Some(s) => Ok(s.system.dynamics()),
            None => Err(ConfigError::new(
                "run.scenario",
                "the config was not loaded (scenario unresolved)",
            )),
        }
    }

    /// The system's state, observation and control dimensions.
    pub fn dims(&self) -> Result<crate::model::Dims, ConfigError> {
        self.dynamics().map(|d| d.dims())
    }

    /// The filter's prior N(prior_mean, diag(prior_std²)).
    pub fn prior(&self) -> crate::belief::Gaussian {
        crate::belief::Gaussian::diagonal(&self.filter.prior_mean, &self.filter.prior_std)
    }

    /// Take what the file leaves out from the scenario: the initial state,
    /// the prior and the sensor channels.
    pub(super) fn fill_from_scenario(&mut self) {
        let Some(s) = self.scenario.clone() else {
            return;
        };
        let sys = s.system.as_ref();
        if self.plant.initial_state.is_empty() {
            self.plant.initial_state = sys.initial_state();
        }
        if self.filter.prior_mean.is_empty() || self.filter.prior_std.is_empty() {
            let (m, sd) = sys.prior();
            if self.filter.prior_mean.is_empty() {
                self.filter.prior_mean = m;
            }
            if self.filter.prior_std.is_empty() {
                self.filter.prior_std = sd;
            }
        }
    }

    /// The ingest channel map in effect: `ingest.channels`, else the
    /// scenario's sensor channels (a single one on `plant.channel`), else
    /// `plant.channel` carrying all `obs_dim` components.
    pub fn channels(&self, obs_dim: usize) -> Vec<ChannelConfig> {
        if !self.ingest.channels.is_empty() {
            return self.ingest.channels.clone();
        }
        let declared = self
            .scenario
            .as_ref()
            .map(|s| s.system.sensor_channels())
            .unwrap_or_default();
        match declared.len() {
            0 => vec![ChannelConfig {
                id: self.plant.channel,
                components: (0..obs_dim).collect(),
                max_rate_hz: default_max_rate(),
            }],
            1 => vec![ChannelConfig {
                id: self.plant.channel,
                components: declared[0].components.clone(),
                max_rate_hz: default_max_rate(),
            }],
            _ => declared
                .into_iter()
                .map(|c| ChannelConfig {
                    id: c.id,
                    components: c.components,
                    max_rate_hz: default_max_rate(),
                })
                .collect(),
        }
    }

    /// Check everything; the first problem found is returned.
    pub fn validate(&self) -> Result<(), ConfigError> {
        // Long on purpose: a flat list of independent checks in the order of
        // the config's sections, each naming its key; split, the list would
        // only be scattered.
        let r = &self.run;
        crate::ipc::validate_instance(&r.instance)
            .map_err(|e| ConfigError::new("run.instance", e.to_string()))?;
        crate::ipc::validate_prefix(&r.prefix)
            .map_err(|e| ConfigError::new("run.prefix", e.to_string()))?;
        if !(r.duration_s.is_finite() && r.duration_s >= 0.0) {
            return Err(ConfigError::new("run.duration_s", "must be >= 0"));
        }
        if !(r.warmup_s.is_finite() && r.warmup_s >= 0.0) {
            return Err(ConfigError::new("run.warmup_s", "must be >= 0"));
        }
        positive("run.stats_period_s", r.stats_period_s)?;

        let p = &self.plant;
        positive("plant.sensor_rate_hz", p.sensor_rate_hz)?;
        if p.sensor_rate_hz > limits::MAX_SENSOR_RATE_HZ {
            return Err(ConfigError::new(
                "plant.sensor_rate_hz",
                format!(
                    "must be at most {} Hz, got {}",
                    limits::MAX_SENSOR_RATE_HZ,
                    p.sensor_rate_hz
                ),
            ));
        }
        positive("plant.integration_dt", p.integration_dt)?;
        if p.integration_dt > self.sample_dt() {
            return Err(ConfigError::new(
                "plant.integration_dt",
                format!(
                    "must not exceed the sensor period {} s, got {}",
                    self.sample_dt(),
                    p.integration_dt
                ),
            ));
        }
        if !(1..=limits::MAX_CATCH_UP_PERIODS).contains(&p.catch_up_periods) {
            return Err(ConfigError::new(
                "plant.catch_up_periods",
                format!(
                    "must be between 1 and {}, got {}",
                    limits::MAX_CATCH_UP_PERIODS,
                    p.catch_up_periods
                ),
            ));
        }
        let dynamics = self.dynamics()?;
        let dims = dynamics.dims();
        len_is(
            "plant.initial_state",
            &p.initial_state,
            dims.state,
            "state dimension",
        )?;
        finite_all("plant.initial_state", &p.initial_state)?;

        positive("ingest.max_age_s", self.ingest.max_age_s)?;
        let w = self.ingest.reorder_window_ms;
        if !(w.is_finite() && w >= 0.0 && w <= self.ingest.max_age_s * 1e3) {
            return Err(ConfigError::new(
                "ingest.reorder_window_ms",
                format!("must be >= 0 and at most ingest.max_age_s, got {w}"),
            ));
        }
        let channels = self.channels(dims.obs);
        for (i, c) in channels.iter().enumerate() {
            let key = format!("ingest.channels[{i}]");
            if c.components.is_empty() || c.components.len() > crate::ipc::SENSOR_MAX_DIM {
                return Err(ConfigError::new(
                    format!("{key}.components"),
                    format!("needs 1 to {} entries", crate::ipc::SENSOR_MAX_DIM),
                ));
            }
            if let Some(&bad) = c.components.iter().find(|&&k| k >= dims.obs) {
                return Err(ConfigError::new(
                    format!("{key}.components"),
                    format!(
                        "component {bad} is outside the observation (dimension {})",
                        dims.obs
                    ),
                ));
            }
            positive(&format!("{key}.max_rate_hz"), c.max_rate_hz)?;
            if channels[..i].iter().any(|o| o.id == c.id) {
                return Err(ConfigError::new(
                    format!("{key}.id"),
                    format!("channel {} appears twice", c.id),
                ));
            }
        }

        let f = &self.filter;
        len_is(
            "filter.prior_mean",
            &f.prior_mean,
            dims.state,
            "state dimension",
        )?;
        len_is(
            "filter.prior_std",
            &f.prior_std,
            dims.state,
            "state dimension",
        )?;
        finite_all("filter.prior_mean", &f.prior_mean)?;
        for (i, s) in f.prior_std.iter().enumerate() {
            if !(s.is_finite() && *s > 0.0) {
                return Err(ConfigError::new(
                    "filter.prior_std",
                    format!("entry {i} must be positive, got {s}"),
                ));
            }
        }
        f.pf.validate()
            .map_err(|e| ConfigError::new(format!("filter.pf.{}", e.key), e.problem))?;
        f.ekf
            .validate()
            .map_err(|e| ConfigError::new(format!("filter.ekf.{}", e.key), e.problem))?;
        f.ukf
            .validate(dims.state)
            .map_err(|e| ConfigError::new(format!("filter.ukf.{}", e.key), e.problem))?;
        if !(f.max_obs_age_us.is_finite() && f.max_obs_age_us >= 0.0) {
            return Err(ConfigError::new("filter.max_obs_age_us", "must be >= 0"));
        }
        if let FilterBackend::Scenario(name) = &f.backend {
            self.validate_scenario_filter(name)?;
        } else if f.backend == FilterBackend::ProjectionPf && dynamics.sde().is_none() {
            // A discrete-time system supplies the projection PF on its own
            // model under the same name.
            self.validate_scenario_filter(f.backend.name())?;
        } else {
            let model = self.sde_for("filter.backend", f.backend.name(), &dynamics)?;
            self.validate_sde_filter(&model)?;
        }

        self.validate_control(&dynamics)?;

        self.refine.validate()?;
        let u0 = &self.refine.reference_control;
        if !(u0.is_empty() || u0.len() == dims.control) {
            return Err(ConfigError::new(
                "refine.reference_control",
                format!("needs {} entries (or none)", dims.control),
            ));
        }
        if u0.iter().any(|v| !v.is_finite()) {
            return Err(ConfigError::new(
                "refine.reference_control",
                "must be finite",
            ));
        }
        // A refine round lasts work_ms and counts against the stage's
        // budget: a longer round would be a miss by design. Refine only
        // runs rounds for the chain filter; otherwise it idles.
        let refine_budget_ms = self.stages.get(StageKind::Refine).budget_us * 1e-3;
        let rounds = self.filter.backend == FilterBackend::Chain;
        if rounds && refine_budget_ms > 0.0 && self.refine.work_ms >= refine_budget_ms {
            return Err(ConfigError::new(
                "refine.work_ms",
                "must be below stages.refine.budget_us (a round counts against that budget)",
            ));
        }
        positive(
            "filter.chain.prepare_budget_us",
            self.filter.chain.prepare_budget_us,
        )?;
        let cf = self.filter.chain.collapse_fraction;
        if !(0.0..=1.0).contains(&cf) {
            return Err(ConfigError::new(
                "filter.chain.collapse_fraction",
                format!("must be in [0, 1], got {cf}"),
            ));
        }
        self.filter
            .chain
            .stale
            .validate()
            .map_err(|(k, e)| ConfigError::new(format!("filter.chain.stale.{k}"), e))?;

        let cores = crate::rt::sched::available_cores();
        for kind in StageKind::ALL {
            let s = self.stages.get(kind);
            let key = format!("stages.{}", kind.name());
            s.rt().validate().map_err(|e| ConfigError::new(&key, e))?;
            if let Some(c) = s.core {
                if c >= cores {
                    return Err(ConfigError::new(
                        format!("{key}.core"),
                        format!("core {c} does not exist (this machine has {cores})"),
                    ));
                }
            }
            if !(s.budget_us.is_finite() && s.budget_us >= 0.0) {
                return Err(ConfigError::new(format!("{key}.budget_us"), "must be >= 0"));
            }
            s.restart
                .validate()
                .map_err(|(k, p)| ConfigError::new(format!("{key}.restart.{k}"), p))?;
        }
        self.validate_limits()
    }

    /// The built-in filters' checks against the SDE model.
    fn validate_sde_filter(&self, model: &DynModel) -> Result<(), ConfigError> {
        let f = &self.filter;
        // The integration step of the filter that will run (the chain
        // backend's fallback is the EKF) against the model's time scales:
        // a step too coarse for the drift is refused here, not at start.
        {
            use crate::filter::build::{check_step, BuildError, StepRule};
            let (key, step, rule) = match f.backend {
                FilterBackend::Pf | FilterBackend::ProjectionPf => {
                    ("filter.pf.max_dt", f.pf.max_dt, StepRule::EulerMaruyama)
                }
                FilterBackend::Ekf | FilterBackend::Chain => {
                    ("filter.ekf.max_dt", f.ekf.max_dt, StepRule::Rk4)
                }
                FilterBackend::Ukf => ("filter.ukf.max_dt", f.ukf.max_dt, StepRule::Rk4),
                FilterBackend::Scenario(_) => return Ok(()),
            };
            match check_step(model, &self.prior(), key, step, rule, 0) {
                Ok(()) => {}
                Err(BuildError::Config(e)) => return Err(ConfigError::new(key, e.problem)),
                Err(e) => return Err(ConfigError::new("filter", e.to_string())),
            }
        }
        // Singular F Fᵀ (noise through the velocities only): the moving
        // frame's versions must carry the posterior's correlations, which
        // only the steady placement draws (docs/degenerate-chains.md).
        let steady = self.refine.moving_frame
            && self.refine.placement == super::placement::Placement::Steady;
        if f.backend == FilterBackend::Chain
            && !steady
            && !crate::scenario::full_rank_diffusion(model, &f.prior_mean)
        {
            return Err(ConfigError::new(
                "filter.backend",
                format!(
                    "scenario {}: this model's diffusion is singular at the prior mean (noise \
                     on some coordinates only); the chain filter then needs \
                     refine.moving_frame = true and refine.placement = \"steady\", or use \
                     \"pf\", \"ekf\" or \"ukf\"",
                    self.run.scenario
                ),
            ));
        }

        Ok(())
    }
}

pub(super) fn positive(key: &str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(ConfigError::new(
            key,
            format!("must be positive and finite, got {v}"),
        ))
    }
}

fn finite_all(key: &str, v: &[f64]) -> Result<(), ConfigError> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(i) => Err(ConfigError::new(key, format!("entry {i} is not finite"))),
        None => Ok(()),
    }
}

pub(super) fn len_is(key: &str, v: &[f64], n: usize, what: &str) -> Result<(), ConfigError> {
    if v.len() == n {
        Ok(())
    } else {
        Err(ConfigError::new(
            key,
            format!("needs {n} entries (the {what}), got {}", v.len()),
        ))
    }
}
