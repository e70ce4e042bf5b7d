//! The pipeline configuration: one TOML file read by the launcher and by
//! every stage, with `--set KEY=VALUE` overrides by dotted path.
//!
//! Loading is all-or-nothing and happens before anything starts:
//! 1. parse the file into a TOML table (syntax errors name the line);
//! 2. apply each `--set` to the table (the key must name a value position;
//!    VALUE is read as TOML, falling back to a string);
//! 3. deserialize with `deny_unknown_fields` everywhere — an unknown key or
//!    a wrong type is reported with its dotted path;
//! 4. validate every value and the cross-section consistency (dimensions
//!    against the scenario's model, cores against the machine, ...).
//!
//! Every error is a [`ConfigError`]: one line naming the key and the
//! problem; the binaries print it and exit with status 2.

use super::scenario::{AnyModel, Scenario};
use crate::control::cost::DiscBarrier;
use crate::control::mppi::MppiConfig;
use crate::control::path_integral::{PathIntegralConfig, PathIntegralConfigError};
use crate::control::waypoints::RouteConfig;
use crate::filter::ekf::EkfConfig;
use crate::filter::pf::PfConfig;
use crate::filter::ukf::UkfConfig;
use crate::ipc::{StageKind, WakeMode};
use crate::model::ship::ShipParams;
use crate::model::vanderpol::VanDerPolParams;
use crate::model::SdeModel;
use crate::rt::RtSettings;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Duration;

/// A configuration problem: the dotted key (empty for the file as a whole)
/// and what is wrong with it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("config: {}{problem}", if key.is_empty() { String::new() } else { format!("`{key}`: ") })]
pub struct ConfigError {
    pub key: String,
    pub problem: String,
}

impl ConfigError {
    fn new(key: impl Into<String>, problem: impl Into<String>) -> Self {
        // One line, whatever the source said.
        let problem: String = problem.into();
        let problem = problem
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .collect::<Vec<_>>()
            .join("; ");
        Self {
            key: key.into(),
            problem,
        }
    }
}

/// The whole pipeline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PipelineConfig {
    pub run: RunConfig,
    /// Ship parameters (scenario `ship`); default: the paper's at the
    /// sensor rate.
    #[serde(default)]
    pub ship: Option<ShipParams>,
    /// Van der Pol parameters (scenario `vanderpol`).
    #[serde(default)]
    pub vanderpol: Option<VanDerPolParams>,
    pub plant: PlantConfig,
    #[serde(default)]
    pub ingest: IngestConfig,
    pub filter: FilterConfig,
    pub control: ControlConfig,
    #[serde(default)]
    pub refine: RefineConfig,
    #[serde(default)]
    pub stages: StagesConfig,
}

/// `[run]`: what runs and where.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    pub scenario: Scenario,
    /// Pipeline instance: services are `beliefbus/<instance>/<channel>`.
    pub instance: String,
    /// Shared-memory prefix used when stages are started by hand; the
    /// launcher replaces it with a fresh one per run.
    #[serde(default = "default_prefix")]
    pub prefix: String,
    /// Base seed of every random stream (plant, filter, controller).
    #[serde(default = "one")]
    pub seed: u64,
    /// Run length when `--duration` is not given (0: until Ctrl-C).
    #[serde(default = "default_duration")]
    pub duration_s: f64,
    /// Samples measured in the first `warmup_s` seconds are left out of the
    /// hop histograms and the accuracy figures.
    #[serde(default = "one_f")]
    pub warmup_s: f64,
    /// Period of the stages' statistics reports.
    #[serde(default = "one_f")]
    pub stats_period_s: f64,
}

fn default_prefix() -> String {
    "iox2_beliefbus_".into()
}
fn one() -> u64 {
    1
}
fn one_f() -> f64 {
    1.0
}
fn default_duration() -> f64 {
    20.0
}

