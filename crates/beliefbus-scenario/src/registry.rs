//! The scenario registry: name → constructor. [`Registry::builtin`] holds
//! the scenarios that ship with beliefbus; a user's crate adds its own with
//! [`Registry::with`] and hands the registry to `beliefbus::cli::main_with`.

use super::{BuildContext, Scenario, System};
use crate::model::SdeModel;
use std::sync::Arc;

/// A parameter problem: the key inside the scenario's section (empty for
/// the section as a whole) and what is wrong.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParamError {
    pub key: String,
    pub problem: String,
}

type BuildFn = fn(Option<&toml::Table>, &BuildContext) -> Result<Box<dyn System>, ParamError>;

/// A registered scenario, type-erased.
#[derive(Clone)]
pub struct Entry {
    pub name: &'static str,
    pub summary: &'static str,
    /// The embedded pipeline config that runs it.
    pub config: &'static str,
    build: BuildFn,
    schema: fn() -> Option<schemars::Schema>,
}

impl Entry {
    /// Build the system from its section (`None`: the defaults).
    pub fn build(
        &self,
        section: Option<&toml::Table>,
        ctx: &BuildContext,
    ) -> Result<Arc<dyn System>, ParamError> {
        (self.build)(section, ctx).map(Arc::from)
    }

    /// The parameter section's JSON schema ([`Scenario::params_schema`]).
    pub fn params_schema(&self) -> Option<schemars::Schema> {
        (self.schema)()
    }
}

fn build_typed<S: Scenario>(
    section: Option<&toml::Table>,
    ctx: &BuildContext,
) -> Result<Box<dyn System>, ParamError> {
    let params = match section {
        None => S::defaults(ctx),
        Some(t) => serde_path_to_error::deserialize(over_defaults::<S>(t, ctx)).map_err(
            |e: serde_path_to_error::Error<toml::de::Error>| {
                let path = e.path().to_string();
                ParamError {
                    key: if path == "." { String::new() } else { path },
                    problem: e.inner().message().to_string(),
                }
            },
        )?,
    };
    S::build(params, ctx).map_err(|problem| ParamError {
        key: String::new(),
        problem,
    })
}

/// The section `t` laid over the scenario's defaults: keys the config
/// leaves out keep their default values (also for parameter structs whose
/// defaults depend on the run, like the ship's noise at the sensor rate);
/// the config's keys, unknown ones included, win.
fn over_defaults<S: Scenario>(t: &toml::Table, ctx: &BuildContext) -> toml::Value {
    fn lay(base: &mut toml::Table, top: &toml::Table) {
        for (k, v) in top {
            match (base.get_mut(k), v) {
                (Some(toml::Value::Table(b)), toml::Value::Table(t)) => lay(b, t),
                _ => {
                    base.insert(k.clone(), v.clone());
                }
            }
        }
    }
    let mut base = match toml::Value::try_from(S::defaults(ctx)) {
        Ok(toml::Value::Table(b)) => b,
        _ => toml::Table::new(),
    };
    lay(&mut base, t);
    toml::Value::Table(base)
}

/// What `beliefbus scenarios` lists about one scenario (built with its
/// defaults).
#[derive(Clone, Debug, PartialEq)]
pub struct ScenarioInfo {
    pub name: &'static str,
    pub summary: &'static str,
    pub state: usize,
    pub control: usize,
    pub obs: usize,
    /// `name[components]` per sensor channel.
    pub channels: Vec<String>,
    pub filters: Vec<&'static str>,
    pub controllers: Vec<&'static str>,
}

/// Name → scenario.
#[derive(Clone, Default)]
pub struct Registry {
    entries: Vec<Entry>,
    /// Holds only the built-in scenarios (the stage executables next to the
    /// `beliefbus` binary know exactly these).
    builtin_only: bool,
    /// What `beliefbus run` runs without a config or `--scenario`.
    default: Option<&'static str>,
}

impl std::fmt::Debug for Registry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Registry")
            .field("scenarios", &self.names())
            .field("default", &self.default)
            .finish()
    }
}

