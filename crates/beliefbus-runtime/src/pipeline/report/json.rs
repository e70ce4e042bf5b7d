//! The report JSON as serde structs: [`RunReport`] is what `beliefbus run
//! --report FILE` writes (and `launcher::run` returns), field for field;
//! [`ReportInput::report`] builds it from the stages' last statistics.
//! Figures without data are `None` (JSON `null`), never zeros.
//!
//! [`REPORT_SCHEMA_VERSION`] is written as `schema_version`; it is bumped on
//! any incompatible change (a field removed, renamed or changing meaning or
//! unit). Adding a field is compatible and keeps the version.

use super::miss_report::MissReport;
use super::{us, ReportInput};
use crate::ipc::{stats_flags, Hop, StageKind, StageStats};
use crate::stage::{chain_guard, control, filter, ingest, plant, DropReason};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::BTreeMap;

/// Version of the run report's layout (`schema_version`).
pub const REPORT_SCHEMA_VERSION: u32 = 1;

/// The whole run report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunReport {
    pub schema_version: u32,
    pub scenario: String,
    pub duration_s: f64,
    pub sensor_rate_hz: f64,
    pub filter_backend: String,
    pub controller: String,
    /// `plant` or `external`.
    pub sensor_source: String,
    pub prefix: String,
    /// The plant's samples, or (external sensors) what reached ingest.
    pub sensor_samples: u64,
    pub sensor_samples_after_warmup: Option<u64>,
    /// By hop key (`sensor->ingest`, ...).
    pub hops: BTreeMap<String, HopJson>,
    /// By stage name.
    pub stages: BTreeMap<String, StageReport>,
    pub accuracy: AccuracyReport,
    pub control: ControlReport,
    /// The filter's collapsed steps (added with a default: reports written
    /// before it parse).
    #[serde(default)]
    pub filter: FilterReport,
    pub chain: ChainReport,
    pub streams: StreamsReport,
    pub shared_memory: SharedMemoryReport,
    /// The scenario's own figures, keyed by the scenario's name
    /// (`System::run_metrics`; e.g. `scenario_metrics.arx`); absent when
    /// it has none.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub scenario_metrics: BTreeMap<String, Value>,
    /// The supervisor's figures (present when the launcher ran the stages).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub supervisor: Option<SupervisorReport>,
    /// The timeline summary (`--timeline`; null without samples).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timeline: Option<Value>,
    /// When the run started, CLOCK_MONOTONIC ns: the origin of the misses'
    /// `t_us` (absent in reports written before it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run_start_ns: Option<u64>,
    /// Time the machine took from the stages' cores during the run
    /// (present when the launcher ran it on Linux).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<HostReport>,
}

/// Time taken from each core the stages are pinned to, over the run
/// (`/proc/stat`, 10 ms resolution; `beliefbus_rt::host`): the
/// hypervisor's steal and the kernel's interrupt handlers. Beside the
/// stages' `deadline_misses_host` it says whether a miss was the
/// pipeline's or the machine's.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HostReport {
    pub cores: Vec<crate::rt::host::CoreLoss>,
}

/// Percentiles of one hop in µs (`count` 0 and `null`s without data).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HopJson {
    pub count: u64,
    pub p50_us: Option<f64>,
    pub p90_us: Option<f64>,
    pub p99_us: Option<f64>,
    pub p999_us: Option<f64>,
    pub max_us: Option<f64>,
}

