//! The host stall probe's part of the jitter report
//! ([`crate::rt::stall`]): per core, how many stalls of each kind longer
//! than each threshold a spinning thread met, per minute of spinning, and
//! beside each stage's misses the rate of host stalls longer than that
//! stage's budget on its core.

use crate::latency::pipeline::StageFigures;
use crate::rt::grid::{alignment, Alignment};
use crate::rt::stall::{CoreStalls, StallKind};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Thresholds every report has (µs); the pipeline's stage budgets are
/// added to them.
pub const THRESHOLDS_US: [f64; 6] = [50.0, 100.0, 200.0, 500.0, 1000.0, 5000.0];

/// One core's probe figures.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StallRow {
    pub core: usize,
    pub fifo: bool,
    /// Seconds spent spinning.
    pub spun_s: f64,
    /// Ascending thresholds the counts are for, µs.
    pub thresholds_us: Vec<f64>,
    /// Stalls longer than each threshold per minute of spinning, by kind.
    pub switched_per_min: Vec<f64>,
    pub charged_per_min: Vec<f64>,
    pub steal_per_min: Vec<f64>,
    /// Total stalled time per minute of spinning (ms) and the longest
    /// stall (µs), by kind: switched, charged, steal.
    pub total_ms_per_min: [f64; 3],
    pub max_us: [f64; 3],
}

/// The probe's length: `probe` (`--probe`), else `duration` capped at
/// 10 s.
pub fn seconds(probe: Option<f64>, duration: f64) -> Result<f64, crate::latency::LatencyError> {
    let s = probe.unwrap_or(duration.min(10.0));
    if !(s.is_finite() && (0.0..=3600.0).contains(&s)) {
        return Err(crate::latency::LatencyError::BadArg(format!(
            "--probe must be 0..=3600 seconds, got {s}"
        )));
    }
    Ok(s)
}

/// The thresholds: the fixed ones and the stages' budgets, ascending.
pub fn thresholds(stages: Option<&BTreeMap<String, StageFigures>>) -> Vec<f64> {
    let mut t: Vec<f64> = THRESHOLDS_US.to_vec();
    if let Some(st) = stages {
        t.extend(st.values().filter_map(|f| f.budget_us));
    }
    t.retain(|x| x.is_finite() && *x > 0.0);
    t.sort_by(f64::total_cmp);
    t.dedup();
    t
}

/// The rows of a probe run.
pub fn rows(stalls: &[CoreStalls], thresholds_us: &[f64]) -> Vec<StallRow> {
    stalls
        .iter()
        .map(|c| {
            let rate = |k: StallKind| -> Vec<f64> {
                thresholds_us
                    .iter()
                    .map(|t| c.per_minute(k, (t * 1e3) as u64))
                    .collect()
            };
            let minutes = c.spun_ns as f64 / 60e9;
            let per_min = |k: StallKind| match minutes > 0.0 {
                true => c.total_ns(k) as f64 / 1e6 / minutes,
                false => 0.0,
            };
            StallRow {
                core: c.core,
                fifo: c.fifo,
                spun_s: c.spun_ns as f64 / 1e9,
                thresholds_us: thresholds_us.to_vec(),
                switched_per_min: rate(StallKind::Switched),
                charged_per_min: rate(StallKind::Charged),
                steal_per_min: rate(StallKind::Steal),
                total_ms_per_min: StallKind::ALL.map(per_min),
                max_us: StallKind::ALL.map(|k| c.gaps[k as usize].max() as f64 / 1e3),
            }
        })
        .collect()
}

/// Periods the probe's host stalls are tested against (ms): the host's
/// scheduler tick and CPU-bandwidth period as seen on this VM, and 97 ms,
/// which means nothing, as the control.
pub const GRID_PERIODS_MS: [u64; 3] = [10, 100, 97];
/// Tolerance of the grid test.
pub const GRID_TOLERANCE_NS: u64 = 50_000;
/// Pairs of stalls closer than this are left out (a pause of the whole VM
/// shows on every core at once).
pub const GRID_MIN_SEPARATION_NS: u64 = 5_000_000;

