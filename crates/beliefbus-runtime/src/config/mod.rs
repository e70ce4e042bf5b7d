//! The pipeline configuration: one TOML file read by the launcher and by
//! every stage, with `--set KEY=VALUE` overrides by dotted path.
//!
//! Loading is all-or-nothing and happens before anything starts
//! ([`load`], [`load_str`], [`from_table`]):
//! 1. parse the file into a TOML table (syntax errors name the line);
//! 2. apply each `--set` to the table (the key must name a value position;
//!    VALUE is read as TOML, falling back to a string);
//! 3. look `run.scenario` up in the [`Registry`] and build its system from
//!    the section named after it (`[ship]`, `[vanderpol]`, a user's
//!    `[pendulum]`; absent: the scenario's defaults);
//! 4. deserialize the rest with `deny_unknown_fields` everywhere — an
//!    unknown key or a wrong type is reported with its dotted path;
//! 5. fill what the config leaves to the scenario (initial state, prior,
//!    sensor channels), then validate every value and the cross-section
//!    consistency (dimensions against the model, the capabilities each
//!    backend needs, cores against the machine, ...).
//!
//! Every error is a [`ConfigError`]: one line naming the key and the
//! problem; the binaries print it and exit with status 2.

mod backend;
pub mod limits;
pub mod load;
pub mod placement;
pub mod reference;
mod refine;
pub mod restart;
pub mod stale;
mod validate;
mod validate_backends;
pub use backend::{ControlBackend, FilterBackend};
pub use refine::RefineConfig;

pub use load::{
    apply_override, from_table, from_table_in, load, load_in, load_str, load_str_in, ConfigSource,
};

use crate::control::cost::DiscBarrier;
use crate::control::mppi::MppiConfig;
use crate::control::path_integral::PathIntegralConfig;
use crate::control::waypoints::RouteConfig;
use crate::filter::ekf::EkfConfig;
use crate::filter::pf::PfConfig;
use crate::filter::ukf::UkfConfig;
use crate::ipc::{StageKind, WakeMode};
use crate::rt::RtSettings;
use crate::scenario::{DynModel, Registry, System};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
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
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PipelineConfig {
    pub run: RunConfig,
    pub plant: PlantConfig,
    #[serde(default)]
    pub ingest: IngestConfig,
    pub filter: FilterConfig,
    pub control: ControlConfig,
    #[serde(default)]
    pub refine: RefineConfig,
    #[serde(default)]
    pub stages: StagesConfig,
    /// The scenario `run.scenario` resolved to (set by loading).
    #[serde(skip)]
    pub scenario: Option<ResolvedScenario>,
}

/// The scenario of a loaded config: its parameter section as written and
/// the system built from it.
#[derive(Clone)]
pub struct ResolvedScenario {
    /// The `[<scenario>]` section (`None`: the scenario's defaults).
    pub params: Option<toml::Table>,
    pub system: Arc<dyn System>,
    /// The registry it was found in (the launcher starts the stages with
    /// the same one).
    pub registry: Registry,
}

impl PartialEq for ResolvedScenario {
    /// Two configs of the same scenario name and parameters built the same
    /// system.
    fn eq(&self, other: &Self) -> bool {
        self.params == other.params
    }
}

impl std::fmt::Debug for ResolvedScenario {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ResolvedScenario")
            .field("params", &self.params)
            .field("model", &self.system.dynamics().name())
            .finish()
    }
}

