//! The latency, stage, accuracy, chain and control tables printed at the
//! end of a run (the same figures as the JSON, for a terminal).

use super::{us, ReportInput};
use crate::ipc::{Hop, StageKind};

impl ReportInput {
    /// The latency and stage tables printed at the end of a run.
    pub fn render(&self) -> String {
        let mut out = self.hop_table();
        out.push('\n');
        out.push_str(&self.stage_table());
        out.push_str(&self.miss_lines());
        out.push_str(&self.summary_lines());
        out
    }

    /// One line per hop: count and percentiles (µs).
    fn hop_table(&self) -> String {
        let mut out = String::new();
        out.push_str(&format!(
            "{:<17} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9}\n",
            "hop (µs)", "count", "p50", "p90", "p99", "p99.9", "max"
        ));
        for h in Hop::ALL {
            match self.hop(h) {
                Some(r) if r.count > 0 => out.push_str(&format!(
                    "{:<17} {:>8} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9.1}\n",
                    h.key(),
                    r.count,
                    r.p50_us,
                    r.p90_us,
                    r.p99_us,
                    r.p999_us,
                    r.max_us
                )),
                _ => out.push_str(&format!("{:<17} {:>8}\n", h.key(), 0)),
            }
        }
        out
    }

    /// One line per stage: pid, core, counters, compute and lateness.
    /// `preempt`: the misses during which the stage's own CPU time stayed
    /// within its budget (time taken from it, not an overrun); `host`: of
    /// those, the ones during which it was never switched out (interrupts
    /// or the hypervisor took the time); `warm`/`after`: the misses that
    /// started in the stage's warm-up and after it (they add up to
    /// `misses`).
    fn stage_table(&self) -> String {
        let mut out = format!(
            "{:<8} {:>7} {:>4} {:>9} {:>7} {:>8} {:>6} {:>5} {:>5} {:>7} {:>5} {:>10} {:>10} {:>9} {:>6} {:>11}\n",
            "stage",
            "pid",
            "core",
            "processed",
            "dropped",
            "rejected",
            "misses",
            "warm",
            "after",
            "preempt",
            "host",
            "cpu p50µs",
            "cpu p99µs",
            "budgetµs",
            "late",
            "late p99µs"
        );
        for (kind, end) in &self.stages {
            let s = end.stats.unwrap_or_default();
            out.push_str(&format!(
                "{:<8} {:>7} {:>4} {:>9} {:>7} {:>8} {:>6} {:>5} {:>5} {:>7} {:>5} {:>10.1} {:>10.1} {:>9.0} {:>6} {:>11}\n",
                kind.name(),
                end.pid.map(|p| p.to_string()).unwrap_or("-".into()),
                if s.core >= 0 {
                    s.core.to_string()
                } else {
                    "-".into()
                },
                s.processed,
                s.dropped,
                s.rejected,
                s.deadline_misses,
                s.deadline_misses_warmup,
                s.deadline_misses - s.deadline_misses_warmup,
                s.deadline_misses_preempted,
                s.deadline_misses_host,
                us(s.compute.p50_ns),
                us(s.compute.p99_ns),
                us(s.budget_ns),
                s.late,
                if s.response_max_ns > 0 {
                    format!("{:.1}", us(s.response_p99_ns) - us(s.budget_ns))
                } else {
                    "-".into()
                },
            ));
        }
        out
    }

    /// One line per listed miss of each stage that missed, oldest first:
    /// when it started (s after the run's start, and on CLOCK_MONOTONIC as
    /// an `ftrace`/`perf` trace prints it), its wall and thread CPU time,
    /// context switches and kind; first how many earlier misses are no
    /// longer listed, if any.
    fn miss_lines(&self) -> String {
        let mut out = String::new();
        let warmup_s = self
            .stages
            .iter()
            .filter_map(|(_, e)| e.stats.as_ref())
            .find(|s| s.deadline_misses > 0)
            .map(|s| s.miss_warmup_ns as f64 / 1e9);
        if let Some(w) = warmup_s {
            out.push_str(&format!(
                "warm: misses that started in the first {w:.1} s after the stage's first \
                 message (run.warmup_s); after: the rest; misses = warm + after\n"
            ));
        }
        for (kind, end) in &self.stages {
            let Some(s) = end.stats.as_ref() else {
                continue;
            };
            if s.miss_log_overwritten > 0 {
                out.push_str(&format!(
                    "{} earlier {} misses not listed (the list keeps the latest {})\n",
                    s.miss_log_overwritten,
                    kind.name(),
                    crate::ipc::STATS_MISSES
                ));
            }
            for m in s.misses() {
                out.push_str(&super::json::miss_report(&m, self.run_start_ns).line(kind.name()));
            }
        }
        out
    }