/// Whether the probe's host stalls (charged or steal, ≥ 200 µs, every core
/// pooled) sit on a periodic grid ([`crate::rt::grid`]).
pub fn grid(stalls: &[CoreStalls]) -> Vec<Alignment> {
    let starts: Vec<u64> = stalls
        .iter()
        .flat_map(|c| c.starts.iter().copied())
        .collect();
    if starts.len() < 2 {
        return Vec::new();
    }
    GRID_PERIODS_MS
        .iter()
        .map(|&p| {
            alignment(
                &starts,
                p * 1_000_000,
                GRID_TOLERANCE_NS,
                GRID_MIN_SEPARATION_NS,
            )
        })
        .collect()
}

/// The grid test's console line (empty without one).
pub fn render_grid(grid: &[Alignment]) -> String {
    let Some(first) = grid.first() else {
        return String::new();
    };
    let mut s = format!(
        "  host stalls ≥ 200 µs, all cores: of {} pairs, a whole number of P apart (± {:.0} µs):",
        first.pairs, first.tolerance_us
    );
    for a in grid {
        s += &format!(
            " P = {:.0} ms {} (chance {:.2}, ×{:.1});",
            a.period_us / 1e3,
            a.aligned,
            a.chance,
            a.ratio()
        );
    }
    s.pop();
    s += "\n  (far above ×1 at a period: something outside the guest stops it on that grid; 97 ms is the control)\n";
    s
}

