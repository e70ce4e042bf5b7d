//! The run report: JSON written by `beliefbus run --report`
//! and the tables printed at the end of a run.
//!
//! ```text
//! { scenario, duration_s, sensor_rate_hz, filter_backend, controller,
//!   sensor_source, prefix, sensor_samples, sensor_samples_after_warmup,
//!   hops:   { "sensor->ingest" | "ingest->filter" | "filter->control" |
//!             "sensor->belief" | "sensor->control":
//!             {count, p50_us, p90_us, p99_us, p999_us, max_us} },
//!   stages: { ingest | filter | control | refine | plant:
//!             {pid, core, processed, dropped, rejected, rejected_by_reason,
//!              deadline_misses, compute_p50_us, compute_p99_us, budget_us,
//!              fifo, mlocked, exit_status} },
//!   accuracy: {rmse_position, rmse_state, rmse_position_raw, beliefs, samples},
//!   control:  {waypoints_reached, mean_distance_to_waypoint, controls_received,
//!              controller, cost, compute_p50_us, compute_p99_us},
//!   chain:    {versions, states, delta_s, swap_p50_us, swap_p99_us, mass_lost_max,
//!              published, refine_states, fallback_steps, fallback_episodes,
//!              fallback_by_cause: {degenerate, age, evidence}, fallback_reinits,
//!              fallback_untethered,
//!              fallback_cost_p50_us, fallback_cost_p99_us, stale_max_ms}   (filter backend `chain`)
//!   shared_memory: {files_removed, files_left} }
//! ```
//! Hops count only samples measured after `run.warmup_s`; a figure with no
//! data is `null` (e.g. control hops of an estimation-only run).
//! `sensor_samples_after_warmup` and the `control` counters come from the
//! plant (built-in, or `beliefbus plant`): `null` with other external
//! publishers, whose controls the pipeline cannot see applied
//! (`stages.control.processed` counts the controls published).
//!
//! `control.cost` is the closed-loop running cost per second after the
//! warm-up, (1/T)∫[q(x̂) + w‖u‖²]dt with the tracking cost q of
//! `[control.cost]` at the belief mean x̂ and the active waypoint, each
//! control held until the next belief, w the backend's control weight;
//! `control.compute_p50_us`/`p99_us` are the control stage's compute time
//! per control (belief taken → control published).

use super::monitor::Accuracy;
use crate::ipc::{stats_flags, Hop, Percentiles, StageKind, StageStats};
use crate::stage::{control, filter, ingest};
use serde::Serialize;
use serde_json::{json, Map, Value};

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
}

fn reasons(kind: StageKind, r: &[u64]) -> Value {
    let names: Vec<&str> = match kind {
        StageKind::Ingest => ingest::Reason::ALL.iter().map(|r| r.name()).collect(),
        StageKind::Filter => filter::Reason::ALL.iter().map(|r| r.name()).collect(),
        StageKind::Control => control::Reason::ALL.iter().map(|r| r.name()).collect(),
        StageKind::Plant => crate::stage::plant::Reason::ALL
            .iter()
            .map(|r| r.name())
            .collect(),
        _ => Vec::new(),
    };
    let mut m = Map::new();
    for (i, n) in names.iter().enumerate() {
        m.insert(n.to_string(), json!(r[i]));
    }
    Value::Object(m)
}