/// `[plant]`: the simulated plant.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantConfig {
    /// Sensor sample rate (Hz).
    pub sensor_rate_hz: f64,
    /// Fine Euler–Maruyama step of the true SDE (seconds).
    pub integration_dt: f64,
    /// True initial state.
    pub initial_state: Vec<f64>,
    /// Sensor channel id the plant publishes on.
    #[serde(default)]
    pub channel: u32,
}

/// `[[ingest.channels]]`: one sensor channel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelConfig {
    /// Channel id in the sensor sample.
    pub id: u32,
    /// Observation components the sample's values fill, in order
    /// (its `dim` must equal their number).
    pub components: Vec<usize>,
    /// Highest accepted sample rate (Hz, by measurement time); faster
    /// samples are rejected as `rate`.
    #[serde(default = "default_max_rate")]
    pub max_rate_hz: f64,
}

fn default_max_rate() -> f64 {
    10_000.0
}

/// `[ingest]`: validation of sensor samples.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IngestConfig {
    /// Samples measured longer than this before they arrive are rejected as
    /// `too_old` (seconds).
    #[serde(default = "default_max_age")]
    pub max_age_s: f64,
    /// Channel map; empty: channel `plant.channel` carries every component.
    #[serde(default)]
    pub channels: Vec<ChannelConfig>,
    /// Longest time an observation is held to merge several channels in
    /// measurement-time order (ms); irrelevant with one channel.
    #[serde(default = "default_reorder_window")]
    pub reorder_window_ms: f64,
}

fn default_reorder_window() -> f64 {
    20.0
}

fn default_max_age() -> f64 {
    0.5
}

impl Default for IngestConfig {
    fn default() -> Self {
        Self {
            max_age_s: default_max_age(),
            channels: Vec::new(),
            reorder_window_ms: default_reorder_window(),
        }
    }
}

/// Filter backends.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FilterBackend {
    Pf,
    Ekf,
    Ukf,
    /// The Markov-chain filter on the refine stage's live snapshots.
    Chain,
}

impl FilterBackend {
    pub fn name(self) -> &'static str {
        match self {
            FilterBackend::Pf => "pf",
            FilterBackend::Ekf => "ekf",
            FilterBackend::Ukf => "ukf",
            FilterBackend::Chain => "chain",
        }
    }
}

/// `[filter]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilterConfig {
    pub backend: FilterBackend,
    /// Prior mean at the first observation.
    pub prior_mean: Vec<f64>,
    /// Prior standard deviations (diagonal covariance).
    pub prior_std: Vec<f64>,
    #[serde(default)]
    pub pf: PfConfig,
    #[serde(default)]
    pub ekf: EkfConfig,
    #[serde(default)]
    pub ukf: UkfConfig,
    #[serde(default)]
    pub chain: ChainFilterConfig,
    /// Freshest-data policy under overload: an observation that waited
    /// longer than this (µs since ingest published it) while a newer one is
    /// queued is skipped and counted as dropped, so a filter slower than the
    /// sensor keeps its latency bounded (0: filter every observation).
    #[serde(default = "default_max_obs_age")]
    pub max_obs_age_us: f64,
}

fn default_max_obs_age() -> f64 {
    50_000.0
}

/// `[filter.chain]`: the chain backend (issue 4).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChainFilterConfig {
    /// Time per filter step (µs) spent preparing a newly received chain
    /// version (validation, observation means) before swapping to it.
    #[serde(default = "default_prepare_budget")]
    pub prepare_budget_us: f64,
    /// Re-anchor the posterior when its effective number of states
    /// (1/Σφ²) falls below this (0: never; see `LiveChainFilter::reanchor`).
    #[serde(default)]
    pub reanchor_ess: f64,
    /// `[filter.chain.stale]`: the stale-chain fallback (see
    /// `stage::chain_guard`).
    #[serde(default)]
    pub stale: crate::stage::chain_guard::StaleConfig,
}

fn default_prepare_budget() -> f64 {
    200.0
}