    /// Accuracy, chain, control and observation-books lines.
    fn summary_lines(&self) -> String {
        let mut out = String::new();
        let a = &self.accuracy;
        let f = |v: Option<f64>| v.map(|x| format!("{x:.3}")).unwrap_or("-".into());
        out.push_str(&format!(
            "\naccuracy: rmse_position {} (raw measurement {}), rmse_state {}, {} beliefs scored\n",
            f(a.rmse_position),
            f(a.rmse_position_raw),
            f(a.rmse_state),
            a.beliefs
        ));
        let health = self.filter_health();
        if let Some(c) = health.ess_collapses {
            out.push_str(&format!(
                "filter: {c} of {} updates collapsed (kept less than the collapse fraction of their effective support, or every weight vanished)\n",
                health.updates
            ));
        }
        if let Some(c) = self
            .stats(StageKind::Filter)
            .filter(|c| c.chain_versions > 0)
        {
            out.push_str(&format!(
                "chain: {} versions installed ({} published), {} states, δ {:.2e} s, swap p50 {:.1} µs p99 {:.1} µs, mass lost in a remap ≤ {:.2e}\n",
                c.chain_versions,
                self.stats(StageKind::Refine).map(|r| r.chain_versions).unwrap_or(0),
                c.chain_states,
                c.chain_delta_s,
                us(c.chain_swap_p50_ns),
                us(c.chain_swap_p99_ns),
                c.chain_mass_lost_max
            ));
            out.push_str(&format!(
                "chain fallback: {} beliefs in {} stale episodes (degenerate {}, age {}, evidence {}), {} re-initialised from it; oldest version at a step {:.0} ms; its step p50 {:.1} µs p99 {:.1} µs\n",
                c.chain_fallback_steps,
                c.chain_fallback_episodes.iter().sum::<u64>(),
                c.chain_fallback_episodes[0],
                c.chain_fallback_episodes[1],
                c.chain_fallback_episodes[2],
                c.chain_fallback_reinits,
                c.chain_stale_max_ns as f64 * 1e-6,
                us(c.chain_fallback_p50_ns),
                us(c.chain_fallback_p99_ns)
            ));
            if let Some(r) = self.stats(StageKind::Refine) {
                out.push_str(&format!(
                    "chain rows: {} versions built, {} rows, {} exact, {} least-squares; {} versions re-published as new lineages\n",
                    r.chain_built, r.chain_rows, r.chain_rows_exact, r.chain_rows_least_squares, r.chain_recentred
                ));
            }
        }
        if let Some(p) = self.stats(StageKind::Plant) {
            if p.controls_received > 0 {
                out.push_str(&format!(
                    "control: {} controls applied, {} waypoints reached, mean distance to waypoint {:.2}\n",
                    p.controls_received, p.waypoints_reached, p.mean_goal_distance
                ));
                if let Some(c) = self.stats(StageKind::Control) {
                    out.push_str(&format!(
                        "controller {}: closed-loop cost {}/s, compute p50 {:.1} µs, p99 {:.1} µs\n",
                        self.controller,
                        if c.control_cost_time_s > 0.0 {
                            format!("{:.3}", c.control_cost)
                        } else {
                            "-".into()
                        },
                        us(c.compute.p50_ns),
                        us(c.compute.p99_ns)
                    ));
                }
            }
        }
        if let Some(v) = self.accuracy.scenario.as_ref().and_then(|v| v.as_object()) {
            out.push_str(&scenario_line(&self.scenario, v));
        }
        if let Some((published, counted, unaccounted)) = self.observation_books() {
            out.push_str(&format!(
                "observations: {published} published, {counted} counted by the filter, {unaccounted} unaccounted (in flight at the stop, or lost with a dead filter)\n"
            ));
        }
        out
    }
}

/// The scenario's own figures on one line: numbers as they are, lists by
/// their length (the JSON report has the entries).
fn scenario_line(name: &str, v: &serde_json::Map<String, serde_json::Value>) -> String {
    let parts: Vec<String> = v
        .iter()
        .map(|(k, x)| match x {
            serde_json::Value::Number(n) => match n.as_f64() {
                Some(f) if n.is_f64() => format!("{k} {f:.4}"),
                _ => format!("{k} {n}"),
            },
            serde_json::Value::Array(a) => format!("{k} [{} entries]", a.len()),
            other => format!("{k} {other}"),
        })
        .collect();
    format!("{name}: {}\n", parts.join(", "))
}