/// One stage at the end of the run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageReport {
    pub pid: Option<u32>,
    /// The core it ran on (null: unpinned or no report).
    pub core: Option<i32>,
    pub processed: u64,
    pub dropped: u64,
    pub dropped_by_reason: BTreeMap<String, u64>,
    /// Control: of the stale drops, those published while the stage was
    /// waiting for work (its own backlog did not delay them). Added with a
    /// default: reports written before it parse.
    #[serde(default)]
    pub dropped_stale_idle: u64,
    pub rejected: u64,
    pub rejected_by_reason: BTreeMap<String, u64>,
    pub deadline_misses: u64,
    /// Of the misses, those during which the stage's own CPU time stayed
    /// within the budget: preempted, not an overrun.
    pub deadline_misses_preempted: u64,
    /// Of the preempted misses, those during which the stage's thread was
    /// never switched out: interrupts or the hypervisor took the time (see
    /// `host` for the run's steal and interrupt time per core). Added with
    /// a default: reports written before it parse.
    #[serde(default)]
    pub deadline_misses_host: u64,
    /// Of the misses, those that started in the warm-up (the first
    /// `miss_warmup_s` after the stage's first message, each incarnation),
    /// and the rest: `deadline_misses` = warm-up + after. Added with a
    /// default: reports written before it parse.
    #[serde(default)]
    pub deadline_misses_warmup: u64,
    #[serde(default)]
    pub deadline_misses_after_warmup: u64,
    #[serde(default)]
    pub miss_warmup_s: f64,
    pub compute_p50_us: Option<f64>,
    pub compute_p99_us: Option<f64>,
    pub budget_us: f64,
    pub late: u64,
    /// Response − budget (negative: early).
    pub lateness_p50_us: Option<f64>,
    pub lateness_p99_us: Option<f64>,
    pub lateness_max_us: Option<f64>,
    pub fifo: bool,
    pub mlocked: bool,
    pub final_report: bool,
    /// `exit 0`, `signal 9`, `restart pending (...)`; null: not reaped or
    /// not started by the launcher.
    pub exit_status: Option<String>,
    /// The stage's most recent deadline misses, oldest first (at most
    /// `beliefbus_rt::miss_log::MISS_LOG_CAPACITY`, over every
    /// incarnation). Added with a default: reports written before it parse.
    #[serde(default)]
    pub misses: Vec<MissReport>,
    /// Misses not in `misses` (pushed out by newer ones):
    /// `deadline_misses` = len(`misses`) + this.
    #[serde(default)]
    pub misses_not_listed: u64,
    /// Restarts, heartbeat misses, chaos kills and deaths (when supervised).
    #[serde(default, flatten, skip_serializing_if = "Option::is_none")]
    pub supervision: Option<StageSupervision>,
}

/// A stage's supervision figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StageSupervision {
    pub restarts: u32,
    pub heartbeat_misses: u64,
    /// Only for stages the launcher started.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chaos_kills: Option<u64>,
    /// Causes of the deaths, in order (only for stages the launcher started).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deaths: Option<Vec<String>>,
}

/// Estimation error after the warm-up.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AccuracyReport {
    pub rmse_position: Option<f64>,
    pub rmse_state: Option<f64>,
    pub rmse_position_raw: Option<f64>,
    pub beliefs: u64,
    pub samples: u64,
}

/// The closed loop (module docs of [`super`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ControlReport {
    pub waypoints_reached: Option<u64>,
    pub mean_distance_to_waypoint: Option<f64>,
    pub controls_received: Option<u64>,
    pub controller: String,
    pub cost: Option<f64>,
    pub compute_p50_us: Option<f64>,
    pub compute_p99_us: Option<f64>,
}

/// `filter`: how many of the filter's updates collapsed (see
/// `filter::regularise`: the update kept less than `collapse_fraction` of
/// the effective support — ESS below that fraction of N for the PF — or
/// every weight vanished). `ess_collapses` is null for a Gaussian filter
/// (EKF, UKF) or without the filter's stats.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FilterReport {
    /// Observations filtered (the filter stage's `processed`).
    pub updates: u64,
    pub ess_collapses: Option<u64>,
}

/// The chain filter's section ([`ReportInput::chain`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChainReport {
    pub versions: u64,
    pub states: u64,
    pub delta_s: Option<f64>,
    pub swap_p50_us: Option<f64>,
    pub swap_p99_us: Option<f64>,
    pub mass_lost_max: Option<f64>,
    pub published: u64,
    pub refine_states: u64,
    pub fallback_steps: u64,
    pub fallback_episodes: u64,
    pub fallback_by_cause: BTreeMap<String, u64>,
    pub fallback_reinits: u64,
    pub fallback_untethered: u64,
    pub fallback_cost_p50_us: Option<f64>,
    pub fallback_cost_p99_us: Option<f64>,
    pub stale_max_ms: Option<f64>,
    /// Refine: versions built, their rows, rows meeting their matched
    /// moment equations exactly, rows fitted by least squares, and
    /// versions published again as new lineages (steady placement).
    #[serde(default)]
    pub built: u64,
    #[serde(default)]
    pub rows: u64,
    #[serde(default)]
    pub rows_exact: u64,
    #[serde(default)]
    pub rows_least_squares: u64,
    #[serde(default)]
    pub recentred: u64,
}