impl Default for ChainFilterConfig {
    fn default() -> Self {
        Self {
            prepare_budget_us: default_prepare_budget(),
            reanchor_ess: 0.0,
            stale: Default::default(),
        }
    }
}

/// Controller backends.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ControlBackend {
    /// Model-predictive path-integral control.
    Mppi,
    /// Path-integral control by implicit sampling (paper 003), `[control.implicit]`.
    Implicit,
    /// No controller: the control stage only consumes beliefs.
    None,
}

impl ControlBackend {
    pub fn name(self) -> &'static str {
        match self {
            ControlBackend::Mppi => "mppi",
            ControlBackend::Implicit => "implicit",
            ControlBackend::None => "none",
        }
    }
}

/// `[control.cost]`: the tracking cost (weights per state component).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CostConfig {
    /// Running weights per unit time.
    pub q: Vec<f64>,
    /// Terminal weights.
    pub qf: Vec<f64>,
    /// Soft wall keeping two coordinates inside a disc.
    #[serde(default)]
    pub barrier: Option<DiscBarrier>,
}

/// `[control]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlConfig {
    pub backend: ControlBackend,
    /// Waypoints (needed by every backend but `none`).
    #[serde(default)]
    pub route: Option<RouteConfig>,
    #[serde(default)]
    pub cost: Option<CostConfig>,
    #[serde(default)]
    pub mppi: MppiConfig,
    /// The implicit path-integral controller (backend `implicit`).
    #[serde(default)]
    pub implicit: PathIntegralConfig,
    /// Freshest-data policy: a belief older than this (µs since it was
    /// published) when the controller gets to it is skipped and counted as
    /// dropped, so a controller slower than the sensor computes on fresh
    /// beliefs only (0: compute on every latest belief).
    #[serde(default)]
    pub max_belief_age_us: f64,
}

/// `[refine]`: the anytime chain refinement (issue 4).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
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
}

fn default_refine_period() -> f64 {
    50.0
}
fn default_refine_work() -> f64 {
    40.0
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
fn default_knn_c() -> f64 {
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
        }
    }
}

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
        Ok(())
    }
}

/// How a stage waits for input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WakeKind {
    /// Block in a WaitSet until notified.
    #[default]
    Event,
    /// Poll for `spin_us` after each wake-up, then block.
    Spin,
}

/// `[stages.<name>]`: scheduling of one stage process.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageRtConfig {
    /// Core to pin to (none: unpinned).
    #[serde(default)]
    pub core: Option<usize>,
    /// SCHED_FIFO priority 1–99 (none or 0: SCHED_OTHER).
    #[serde(default)]
    pub fifo_priority: Option<u8>,
    /// Nice value under SCHED_OTHER (and the fallback of SCHED_FIFO).
    #[serde(default)]
    pub nice: i32,
    /// mlockall.
    #[serde(default)]
    pub mlock: bool,
    /// Compute budget per message (µs); above it counts as a deadline miss.
    #[serde(default)]
    pub budget_us: f64,
    #[serde(default)]
    pub wake: WakeKind,
    /// Spin time of `wake = "spin"` (µs).
    #[serde(default = "default_spin")]
    pub spin_us: u64,
    /// Supervision: restart policy and heartbeat deadline
    /// (`[stages.<name>.restart]`, see [`super::supervisor`]).
    #[serde(default)]
    pub restart: super::supervisor::RestartPolicy,
}

fn default_spin() -> u64 {
    50
}

impl Default for StageRtConfig {
    fn default() -> Self {
        Self {
            core: None,
            fifo_priority: None,
            nice: 0,
            mlock: false,
            budget_us: 0.0,
            wake: WakeKind::Event,
            spin_us: default_spin(),
            restart: Default::default(),
        }
    }
}

impl StageRtConfig {
    /// The rt settings to apply.
    pub fn rt(&self) -> RtSettings {
        RtSettings {
            core: self.core,
            fifo_priority: self.fifo_priority,
            nice: self.nice,
            mlock: self.mlock,
        }
    }