/// The console lines.
pub fn render(rows: &[StallRow], stages: Option<&BTreeMap<String, StageFigures>>) -> String {
    let Some(first) = rows.first() else {
        return String::new();
    };
    let mut s = String::from(
        "host stall probe: a thread spinning on each core, stalls per minute of spinning longer than (µs):\n",
    );
    s += &format!("  {:<26}", "");
    for t in &first.thresholds_us {
        s += &format!(" {t:>7.0}");
    }
    s += " | stalled ms/min  longest µs\n";
    for r in rows {
        let fifo = if r.fifo { ", FIFO" } else { "" };
        for (k, rates) in [
            (StallKind::Charged, &r.charged_per_min),
            (StallKind::Steal, &r.steal_per_min),
            (StallKind::Switched, &r.switched_per_min),
        ] {
            let label = format!("core {} {} ({:.0} s{fifo})", r.core, k.name(), r.spun_s);
            s += &format!("  {label:<26}");
            for x in rates.iter() {
                s += &format!(" {x:>7.1}");
            }
            s += &format!(
                " | {:>14.1} {:>11.0}\n",
                r.total_ms_per_min[k as usize], r.max_us[k as usize]
            );
        }
    }
    s += "  (charged: the guest counted the time as the thread's own CPU — host exits not reported as steal, or this machine's interrupt handlers — so a stage's budget split calls such a miss an overrun; steal: reported by the hypervisor; switched: another task of this machine ran)\n";
    let Some(stages) = stages else {
        return s;
    };
    for (name, f) in stages {
        let (Some(core), Some(b)) = (f.core, f.budget_us) else {
            continue;
        };
        let Some(r) = rows.iter().find(|r| r.core == core) else {
            continue;
        };
        let Some(i) = r.thresholds_us.iter().position(|t| *t == b) else {
            continue;
        };
        s += &format!(
            "  {name} (core {core}, budget {b:.0} µs): host stalls longer than its budget {:.1} charged + {:.1} steal per minute; its misses: {} over budget in CPU time, {} preempted ({} the host's)\n",
            r.charged_per_min[i],
            r.steal_per_min[i],
            f.deadline_misses - f.deadline_misses_preempted,
            f.deadline_misses_preempted,
            f.deadline_misses_host,
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_count_stalls_above_each_threshold_per_minute() {
        let mut c = CoreStalls::new(1);
        c.spun_ns = 30_000_000_000; // half a minute
        for us in [60, 120, 700, 2_000] {
            c.gaps[StallKind::Charged as usize].record(us * 1_000);
        }
        c.gaps[StallKind::Steal as usize].record(6_000_000);
        let r = &rows(&[c], &[50.0, 100.0, 700.0, 1000.0])[0];
        assert_eq!(r.core, 1);
        assert_eq!(r.spun_s, 30.0);
        // Above 50: 4; above 100: 3; above 700 (700 itself not above): 1;
        // above 1000: 1. Per minute: twice that.
        assert_eq!(r.charged_per_min, vec![8.0, 6.0, 2.0, 2.0]);
        assert_eq!(r.steal_per_min, vec![2.0; 4]);
        assert_eq!(r.switched_per_min, vec![0.0; 4]);
        let charged_ms = (60 + 120 + 700 + 2_000) as f64 / 1e3 * 2.0;
        assert!((r.total_ms_per_min[1] - charged_ms).abs() < 0.01);
        assert!((r.max_us[2] - 6_000.0).abs() < 10.0);
    }

    #[test]
    fn the_grid_test_pools_the_cores_and_finds_a_100_ms_grid() {
        // Stalls on both cores at whole multiples of 100 ms (+ up to 30 µs),
        // the same instants on both (a pause of the whole VM): the pairs
        // closer than 5 ms (the two cores' copies) are left out.
        let mut cores = [CoreStalls::new(0), CoreStalls::new(1)];
        for k in [3u64, 7, 12, 40, 41, 90, 133, 250] {
            for (i, c) in cores.iter_mut().enumerate() {
                c.starts.push(k * 100_000_000 + 10_000 * i as u64);
            }
        }
        let g = grid(&cores);
        assert_eq!(g.len(), 3);
        let at = |ms: u64| g.iter().find(|a| a.period_us == ms as f64 * 1e3).unwrap();
        // 16 stalls: 120 pairs, less the 8 pairs of copies.
        assert_eq!(at(100).pairs, 112);
        assert_eq!(at(100).aligned, 112);
        assert_eq!(at(10).aligned, 112);
        assert!(at(97).aligned < 20, "{:?}", at(97));
        let line = render_grid(&g);
        assert!(
            line.contains("P = 100 ms 112 (chance 0.11, ×1000.0)"),
            "{line}"
        );
        assert!(grid(&cores[..0]).is_empty() && render_grid(&[]).is_empty());
    }

    #[test]
    fn the_probe_lasts_as_asked_else_the_duration_up_to_10_s() {
        assert_eq!(seconds(None, 3.0).unwrap(), 3.0);
        assert_eq!(seconds(None, 60.0).unwrap(), 10.0);
        assert_eq!(seconds(Some(0.0), 60.0).unwrap(), 0.0);
        assert_eq!(seconds(Some(20.0), 1.0).unwrap(), 20.0);
        for bad in [-1.0, f64::NAN, 4000.0] {
            assert!(seconds(Some(bad), 1.0).is_err(), "{bad}");
        }
    }

    #[test]
    fn thresholds_add_the_stage_budgets_once_and_sort() {
        assert_eq!(thresholds(None), THRESHOLDS_US.to_vec());
        let mut stages = BTreeMap::new();
        for (name, b) in [("control", 700.0), ("filter", 300.0), ("ingest", 50.0)] {
            let f = serde_json::json!({
                "processed": 1, "deadline_misses": 0, "budget_us": b,
                "compute_p50_us": null, "compute_p99_us": null, "late": 0,
                "lateness_p99_us": null, "core": 1
            });
            stages.insert(name.to_string(), serde_json::from_value(f).unwrap());
        }
        let t = thresholds(Some(&stages));
        assert_eq!(
            t,
            vec![50.0, 100.0, 200.0, 300.0, 500.0, 700.0, 1000.0, 5000.0]
        );
    }
}
