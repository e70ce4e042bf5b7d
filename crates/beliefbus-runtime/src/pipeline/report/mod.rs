//! The run report: JSON written by `beliefbus run --report`
//! and the tables printed at the end of a run.
//!
//! ```text
//! { schema_version, scenario, duration_s, sensor_rate_hz, filter_backend, controller,
//!   sensor_source, prefix, sensor_samples, sensor_samples_after_warmup,
//!   hops:   { "sensor->ingest" | "ingest->filter" | "filter->control" |
//!             "sensor->belief" | "sensor->control":
//!             {count, p50_us, p90_us, p99_us, p999_us, max_us} },
//!   stages: { ingest | filter | control | refine | plant:
//!             {pid, core, processed, dropped, rejected, rejected_by_reason,
//!              deadline_misses, deadline_misses_preempted, deadline_misses_host,
//!              deadline_misses_warmup, deadline_misses_after_warmup, miss_warmup_s,
//!              compute_p50_us, compute_p99_us, budget_us,
//!              fifo, mlocked, final_report, exit_status,
//!              misses: [{t_us, t_ns, wall_us, cpu_us, switches, minor_faults,
//!                        major_faults, kind}], misses_not_listed,
//!              restarts, heartbeat_misses, chaos_kills, deaths} },
//!   accuracy: {rmse_position, rmse_state, rmse_position_raw, beliefs, samples},
//!   control:  {waypoints_reached, mean_distance_to_waypoint, controls_received,
//!              controller, cost, compute_p50_us, compute_p99_us},
//!   filter:   {updates, ess_collapses}   (null collapses: a Gaussian filter)
//!   chain:    {versions, states, delta_s, swap_p50_us, swap_p99_us, mass_lost_max,
//!              published, refine_states, fallback_steps, fallback_episodes,
//!              fallback_by_cause: {degenerate, age, evidence}, fallback_reinits,
//!              fallback_untethered,
//!              fallback_cost_p50_us, fallback_cost_p99_us, stale_max_ms}   (filter backend `chain`)
//!   streams:  {observations: {published, counted, unaccounted}},
//!   shared_memory: {files_removed, files_left},
//!   scenario_metrics: {<scenario>: {...}}   (scenarios with their own figures)
//!   run_start_ns,                           (CLOCK_MONOTONIC; origin of the misses' t_us)
//!   supervisor: {...}, timeline: {...} }    (added by the launcher)
//! ```
//! The JSON is written from the serde structs of [`json`] ([`RunReport`]);
//! `schema_version` is [`REPORT_SCHEMA_VERSION`], bumped on any
//! incompatible change. The tables are [`ReportInput::render`].
//! Hops count only samples measured after `run.warmup_s`; a figure with no
//! data is `null` (e.g. control hops of an estimation-only run).
//! `sensor_samples_after_warmup` and the `control` counters come from the
//! plant (built-in, or `beliefbus plant`): `null` with other external
//! publishers, whose controls the pipeline cannot see applied
//! (`stages.control.processed` counts the controls published).
//!
//! `scenario_metrics.<scenario>` is what the scenario's
//! `System::run_metrics` reports (its module documents the keys); the
//! section is absent for scenarios without one, so the layout stays
//! version 1.
//!
//! `control.cost` is the closed-loop running cost per second after the
//! warm-up, (1/T)∫[q(x̂) + w‖u‖²]dt with the tracking cost q of
//! `[control.cost]` at the belief mean x̂ and the active waypoint, each
//! control held until the next belief, w the backend's control weight;
//! `control.compute_p50_us`/`p99_us` are the control stage's compute time
//! per control (belief taken → control published).

mod json;
mod miss_report;
mod render;

pub use json::{
    AccuracyReport, ChainReport, ControlReport, FilterReport, HopJson, HostReport,
    ObservationBooks, RecoveryReport, RecoverySummary, RunReport, SharedMemoryReport, StageReport,
    StageSupervision, StreamsReport, SupervisorReport, REPORT_SCHEMA_VERSION,
};
pub use miss_report::MissReport;

use super::monitor::Accuracy;
use crate::ipc::{Hop, Percentiles, StageKind, StageStats};
use serde::Serialize;

/// Percentiles in µs.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct HopReport {
    pub count: u64,
    pub p50_us: f64,
    pub p90_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
}

fn us(ns: u64) -> f64 {
    ns as f64 / 1e3
}

impl From<&Percentiles> for HopReport {
    fn from(p: &Percentiles) -> Self {
        Self {
            count: p.count,
            p50_us: us(p.p50_ns),
            p90_us: us(p.p90_ns),
            p99_us: us(p.p99_ns),
            p999_us: us(p.p999_ns),
            max_us: us(p.max_ns),
        }
    }
}

/// What the launcher knows about one stage at the end.
#[derive(Clone, Debug, Default)]
pub struct StageEnd {
    pub pid: Option<u32>,
    /// The last report (the final one if the stage stopped cleanly).
    pub stats: Option<StageStats>,
    /// How the process ended (`exit 0`, `signal 9`, ...).
    pub exit: Option<String>,
}

/// Everything the report is made of.
#[derive(Clone, Debug)]
pub struct ReportInput {
    pub scenario: String,
    pub duration_s: f64,
    pub sensor_rate_hz: f64,
    pub filter_backend: String,
    pub controller: String,
    /// `plant` (built-in) or `external` (`beliefbus run --sensor external`).
    pub sensor_source: String,
    pub prefix: String,
    pub stages: Vec<(StageKind, StageEnd)>,
    pub accuracy: Accuracy,
    pub files_removed: usize,
    pub files_left: usize,
    /// When the run started, CLOCK_MONOTONIC ns (0: unknown): the origin
    /// of the times of the stages' misses.
    pub run_start_ns: u64,
}

impl ReportInput {
    fn stats(&self, kind: StageKind) -> Option<&StageStats> {
        self.stages
            .iter()
            .find(|(k, _)| *k == kind)
            .and_then(|(_, e)| e.stats.as_ref())
    }

    /// The percentiles of `hop` from whichever stage measured it.
    pub fn hop(&self, hop: Hop) -> Option<HopReport> {
        self.stages
            .iter()
            .filter_map(|(_, e)| e.stats.as_ref())
            .find_map(|s| s.hop(hop))
            .map(HopReport::from)
    }

    /// The observation stream's books: `published` (ingest's sends, over
    /// every incarnation) = `counted` (the filter's processed + dropped +
    /// rejected, over every incarnation) + `unaccounted`. A clean run ends
    /// with `unaccounted` near 0 (a few in flight at the stop); a filter
    /// restart adds what its dead incarnation held in its queue, what was
    /// published while no filter was subscribed, and what it processed
    /// after its last stats report — no incarnation can count those, so
    /// the report counts them here instead of losing them silently. `null`
    /// without both stages' stats (an external ingest or filter).
    pub fn observation_books(&self) -> Option<(u64, u64, i64)> {
        let i = self.stats(StageKind::Ingest)?;
        let f = self.stats(StageKind::Filter)?;
        // Observations the filter refused as not ingest's were never
        // published by ingest: outside the books.
        let foreign = f.rejected_by_reason[crate::stage::filter::Reason::Foreign as usize];
        let counted = f.processed + f.dropped + f.rejected - foreign.min(f.rejected);
        Some((i.processed, counted, i.processed as i64 - counted as i64))
    }
}

#[cfg(test)]
mod tests;