    /// The wake mode of its loop.
    pub fn wake_mode(&self) -> WakeMode {
        match self.wake {
            WakeKind::Event => WakeMode::Event,
            WakeKind::Spin => WakeMode::SpinThenBlock {
                spin: Duration::from_micros(self.spin_us),
            },
        }
    }

    /// Budget in ns.
    pub fn budget_ns(&self) -> u64 {
        (self.budget_us * 1e3).round() as u64
    }
}

/// `[stages]`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StagesConfig {
    #[serde(default)]
    pub ingest: StageRtConfig,
    #[serde(default)]
    pub filter: StageRtConfig,
    #[serde(default)]
    pub control: StageRtConfig,
    #[serde(default)]
    pub refine: StageRtConfig,
    #[serde(default)]
    pub plant: StageRtConfig,
}

impl StagesConfig {
    /// Settings of one stage.
    pub fn get(&self, kind: StageKind) -> &StageRtConfig {
        match kind {
            StageKind::Ingest => &self.ingest,
            StageKind::Filter => &self.filter,
            StageKind::Control => &self.control,
            StageKind::Refine => &self.refine,
            StageKind::Plant => &self.plant,
        }
    }
}

// ---------------------------------------------------------------------------
// Loading

/// Read `path`, apply `overrides` (`KEY=VALUE`), deserialize and validate.
pub fn load(path: &Path, overrides: &[String]) -> Result<PipelineConfig, ConfigError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| ConfigError::new("", format!("cannot read {}: {e}", path.display())))?;
    load_str(&text, overrides)
}

/// [`load`] from the file's text.
pub fn load_str(text: &str, overrides: &[String]) -> Result<PipelineConfig, ConfigError> {
    let mut table: toml::Table = toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|s| {
                format!(
                    "line {}: ",
                    text[..s.start.min(text.len())].lines().count().max(1)
                )
            })
            .unwrap_or_default();
        ConfigError::new("", format!("{line}{}", e.message()))
    })?;
    for o in overrides {
        apply_override(&mut table, o)?;
    }
    from_table(&table)
}

/// Apply one `KEY=VALUE` to the table.
pub fn apply_override(table: &mut toml::Table, kv: &str) -> Result<(), ConfigError> {
    let (key, value) = kv
        .split_once('=')
        .ok_or_else(|| ConfigError::new(kv.trim(), "--set needs KEY=VALUE"))?;
    let key = key.trim();
    let value = value.trim();
    let parts: Vec<&str> = key.split('.').collect();
    if key.is_empty() || parts.iter().any(|p| p.is_empty()) {
        return Err(ConfigError::new(
            key,
            "--set needs a dotted KEY such as filter.backend",
        ));
    }
    let parsed: toml::Value = match toml::from_str::<toml::Table>(&format!("v = {value}")) {
        Ok(mut t) => t.remove("v").unwrap_or(toml::Value::String(value.into())),
        Err(_) => toml::Value::String(value.to_string()),
    };
    let mut cur = table;
    for (i, p) in parts[..parts.len() - 1].iter().enumerate() {
        let entry = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        cur = match entry {
            toml::Value::Table(t) => t,
            _ => {
                return Err(ConfigError::new(
                    parts[..=i].join("."),
                    "is a value, not a section",
                ))
            }
        };
    }
    cur.insert(parts[parts.len() - 1].to_string(), parsed);
    Ok(())
}

/// Deserialize and validate a table; errors carry the dotted key.
pub fn from_table(table: &toml::Table) -> Result<PipelineConfig, ConfigError> {
    let text = toml::to_string(table).map_err(|e| ConfigError::new("", e.to_string()))?;
    let cfg: PipelineConfig = toml::from_str(&text).map_err(|e| {
        let key = e
            .span()
            .and_then(|s| key_at(&text, s.start))
            .unwrap_or_default();
        ConfigError::new(key, e.message())
    })?;
    cfg.validate()?;
    Ok(cfg)
}

