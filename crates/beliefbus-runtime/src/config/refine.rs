//! `[refine]`: the anytime chain refinement's settings and their defaults.

use super::placement;
use serde::{Deserialize, Serialize};

/// `[refine]`: the anytime chain refinement.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RefineConfig {
    /// Period of its work rounds (ms).
    #[serde(default = "default_refine_period")]
    pub period_ms: f64,
    /// Time spent growing the chain per round (ms, at most `period_ms`).
    #[serde(default = "default_refine_work")]
    pub work_ms: f64,
    /// Snapshot cadence (ms).
    #[serde(default = "default_publish_period")]
    pub publish_period_ms: f64,
    /// Bound on the chain size (also sizes the snapshot service).
    #[serde(default = "default_max_states")]
    pub max_states: usize,
    /// States of the first (batch) chain, around the prior.
    #[serde(default = "default_initial_states")]
    pub initial_states: usize,
    /// Fraction of `max_states` retired when the bound is reached.
    #[serde(default = "default_retire_fraction")]
    pub retire_fraction: f64,
    /// New states: N(mean(τ), (inflate·σ)²) around the belief mean
    /// propagated by the drift for τ ~ U[0, horizon_s] ...
    #[serde(default = "default_inflate")]
    pub inflate: f64,
    /// ... (incremental chain) the horizon of that drift, in seconds ...
    #[serde(default = "default_horizon")]
    pub horizon_s: f64,
    /// ... mixed with this fraction of uniform draws on the model's bounds.
    #[serde(default = "default_uniform_fraction")]
    pub uniform_fraction: f64,
    /// Floor on the sampling std per state component, as a fraction of the
    /// bounds' width (a collapsed belief still gets a neighbourhood).
    #[serde(default = "default_min_std_fraction")]
    pub min_std_fraction: f64,
    /// k-NN Near rule constant: k = max(⌈c log n⌉, 1 + d + d(d+1)/2 + 1).
    #[serde(default = "default_knn_c")]
    pub knn_c: f64,
    /// Moving-frame versions: each snapshot is a batch chain around the
    /// belief built in the frame moving with its states' mean drift on the
    /// translation-invariant axes (the filter carries the frame exactly;
    /// see `LiveChainFilter::set_moving_frame`). Off: one incremental chain.
    #[serde(default)]
    pub moving_frame: bool,
    /// Reference control u₀ the chain versions are built for (hover
    /// thrust, cruise speed): one entry per model control, empty for
    /// u₀ = 0. The filter takes a control's effect relative to f(x, u₀).
    #[serde(default)]
    pub reference_control: Vec<f64>,
    /// Where moving-frame versions put their states: "belief" or "steady".
    #[serde(default)]
    pub placement: placement::Placement,
    /// Steady placement: the latest version is published again as a new
    /// lineage this often (ms); 0: only fresh versions.
    #[serde(default = "default_recenter")]
    pub recenter_ms: f64,
}

fn default_recenter() -> f64 {
    50.0
}

fn default_refine_period() -> f64 {
    10.0
}
fn default_refine_work() -> f64 {
    5.0
}
fn default_publish_period() -> f64 {
    200.0
}
fn default_max_states() -> usize {
    4000
}
fn default_initial_states() -> usize {
    500
}
fn default_retire_fraction() -> f64 {
    0.1
}
fn default_inflate() -> f64 {
    3.0
}
fn default_horizon() -> f64 {
    0.5
}
fn default_uniform_fraction() -> f64 {
    0.02
}
fn default_min_std_fraction() -> f64 {
    0.01
}
pub(super) fn default_knn_c() -> f64 {
    1.5
}

impl Default for RefineConfig {
    fn default() -> Self {
        Self {
            period_ms: default_refine_period(),
            work_ms: default_refine_work(),
            publish_period_ms: default_publish_period(),
            max_states: default_max_states(),
            initial_states: default_initial_states(),
            retire_fraction: default_retire_fraction(),
            inflate: default_inflate(),
            horizon_s: default_horizon(),
            uniform_fraction: default_uniform_fraction(),
            min_std_fraction: default_min_std_fraction(),
            knn_c: default_knn_c(),
            moving_frame: false,
            reference_control: vec![],
            placement: placement::Placement::Belief,
            recenter_ms: default_recenter(),
        }
    }
}