/// `streams`: the observation channel's books (null without both stages).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StreamsReport {
    pub observations: Option<ObservationBooks>,
}

/// [`ReportInput::observation_books`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObservationBooks {
    pub published: u64,
    pub counted: u64,
    pub unaccounted: i64,
}

/// What the run left in shared memory.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SharedMemoryReport {
    pub files_removed: usize,
    pub files_left: usize,
}

/// The supervisor's section.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SupervisorReport {
    pub restarts: u64,
    pub heartbeat_misses: u64,
    pub chaos_kills: u64,
    pub dead_nodes_removed: usize,
    /// Deaths whose recovery was not complete at the end.
    pub recoveries_pending: usize,
    pub recovery_ms: RecoverySummary,
    pub recovery_ms_by_stage: BTreeMap<String, RecoverySummary>,
    pub recoveries: Vec<RecoveryReport>,
}

/// Count, lower median (nearest rank) and maximum of recovery times (ms).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RecoverySummary {
    pub count: usize,
    pub p50: Option<f64>,
    pub max: Option<f64>,
}

impl RecoverySummary {
    /// Of these values.
    pub fn of(mut v: Vec<f64>) -> Self {
        v.sort_by(f64::total_cmp);
        Self {
            count: v.len(),
            p50: v.get(v.len().saturating_sub(1) / 2).copied(),
            max: v.last().copied(),
        }
    }
}

/// One death and its recovery.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RecoveryReport {
    pub stage: String,
    pub cause: String,
    pub backoff_ms: f64,
    pub new_pid: Option<u32>,
    /// Null while pending.
    pub recovery_ms: Option<f64>,
}

/// A finite number, else none.
fn finite(v: Option<f64>) -> Option<f64> {
    v.filter(|x| x.is_finite())
}

/// The names of the rejection reasons of stage `kind`, in counter order.
fn reason_names(kind: StageKind) -> Vec<&'static str> {
    match kind {
        StageKind::Ingest => ingest::Reason::ALL.iter().map(|r| r.name()).collect(),
        StageKind::Filter => filter::Reason::ALL.iter().map(|r| r.name()).collect(),
        StageKind::Control => control::Reason::ALL.iter().map(|r| r.name()).collect(),
        StageKind::Plant => plant::Reason::ALL.iter().map(|r| r.name()).collect(),
        _ => Vec::new(),
    }
}

/// A miss as the report lists it, its time relative to `run_start_ns`.
pub(super) fn miss_report(m: &crate::rt::miss_log::Miss, run_start_ns: u64) -> MissReport {
    MissReport {
        t_us: (m.start_ns as i128 - run_start_ns as i128) as f64 / 1e3,
        t_ns: m.start_ns,
        wall_us: us(m.wall_ns),
        cpu_us: m.cpu_ns.map(us),
        switches: m.switches,
        minor_faults: m.faults.map(|f| f.minor),
        major_faults: m.faults.map(|f| f.major),
        kind: m.kind.name().to_string(),
    }
}