/// The dotted key whose key or value span contains byte `at` of `text`.
fn key_at(text: &str, at: usize) -> Option<String> {
    use toml::de::{DeTable, DeValue};
    let doc = DeTable::parse(text).ok()?;
    fn walk(t: &DeTable, at: usize, path: &mut Vec<String>) -> bool {
        for (k, v) in t.iter() {
            let ks = k.span();
            let vs = v.span();
            if (ks.start <= at && at < ks.end.max(ks.start + 1)) || (vs.start <= at && at < vs.end)
            {
                path.push(k.get_ref().to_string());
                if let DeValue::Table(inner) = v.get_ref() {
                    walk(inner, at, path);
                }
                return true;
            }
            if let DeValue::Table(inner) = v.get_ref() {
                path.push(k.get_ref().to_string());
                if walk(inner, at, path) {
                    return true;
                }
                path.pop();
            }
        }
        false
    }
    let mut path = Vec::new();
    walk(doc.get_ref(), at, &mut path);
    (!path.is_empty()).then(|| path.join("."))
}

fn positive(key: &str, v: f64) -> Result<(), ConfigError> {
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

fn len_is(key: &str, v: &[f64], n: usize, what: &str) -> Result<(), ConfigError> {
    if v.len() == n {
        Ok(())
    } else {
        Err(ConfigError::new(
            key,
            format!("needs {n} entries (the {what}), got {}", v.len()),
        ))
    }
}

impl PipelineConfig {
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

    /// The ship parameters in effect (the paper's at the sensor rate unless
    /// given).
    pub fn ship_params(&self) -> ShipParams {
        self.ship
            .clone()
            .unwrap_or_else(|| ShipParams::paper(self.sample_dt()))
    }

    /// The Van der Pol parameters in effect.
    pub fn vanderpol_params(&self) -> VanDerPolParams {
        self.vanderpol.clone().unwrap_or_default()
    }

    /// The scenario's model.
    pub fn model(&self) -> Result<AnyModel, ConfigError> {
        let key = self.run.scenario.name();
        AnyModel::build(
            self.run.scenario,
            &self.ship_params(),
            &self.vanderpol_params(),
        )
        .map_err(|e| ConfigError::new(key, e))
    }

    /// The ingest channel map in effect.
    pub fn channels(&self, obs_dim: usize) -> Vec<ChannelConfig> {
        if self.ingest.channels.is_empty() {
            vec![ChannelConfig {
                id: self.plant.channel,
                components: (0..obs_dim).collect(),
                max_rate_hz: default_max_rate(),
            }]
        } else {
            self.ingest.channels.clone()
        }
    }

    /// Check everything; the first problem found is returned.
    pub fn validate(&self) -> Result<(), ConfigError> {
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
        let model = self.model()?;
        let dims = model.dims();
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

        self.validate_control(&model)?;

        self.refine.validate()?;
        positive(
            "filter.chain.prepare_budget_us",
            self.filter.chain.prepare_budget_us,
        )?;
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
        Ok(())
    }

    fn validate_control(&self, model: &AnyModel) -> Result<(), ConfigError> {
        let c = &self.control;
        if !(c.max_belief_age_us.is_finite() && c.max_belief_age_us >= 0.0) {
            return Err(ConfigError::new(
                "control.max_belief_age_us",
                "must be >= 0",
            ));
        }
        if c.backend == ControlBackend::None {
            return Ok(());
        }
        let dims = model.dims();
        if dims.control == 0 {
            return Err(ConfigError::new(
                "control.backend",
                format!(
                    "scenario {} has no control input; use \"none\"",
                    self.run.scenario.name()
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
                // Condition (8) and the model's structure, checked at start.
                crate::stage::control::implicit_controller(model, cost, &c.implicit)
                    .map(|_| ())
                    .map_err(|e| ConfigError::new("control.backend", e))
            }
            ControlBackend::None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests;