fn opt(v: Option<f64>) -> Value {
    v.filter(|x| x.is_finite())
        .map(Value::from)
        .unwrap_or(Value::Null)
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

    /// The report JSON.
    pub fn to_json(&self) -> Value {
        let mut hops = Map::new();
        for h in Hop::ALL {
            // An empty histogram (e.g. the control hops of an estimation-only
            // run) is reported as count 0 with null percentiles, not zeros.
            let v = self
                .hop(h)
                .filter(|r| r.count > 0)
                .map(|r| serde_json::to_value(r).unwrap_or(Value::Null))
                .unwrap_or_else(|| {
                    json!({"count": 0, "p50_us": null, "p90_us": null, "p99_us": null,
                           "p999_us": null, "max_us": null})
                });
            hops.insert(h.key().to_string(), v);
        }
        let mut stages = Map::new();
        for (kind, end) in &self.stages {
            let s = end.stats.unwrap_or_default();
            let has = end.stats.is_some();
            let c = &s.compute;
            // Lateness = response − budget (negative: early); null without data.
            let lateness = |r: u64| {
                if s.response_max_ns > 0 {
                    json!((r as f64 - s.budget_ns as f64) / 1e3)
                } else {
                    Value::Null
                }
            };
            stages.insert(
                kind.name().to_string(),
                json!({
                    "pid": end.pid,
                    "core": if s.core >= 0 { json!(s.core) } else { Value::Null },
                    "processed": s.processed,
                    "dropped": s.dropped,
                    "dropped_by_reason": crate::stage::DropReason::ALL
                        .iter()
                        .map(|r| (r.name().to_string(), json!(s.dropped_by_reason[*r as usize])))
                        .collect::<Map<String, Value>>(),
                    "rejected": s.rejected,
                    "rejected_by_reason": reasons(*kind, &s.rejected_by_reason),
                    "deadline_misses": s.deadline_misses,
                    "compute_p50_us": if c.count > 0 { json!(us(c.p50_ns)) } else { Value::Null },
                    "compute_p99_us": if c.count > 0 { json!(us(c.p99_ns)) } else { Value::Null },
                    "budget_us": us(s.budget_ns),
                    "late": s.late,
                    "lateness_p50_us": lateness(s.response_p50_ns),
                    "lateness_p99_us": lateness(s.response_p99_ns),
                    "lateness_max_us": lateness(s.response_max_ns),
                    "fifo": has && s.flags & stats_flags::FIFO != 0,
                    "mlocked": has && s.flags & stats_flags::MLOCKED != 0,
                    "final_report": has && s.flags & stats_flags::FINAL != 0,
                    "exit_status": end.exit,
                }),
            );
        }
        let plant = self.stats(StageKind::Plant);
        let ctl = self.stats(StageKind::Control);
        let a = &self.accuracy;
        json!({
            "scenario": self.scenario,
            "duration_s": self.duration_s,
            "sensor_rate_hz": self.sensor_rate_hz,
            "filter_backend": self.filter_backend,
            "controller": self.controller,
            "sensor_source": self.sensor_source,
            "prefix": self.prefix,
            // External sensors without a plant: what reached ingest.
            "sensor_samples": plant.map(|p| p.processed).or(self
                .stats(StageKind::Ingest)
                .map(|i| i.processed + i.rejected + i.dropped))
                .unwrap_or(0),
            "sensor_samples_after_warmup": plant.map(|p| p.processed_after_warmup),
            "hops": hops,
            "stages": stages,
            "accuracy": {
                "rmse_position": opt(a.rmse_position),
                "rmse_state": opt(a.rmse_state),
                "rmse_position_raw": opt(a.rmse_position_raw),
                "beliefs": a.beliefs,
                "samples": a.samples,
            },
            "control": {
                "waypoints_reached": plant.map(|p| p.waypoints_reached),
                "mean_distance_to_waypoint":
                    opt(plant.filter(|p| p.controls_received > 0).map(|p| p.mean_goal_distance)),
                "controls_received": plant.map(|p| p.controls_received),
                "controller": self.controller,
                "cost": opt(ctl.filter(|c| c.control_cost_time_s > 0.0).map(|c| c.control_cost)),
                "compute_p50_us":
                    opt(ctl.filter(|c| c.compute.count > 0).map(|c| us(c.compute.p50_ns))),
                "compute_p99_us":
                    opt(ctl.filter(|c| c.compute.count > 0).map(|c| us(c.compute.p99_ns))),
            },
            "chain": self.chain_json(),
            "streams": self.streams_json(),
            "shared_memory": {
                "files_removed": self.files_removed,
                "files_left": self.files_left,
            },
        })
    }

    /// The `chain` section: what the filter installed (versions, size and δ
    /// of the active chain, swap durations, largest mass lost in a remap),
    /// what refine published, and the stale-chain fallback
    /// (`stage::chain_guard`): beliefs published from the fallback
    /// (`fallback_steps`), stale episodes (`fallback_episodes`, by the
    /// cause that opened them), chain beliefs re-initialised from the
    /// fallback when a version ended an episode (`fallback_reinits`),
    /// installs that left the fallback apart from a doubtful chain
    /// (`fallback_untethered`), the
    /// fallback's predict + update time per observation — its extra cost —
    /// (`fallback_cost_p50_us`/`p99_us`), and the oldest installed version
    /// at a filter step (`stale_max_ms`; null before any install).
    fn chain_json(&self) -> Value {
        let f = self.stats(StageKind::Filter);
        let r = self.stats(StageKind::Refine);
        let swaps = f.map(|s| s.chain_versions).unwrap_or(0);
        let us_or_null = |v: Option<u64>| {
            v.filter(|_| swaps > 0)
                .map(|ns| json!(us(ns)))
                .unwrap_or(Value::Null)
        };
        json!({
            "versions": swaps,
            "states": f.map(|s| s.chain_states).unwrap_or(0),
            "delta_s": opt(f.filter(|_| swaps > 0).map(|s| s.chain_delta_s)),
            "swap_p50_us": us_or_null(f.map(|s| s.chain_swap_p50_ns)),
            "swap_p99_us": us_or_null(f.map(|s| s.chain_swap_p99_ns)),
            "mass_lost_max": opt(f.filter(|_| swaps > 0).map(|s| s.chain_mass_lost_max)),
            "published": r.map(|s| s.chain_versions).unwrap_or(0),
            "refine_states": r.map(|s| s.chain_states).unwrap_or(0),
            "fallback_steps": f.map(|s| s.chain_fallback_steps).unwrap_or(0),
            "fallback_episodes": f.map(|s| s.chain_fallback_episodes.iter().sum::<u64>()).unwrap_or(0),
            "fallback_by_cause": Value::Object(
                crate::stage::chain_guard::Cause::ALL
                    .iter()
                    .map(|c| {
                        let n = f.map(|s| s.chain_fallback_episodes[*c as usize]).unwrap_or(0);
                        (c.name().to_string(), json!(n))
                    })
                    .collect::<Map<String, Value>>(),
            ),
            "fallback_reinits": f.map(|s| s.chain_fallback_reinits).unwrap_or(0),
            "fallback_untethered": f.map(|s| s.chain_fallback_untethered).unwrap_or(0),
            "fallback_cost_p50_us": opt(f.filter(|s| s.chain_fallback_p50_ns > 0).map(|s| us(s.chain_fallback_p50_ns))),
            "fallback_cost_p99_us": opt(f.filter(|s| s.chain_fallback_p99_ns > 0).map(|s| us(s.chain_fallback_p99_ns))),
            "stale_max_ms": opt(f.filter(|_| swaps > 0).map(|s| s.chain_stale_max_ns as f64 * 1e-6)),
        })
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

    fn streams_json(&self) -> Value {
        match self.observation_books() {
            Some((published, counted, unaccounted)) => json!({
                "observations": {
                    "published": published,
                    "counted": counted,
                    "unaccounted": unaccounted,
                }
            }),
            None => json!({ "observations": Value::Null }),
        }
    }

    /// The latency and stage tables printed at the end of a run.
    pub fn render(&self) -> String {
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
        out.push('\n');
        out.push_str(&format!(
            "{:<8} {:>7} {:>4} {:>9} {:>7} {:>8} {:>6} {:>10} {:>10} {:>9} {:>6} {:>11}\n",
            "stage",
            "pid",
            "core",
            "processed",
            "dropped",
            "rejected",
            "misses",
            "cpu p50µs",
            "cpu p99µs",
            "budgetµs",
            "late",
            "late p99µs"
        ));
        for (kind, end) in &self.stages {
            let s = end.stats.unwrap_or_default();
            out.push_str(&format!(
                "{:<8} {:>7} {:>4} {:>9} {:>7} {:>8} {:>6} {:>10.1} {:>10.1} {:>9.0} {:>6} {:>11}\n",
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
        let a = &self.accuracy;
        let f = |v: Option<f64>| v.map(|x| format!("{x:.3}")).unwrap_or("-".into());
        out.push_str(&format!(
            "\naccuracy: rmse_position {} (raw measurement {}), rmse_state {}, {} beliefs scored\n",
            f(a.rmse_position),
            f(a.rmse_position_raw),
            f(a.rmse_state),
            a.beliefs
        ));
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
        if let Some((published, counted, unaccounted)) = self.observation_books() {
            out.push_str(&format!(
                "observations: {published} published, {counted} counted by the filter, {unaccounted} unaccounted (in flight at the stop, or lost with a dead filter)\n"
            ));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ipc::HopStats;

    fn input() -> ReportInput {
        let mut ctl = StageStats {
            stage: StageKind::Control as u32,
            processed: 10,
            budget_ns: 700_000,
            late: 2,
            response_p50_ns: 400_000,
            response_p99_ns: 750_000,
            response_max_ns: 900_000,
            ..StageStats::default()
        };
        ctl.hops[0] = HopStats {
            hop: Hop::SensorToControl as u32,
            reserved: 0,
            pct: Percentiles {
                count: 9,
                p50_ns: 1_500,
                p90_ns: 2_000,
                p99_ns: 3_000,
                p999_ns: 4_000,
                max_ns: 5_000,
            },
        };
        ReportInput {
            scenario: "ship".into(),
            duration_s: 1.0,
            sensor_rate_hz: 100.0,
            filter_backend: "pf".into(),
            controller: "mppi".into(),
            sensor_source: "plant".into(),
            prefix: "p".into(),
            stages: StageKind::ALL
                .iter()
                .map(|&k| {
                    (
                        k,
                        StageEnd {
                            pid: Some(k as u32),
                            stats: (k == StageKind::Control).then_some(ctl),
                            exit: Some("exit 0".into()),
                        },
                    )
                })
                .collect(),
            accuracy: Accuracy::default(),
            files_removed: 3,
            files_left: 0,
        }
    }

    #[test]
    fn json_has_every_key_of_issue_2() {
        let v = input().to_json();
        for k in [
            "scenario",
            "duration_s",
            "sensor_rate_hz",
            "filter_backend",
            "controller",
            "hops",
            "stages",
            "accuracy",
            "control",
        ] {
            assert!(v.get(k).is_some(), "missing {k}");
        }
        for h in Hop::ALL {
            let hop = &v["hops"][h.key()];
            for k in ["count", "p50_us", "p90_us", "p99_us", "p999_us", "max_us"] {
                assert!(hop.get(k).is_some(), "hops.{}.{k}", h.key());
            }
        }
        assert_eq!(v["hops"]["sensor->control"]["p50_us"], json!(1.5));
        assert_eq!(v["hops"]["sensor->control"]["count"], json!(9));
        // Lateness = response − budget, negative when early; null without data.
        let c = &v["stages"]["control"];
        assert_eq!(c["late"], json!(2));
        assert_eq!(c["lateness_p50_us"], json!(-300.0));
        assert_eq!(c["lateness_p99_us"], json!(50.0));
        assert_eq!(c["lateness_max_us"], json!(200.0));
        assert!(v["stages"]["filter"]["lateness_p99_us"].is_null());
        for s in StageKind::ALL {
            let st = &v["stages"][s.name()];
            for k in [
                "pid",
                "core",
                "processed",
                "dropped",
                "rejected",
                "deadline_misses",
                "compute_p50_us",
                "compute_p99_us",
                "budget_us",
                "late",
                "lateness_p50_us",
                "lateness_p99_us",
                "lateness_max_us",
            ] {
                assert!(st.get(k).is_some(), "stages.{}.{k}", s.name());
            }
        }
        for k in ["rmse_position", "rmse_state", "rmse_position_raw"] {
            assert!(v["accuracy"].get(k).is_some());
        }
        for k in ["waypoints_reached", "mean_distance_to_waypoint"] {
            assert!(v["control"].get(k).is_some());
        }
        for k in [
            "versions",
            "states",
            "delta_s",
            "swap_p50_us",
            "swap_p99_us",
            "mass_lost_max",
            "fallback_steps",
            "fallback_episodes",
            "fallback_reinits",
            "stale_max_ms",
        ] {
            assert!(v["chain"].get(k).is_some(), "chain.{k}");
        }
        assert!(v["stages"]["ingest"]["rejected_by_reason"]
            .get("non_finite")
            .is_some());
    }

    #[test]
    fn control_section_has_controller_cost_and_compute_percentiles() {
        let mut inp = input();
        let v = inp.to_json();
        assert_eq!(v["control"]["controller"], json!("mppi"));
        // No control data yet: null, not zero.
        for k in ["cost", "compute_p50_us", "compute_p99_us"] {
            assert!(v["control"][k].is_null(), "{k}");
        }
        let (_, end) = inp
            .stages
            .iter_mut()
            .find(|(k, _)| *k == StageKind::Control)
            .unwrap();
        let s = end.stats.as_mut().unwrap();
        s.control_cost = 12.5;
        s.control_cost_time_s = 3.0;
        s.compute = Percentiles {
            count: 10,
            p50_ns: 250_000,
            p90_ns: 300_000,
            p99_ns: 420_000,
            p999_ns: 500_000,
            max_ns: 600_000,
        };
        let v = inp.to_json();
        assert_eq!(v["control"]["cost"], json!(12.5));
        assert_eq!(v["control"]["compute_p50_us"], json!(250.0));
        assert_eq!(v["control"]["compute_p99_us"], json!(420.0));
    }

    #[test]
    fn render_lists_every_hop_and_stage() {
        let t = input().render();
        for h in Hop::ALL {
            assert!(t.contains(h.key()));
        }
        for s in StageKind::ALL {
            assert!(t.contains(s.name()));
        }
    }
}