impl Registry {
    /// No scenarios.
    pub fn empty() -> Self {
        Self::default()
    }

    /// The scenarios that ship with beliefbus.
    pub fn builtin() -> Self {
        let mut r = Self::empty()
            .with::<super::builtin::ShipScenario>()
            .with::<super::builtin::VanDerPolScenario>()
            .with::<super::builtin::ArxScenario>()
            .with::<super::builtin::CarparkScenario>()
            .with::<super::builtin::InventoryScenario>()
            .with::<super::builtin::VictoriaParkScenario>()
            .with::<super::builtin::LightDarkScenario>();
        r.builtin_only = true;
        r.default = Some(super::builtin::ShipScenario::NAME);
        r
    }

    /// Add scenario `S` (replacing one of the same name) and make it the
    /// default (what `beliefbus run` runs without a config or
    /// `--scenario`).
    pub fn with<S: Scenario>(mut self) -> Self {
        self.entries.retain(|e| e.name != S::NAME);
        self.entries.push(Entry {
            name: S::NAME,
            summary: S::SUMMARY,
            config: S::CONFIG,
            build: build_typed::<S>,
            schema: S::params_schema,
        });
        self.builtin_only = false;
        self.default = Some(S::NAME);
        self
    }

    /// Whether this is exactly [`Registry::builtin`].
    pub fn is_builtin(&self) -> bool {
        self.builtin_only
    }

    /// The scenario called `name`.
    pub fn get(&self, name: &str) -> Option<&Entry> {
        self.entries.iter().find(|e| e.name == name)
    }

    /// Every scenario, in registration order.
    pub fn entries(&self) -> &[Entry] {
        &self.entries
    }

    /// Every name, in registration order.
    pub fn names(&self) -> Vec<&'static str> {
        self.entries.iter().map(|e| e.name).collect()
    }

    /// The default scenario (what `beliefbus run` runs without a config or
    /// `--scenario`): the last one added with [`Registry::with`], ship for
    /// [`Registry::builtin`].
    pub fn default_entry(&self) -> Option<&Entry> {
        self.default.and_then(|n| self.get(n))
    }

    /// What each scenario is and which backends it supports, each built
    /// with its defaults at a 100 Hz sensor.
    pub fn describe(&self) -> Vec<Result<ScenarioInfo, String>> {
        let ctx = BuildContext { sample_dt: 0.01 };
        self.entries
            .iter()
            .map(|e| {
                let sys = e
                    .build(None, &ctx)
                    .map_err(|p| format!("{}: {}", e.name, p.problem))?;
                let dims = sys.dims();
                Ok(ScenarioInfo {
                    name: e.name,
                    summary: e.summary,
                    state: dims.state,
                    control: dims.control,
                    obs: dims.obs,
                    channels: sys
                        .sensor_channels()
                        .iter()
                        .map(|c| format!("{}{:?}", c.name, c.components))
                        .collect(),
                    filters: supported_filters(sys.as_ref()),
                    controllers: supported_controllers(sys.as_ref()),
                })
            })
            .collect()
    }
}

/// Filter backends `sys` supports: the built-in ones on an SDE model
/// (`chain` needs noise on every coordinate at the prior mean), then its
/// own.
pub fn supported_filters(sys: &dyn System) -> Vec<&'static str> {
    let mut v = Vec::new();
    if let Some(m) = sys.sde_model() {
        if super::full_rank_diffusion(&m, &sys.prior().0) {
            v.push("chain");
        }
        v.extend(["pf", "ekf", "ukf", "projection-pf"]);
    }
    v.extend(sys.filter_backends());
    v
}

/// Controller backends `sys` supports: on an SDE model with a control
/// input MPPI (and the implicit path-integral controller with its
/// control-affine view), then its own, then `none`.
pub fn supported_controllers(sys: &dyn System) -> Vec<&'static str> {
    let mut v = Vec::new();
    if let Some(m) = sys.sde_model() {
        if m.dims().control > 0 {
            if sys.control_affine().is_some() {
                v.push("implicit");
            }
            v.push("mppi");
        }
    }
    v.extend(sys.controller_backends());
    v.push("none");
    v
}
