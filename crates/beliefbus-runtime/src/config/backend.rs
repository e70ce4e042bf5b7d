//! The filter and controller backend names of `[filter] backend` and
//! `[control] backend`: a built-in backend is a variant, any other name is
//! one the scenario offers (checked at validation, where the registry is
//! known), so the config stays plain strings in TOML and in the report.

use serde::{Deserialize, Serialize};

/// Filter backends: a built-in one, or one the scenario offers by name
/// (`System::filter_backends`; `beliefbus scenarios` lists them).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FilterBackend {
    Pf,
    Ekf,
    Ukf,
    /// The Markov-chain filter on the refine stage's live snapshots.
    Chain,
    /// The projection particle filter (paper 004 §IV): the bootstrap PF's
    /// propagation and weights with `[filter.pf]`'s particles, step and
    /// seed, then the Gaussian projection and N fresh draws from it after
    /// every update.
    ProjectionPf,
    /// A backend the scenario supplies (validated against its list).
    Scenario(String),
}

impl FilterBackend {
    /// The built-in names, in declaration order.
    pub const BUILTIN: [&'static str; 5] = ["pf", "ekf", "ukf", "chain", "projection-pf"];

    /// Config and report name (`[filter] backend = "pf"`, ...).
    pub fn name(&self) -> &str {
        match self {
            FilterBackend::Pf => "pf",
            FilterBackend::Ekf => "ekf",
            FilterBackend::Ukf => "ukf",
            FilterBackend::Chain => "chain",
            FilterBackend::ProjectionPf => "projection-pf",
            FilterBackend::Scenario(n) => n,
        }
    }
}

/// Controller backends: a built-in one, or one the scenario offers by name
/// (`System::controller_backends`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ControlBackend {
    /// Model-predictive path-integral control.
    Mppi,
    /// Path-integral control by implicit sampling (paper 003), `[control.implicit]`.
    Implicit,
    /// No controller: the control stage only consumes beliefs.
    None,
    /// A controller the scenario supplies (validated against its list).
    Scenario(String),
}

impl ControlBackend {
    /// The built-in names, in declaration order.
    pub const BUILTIN: [&'static str; 3] = ["mppi", "implicit", "none"];

    /// Config and report name (`[control] backend = "mppi"`, ...).
    pub fn name(&self) -> &str {
        match self {
            ControlBackend::Mppi => "mppi",
            ControlBackend::Implicit => "implicit",
            ControlBackend::None => "none",
            ControlBackend::Scenario(n) => n,
        }
    }
}

/// Backend names as strings: a built-in name is its variant, any other
/// name a scenario's (checked against the scenario at validation, where
/// the registry is known).
macro_rules! backend_by_name {
    ($t:ident, $($name:literal => $v:ident),+; $doc:literal) => {
        impl std::str::FromStr for $t {
            type Err = std::convert::Infallible;
            fn from_str(s: &str) -> Result<Self, Self::Err> {
                Ok(match s {
                    $($name => $t::$v,)+
                    other => $t::Scenario(other.to_string()),
                })
            }
        }
        impl std::fmt::Display for $t {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.name())
            }
        }
        impl Serialize for $t {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_str(self.name())
            }
        }
        impl<'de> Deserialize<'de> for $t {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let s = String::deserialize(d)?;
                Ok(s.parse().unwrap_or_else(|e: std::convert::Infallible| match e {}))
            }
        }
        impl schemars::JsonSchema for $t {
            fn schema_name() -> std::borrow::Cow<'static, str> {
                stringify!($t).into()
            }
            fn json_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
                schemars::json_schema!({
                    "type": "string",
                    "description": $doc,
                })
            }
        }
    };
}

backend_by_name!(FilterBackend, "pf" => Pf, "ekf" => Ekf, "ukf" => Ukf, "chain" => Chain, "projection-pf" => ProjectionPf;
    "Filter backend: `pf`, `ekf`, `ukf`, `chain` (the Markov-chain filter on the refine stage's live snapshots), `projection-pf` (the bootstrap PF's propagation with `[filter.pf]`'s particles, step and seed, then a Gaussian projection and resampling from it after every update) on an SDE model, or a backend the scenario offers (`beliefbus scenarios` lists them)");
backend_by_name!(ControlBackend, "mppi" => Mppi, "implicit" => Implicit, "none" => None;
    "Controller backend: `mppi` (model-predictive path-integral control), `implicit` (path-integral control by implicit sampling, paper 003, `[control.implicit]`) on an SDE model, `none` (the control stage only consumes beliefs), or a controller the scenario offers");