/// `[run]`: what runs and where.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// The registered scenario to run (`beliefbus scenarios` lists them).
    pub scenario: String,
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
    /// Keep the stages' cores out of idle for the run: one spinner per
    /// core at SCHED_IDLE (any stage preempts it at once). On a VM an idle
    /// core pays a halt exit and a lowered clock on every wake-up; this
    /// trades full power draw on those cores for that latency. The jitter
    /// tool's timer baseline then runs with the same spinners.
    #[serde(default)]
    pub keep_cores_warm: bool,
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
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PlantConfig {
    /// Sensor sample rate (Hz).
    pub sensor_rate_hz: f64,
    /// Fine Euler–Maruyama step of the true SDE (seconds).
    pub integration_dt: f64,
    /// True initial state (empty or absent: the scenario's).
    #[serde(default)]
    pub initial_state: Vec<f64>,
    /// Sensor channel id the plant publishes on.
    #[serde(default)]
    pub channel: u32,
    /// After a stall of the machine, the plant publishes the samples it
    /// owes back to back, each at its own measurement time, for up to this
    /// many periods (1 to 200); older ticks are skipped and counted as
    /// stale. The sensor and observation queues are sized to hold such a
    /// burst whole.
    #[serde(default = "default_catch_up_periods")]
    pub catch_up_periods: u64,
}

fn default_catch_up_periods() -> u64 {
    20
}

/// Room a burst queue keeps beyond the catch-up burst itself: the samples
/// that arrive while the stages below drain it.
const BURST_MARGIN: usize = 32;

impl PlantConfig {
    /// A subscriber queue on `M`'s channel that holds the plant's largest
    /// catch-up burst whole (so a stage preempted by the burst loses none
    /// of it), never shorter than the channel's default and at most its
    /// limit.
    pub fn burst_queue<M: crate::ipc::Message>(&self) -> usize {
        (self.catch_up_periods as usize)
            .saturating_add(BURST_MARGIN)
            .max(M::QOS.default_buffer)
            .min(M::QOS.max_buffer)
    }
}

/// `[[ingest.channels]]`: one sensor channel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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

/// `[filter]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FilterConfig {
    pub backend: FilterBackend,
    /// Prior mean at the first observation (empty or absent: the
    /// scenario's).
    #[serde(default)]
    pub prior_mean: Vec<f64>,
    /// Prior standard deviations, diagonal covariance (empty or absent:
    /// the scenario's).
    #[serde(default)]
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

/// `[filter.chain]`: the chain backend.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    /// An update that keeps less than this fraction of the predicted mass's
    /// effective support, (Σφp)²/(Σφ·Σφp²) — the PF's ESS/N — or that
    /// needs a re-spread, counts as a collapse (report `filter.ess_collapses`;
    /// see `filter::regularise`).
    #[serde(default = "default_collapse_fraction")]
    pub collapse_fraction: f64,
    /// `[filter.chain.stale]`: the stale-chain fallback (see
    /// `stage::chain_guard`).
    #[serde(default)]
    pub stale: stale::StaleConfig,
}

fn default_prepare_budget() -> f64 {
    200.0
}

fn default_collapse_fraction() -> f64 {
    crate::filter::regularise::DEFAULT_COLLAPSE_FRACTION
}

impl Default for ChainFilterConfig {
    fn default() -> Self {
        Self {
            prepare_budget_us: default_prepare_budget(),
            reanchor_ess: 0.0,
            collapse_fraction: default_collapse_fraction(),
            stale: Default::default(),
        }
    }
}

/// `[control.cost]`: the tracking cost (weights per state component).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    /// Beliefs the controller may hold queued (1–256). 1: latest value —
    /// beliefs that arrive together (a sensor burst after a host stall)
    /// are superseded by the newest and counted as dropped. Above 1: a
    /// control for every belief, in arrival order, skipping only those
    /// older than `max_belief_age_us` (set it, or a slow controller falls
    /// behind by up to this many beliefs).
    #[serde(default = "default_belief_queue")]
    pub belief_queue: usize,
}

fn default_belief_queue() -> usize {
    1
}

/// How a stage waits for input.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum WakeKind {
    /// Block in a WaitSet until notified.
    #[default]
    Event,
    /// Poll for `spin_us` after each wake-up, then block.
    Spin,
}

/// `[stages.<name>]`: scheduling of one stage process.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    /// (`[stages.<name>.restart]`, see `pipeline::supervisor`).
    #[serde(default)]
    pub restart: restart::RestartPolicy,
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
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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

#[cfg(test)]
mod tests;