fn stage_report(kind: StageKind, end: &super::StageEnd, run_start_ns: u64) -> StageReport {
    let s = end.stats.unwrap_or_default();
    let has = end.stats.is_some();
    let c = &s.compute;
    // Lateness = response − budget (negative: early); null without data.
    let lateness = |r: u64| (s.response_max_ns > 0).then(|| (r as f64 - s.budget_ns as f64) / 1e3);
    StageReport {
        pid: end.pid,
        core: (s.core >= 0).then_some(s.core),
        processed: s.processed,
        dropped: s.dropped,
        dropped_by_reason: DropReason::ALL
            .iter()
            .map(|r| (r.name().to_string(), s.dropped_by_reason[*r as usize]))
            .collect(),
        dropped_stale_idle: s.dropped_stale_idle,
        rejected: s.rejected,
        rejected_by_reason: reason_names(kind)
            .iter()
            .zip(s.rejected_by_reason)
            .map(|(n, v)| (n.to_string(), v))
            .collect(),
        deadline_misses: s.deadline_misses,
        deadline_misses_preempted: s.deadline_misses_preempted,
        deadline_misses_host: s.deadline_misses_host,
        deadline_misses_warmup: s.deadline_misses_warmup,
        deadline_misses_after_warmup: s.deadline_misses - s.deadline_misses_warmup,
        miss_warmup_s: s.miss_warmup_ns as f64 / 1e9,
        compute_p50_us: (c.count > 0).then(|| us(c.p50_ns)),
        compute_p99_us: (c.count > 0).then(|| us(c.p99_ns)),
        budget_us: us(s.budget_ns),
        late: s.late,
        lateness_p50_us: lateness(s.response_p50_ns),
        lateness_p99_us: lateness(s.response_p99_ns),
        lateness_max_us: lateness(s.response_max_ns),
        fifo: has && s.flags & stats_flags::FIFO != 0,
        mlocked: has && s.flags & stats_flags::MLOCKED != 0,
        final_report: has && s.flags & stats_flags::FINAL != 0,
        exit_status: end.exit.clone(),
        misses: s.misses().map(|m| miss_report(&m, run_start_ns)).collect(),
        misses_not_listed: s.miss_log_overwritten,
        supervision: None,
    }
}

impl ReportInput {
    /// The report (without the supervisor's figures, which the launcher
    /// adds).
    pub fn report(&self) -> RunReport {
        let hops = Hop::ALL
            .iter()
            .map(|&h| {
                // An empty histogram (e.g. the control hops of an
                // estimation-only run) is count 0 with null percentiles.
                let v = self.hop(h).filter(|r| r.count > 0).map(|r| HopJson {
                    count: r.count,
                    p50_us: Some(r.p50_us),
                    p90_us: Some(r.p90_us),
                    p99_us: Some(r.p99_us),
                    p999_us: Some(r.p999_us),
                    max_us: Some(r.max_us),
                });
                (h.key().to_string(), v.unwrap_or_default())
            })
            .collect();
        let plant = self.stats(StageKind::Plant);
        let ingest = self.stats(StageKind::Ingest);
        let a = &self.accuracy;
        RunReport {
            schema_version: REPORT_SCHEMA_VERSION,
            scenario: self.scenario.clone(),
            duration_s: self.duration_s,
            sensor_rate_hz: self.sensor_rate_hz,
            filter_backend: self.filter_backend.clone(),
            controller: self.controller.clone(),
            sensor_source: self.sensor_source.clone(),
            prefix: self.prefix.clone(),
            // External sensors without a plant: what reached ingest.
            sensor_samples: plant
                .map(|p| p.processed)
                .or(ingest.map(|i| i.processed + i.rejected + i.dropped))
                .unwrap_or(0),
            sensor_samples_after_warmup: plant.map(|p| p.processed_after_warmup),
            hops,
            stages: self
                .stages
                .iter()
                .map(|(k, e)| (k.name().to_string(), stage_report(*k, e, self.run_start_ns)))
                .collect(),
            accuracy: AccuracyReport {
                rmse_position: finite(a.rmse_position),
                rmse_state: finite(a.rmse_state),
                rmse_position_raw: finite(a.rmse_position_raw),
                beliefs: a.beliefs,
                samples: a.samples,
            },
            control: self.control(),
            filter: self.filter_health(),
            chain: self.chain(),
            streams: StreamsReport {
                observations: self.observation_books().map(|(p, c, u)| ObservationBooks {
                    published: p,
                    counted: c,
                    unaccounted: u,
                }),
            },
            shared_memory: SharedMemoryReport {
                files_removed: self.files_removed,
                files_left: self.files_left,
            },
            scenario_metrics: a
                .scenario
                .iter()
                .map(|v| (self.scenario.clone(), v.clone()))
                .collect(),
            supervisor: None,
            timeline: None,
            run_start_ns: (self.run_start_ns > 0).then_some(self.run_start_ns),
            host: None,
        }
    }

    /// The report as JSON.
    pub fn to_json(&self) -> Value {
        // Plain data with string keys: serialising it cannot fail.
        serde_json::to_value(self.report()).unwrap_or(Value::Null)
    }

    fn control(&self) -> ControlReport {
        let plant = self.stats(StageKind::Plant);
        let ctl = self.stats(StageKind::Control);
        let computed = ctl.filter(|c| c.compute.count > 0);
        ControlReport {
            waypoints_reached: plant.map(|p| p.waypoints_reached),
            mean_distance_to_waypoint: finite(
                plant
                    .filter(|p| p.controls_received > 0)
                    .map(|p| p.mean_goal_distance),
            ),
            controls_received: plant.map(|p| p.controls_received),
            controller: self.controller.clone(),
            cost: finite(
                ctl.filter(|c| c.control_cost_time_s > 0.0)
                    .map(|c| c.control_cost),
            ),
            compute_p50_us: computed.map(|c| us(c.compute.p50_ns)),
            compute_p99_us: computed.map(|c| us(c.compute.p99_ns)),
        }
    }

    /// The `filter` section ([`FilterReport`]).
    pub(super) fn filter_health(&self) -> FilterReport {
        let f = self.stats(StageKind::Filter);
        FilterReport {
            updates: f.map(|s| s.processed).unwrap_or(0),
            ess_collapses: f
                .filter(|s| s.flags & stats_flags::COLLAPSES_COUNTED != 0)
                .map(|s| s.ess_collapses),
        }
    }

    /// The `chain` section: what the filter installed (versions, size and δ
    /// of the active chain, swap durations, largest mass lost in a remap),
    /// what refine published, and the stale-chain fallback
    /// (`stage::chain_guard`): beliefs published from the fallback
    /// (`fallback_steps`), stale episodes (`fallback_episodes`, by the
    /// cause that opened them), chain beliefs re-initialised from the
    /// fallback when a version ended an episode (`fallback_reinits`),
    /// installs that left the fallback apart from a doubtful chain
    /// (`fallback_untethered`), the fallback's predict + update time per
    /// observation — its extra cost — (`fallback_cost_p50_us`/`p99_us`),
    /// and the oldest installed version at a filter step (`stale_max_ms`;
    /// null before any install).
    fn chain(&self) -> ChainReport {
        let f = self.stats(StageKind::Filter);
        let r = self.stats(StageKind::Refine);
        let swaps = f.map(|s| s.chain_versions).unwrap_or(0);
        // Figures of an installed chain: none before the first install.
        let installed = f.filter(|_| swaps > 0);
        let get = |g: fn(&StageStats) -> u64| f.map(g).unwrap_or(0);
        ChainReport {
            versions: swaps,
            states: get(|s| s.chain_states),
            delta_s: finite(installed.map(|s| s.chain_delta_s)),
            swap_p50_us: installed.map(|s| us(s.chain_swap_p50_ns)),
            swap_p99_us: installed.map(|s| us(s.chain_swap_p99_ns)),
            mass_lost_max: finite(installed.map(|s| s.chain_mass_lost_max)),
            published: r.map(|s| s.chain_versions).unwrap_or(0),
            refine_states: r.map(|s| s.chain_states).unwrap_or(0),
            fallback_steps: get(|s| s.chain_fallback_steps),
            fallback_episodes: get(|s| s.chain_fallback_episodes.iter().sum()),
            fallback_by_cause: chain_guard::Cause::ALL
                .iter()
                .map(|c| {
                    let n = f.map(|s| s.chain_fallback_episodes[*c as usize]);
                    (c.name().to_string(), n.unwrap_or(0))
                })
                .collect(),
            fallback_reinits: get(|s| s.chain_fallback_reinits),
            fallback_untethered: get(|s| s.chain_fallback_untethered),
            fallback_cost_p50_us: f
                .filter(|s| s.chain_fallback_p50_ns > 0)
                .map(|s| us(s.chain_fallback_p50_ns)),
            fallback_cost_p99_us: f
                .filter(|s| s.chain_fallback_p99_ns > 0)
                .map(|s| us(s.chain_fallback_p99_ns)),
            stale_max_ms: installed.map(|s| s.chain_stale_max_ns as f64 * 1e-6),
            built: r.map(|s| s.chain_built).unwrap_or(0),
            rows: r.map(|s| s.chain_rows).unwrap_or(0),
            rows_exact: r.map(|s| s.chain_rows_exact).unwrap_or(0),
            rows_least_squares: r.map(|s| s.chain_rows_least_squares).unwrap_or(0),
            recentred: r.map(|s| s.chain_recentred).unwrap_or(0),
        }
    }
}
