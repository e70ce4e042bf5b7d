//! `scenario_metrics.light-dark`: per episode (from the truth's reward and
//! event components, [`super::encoding`]) the reward — the undiscounted sum
//! of −u²h per move and ±R for the declaration — and whether the goal was
//! reached; and from the published controls the policy lookup time and
//! the policy swaps.
//!
//! Only episodes that start after the warm-up are counted (the first
//! counted sample's episode is partial). The goal fraction comes with its
//! 95 % Wilson interval; the reward per episode with its standard error.

use super::encoding::{
    EVENT_GOAL, EVENT_MISS, EVENT_NONE, EVENT_TIMEOUT, U_DECLARE, U_LOOKUP_NS, U_VERSION,
};
use crate::metrics::{BeliefView, ControlView, RunMetrics, TruthView};
use serde_json::json;

/// The accumulator.
#[derive(Debug, Default)]
pub struct LightDarkMetrics {
    next_seq: Option<u64>,
    truth_gaps: u64,
    /// Inside an episode that started after the warm-up.
    counting: bool,
    reward: f64,
    moves: u64,
    episodes: Vec<(f64, u64, f64)>,
    lookup_ns: Vec<f64>,
    last_version: Option<f64>,
    swaps: u64,
    fallbacks: u64,
    declarations: u64,
    belief_err: Vec<f64>,
}

impl LightDarkMetrics {
    pub fn new() -> Self {
        Self::default()
    }
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    sorted[i]
}

/// The 95 % Wilson score interval of k successes in n.
pub fn wilson(k: u64, n: u64) -> (f64, f64) {
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    let (k, n, z) = (k as f64, n as f64, 1.959_963_985);
    let p = k / n;
    let c = (p + z * z / (2.0 * n)) / (1.0 + z * z / n);
    let h = z / (1.0 + z * z / n) * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt();
    (c - h, c + h)
}

impl RunMetrics for LightDarkMetrics {
    fn truth(&mut self, t: &TruthView) {
        if let Some(n) = self.next_seq {
            if t.seq != n {
                self.truth_gaps += 1;
            }
        }
        self.next_seq = Some(t.seq + 1);
        let (r, e) = (t.x[1], t.x[2]);
        if e == EVENT_NONE {
            // A move (of any velocity, zero included).
            if self.counting {
                self.reward += r;
                self.moves += 1;
            }
            return;
        }
        if self.counting {
            self.episodes.push((self.reward + r, self.moves, e));
        }
        // A new episode starts at this sample.
        self.counting = t.counted;
        self.reward = 0.0;
        self.moves = 0;
    }
    fn belief(&mut self, b: &BeliefView, t: &TruthView) {
        self.belief_err.push((b.mean[0] - t.x[0]).abs());
    }
    fn control(&mut self, c: &ControlView) {
        if !c.ok {
            self.fallbacks += 1;
            return;
        }
        if c.u.len() <= U_LOOKUP_NS {
            return;
        }
        self.lookup_ns.push(c.u[U_LOOKUP_NS]);
        if c.u[U_DECLARE] > 0.5 {
            self.declarations += 1;
        }
        let v = c.u[U_VERSION];
        if let Some(last) = self.last_version {
            if v > last {
                self.swaps += (v - last) as u64;
            }
        }
        self.last_version = Some(self.last_version.map_or(v, |l| l.max(v)));
    }
    fn report(&self) -> serde_json::Value {
        let n = self.episodes.len() as u64;
        let goal = self.episodes.iter().filter(|e| e.2 == EVENT_GOAL).count() as u64;
        let miss = self.episodes.iter().filter(|e| e.2 == EVENT_MISS).count() as u64;
        let timeout = self
            .episodes
            .iter()
            .filter(|e| e.2 == EVENT_TIMEOUT)
            .count() as u64;
        let rewards: Vec<f64> = self.episodes.iter().map(|e| e.0).collect();
        let mean = rewards.iter().sum::<f64>() / n.max(1) as f64;
        let var = rewards.iter().map(|r| (r - mean).powi(2)).sum::<f64>()
            / (n.saturating_sub(1)).max(1) as f64;
        let moves = self.episodes.iter().map(|e| e.1 as f64).sum::<f64>() / n.max(1) as f64;
        let (lo, hi) = wilson(goal, n);
        let mut ns = self.lookup_ns.clone();
        ns.sort_by(f64::total_cmp);
        let mut err = self.belief_err.clone();
        err.sort_by(f64::total_cmp);
        json!({
            "episodes": n,
            "goal_reached": goal,
            "declared_outside": miss,
            "timeouts": timeout,
            "goal_fraction": if n > 0 { goal as f64 / n as f64 } else { f64::NAN },
            "goal_fraction_ci95": [lo, hi],
            "reward_per_episode": mean,
            "reward_per_episode_se": (var / n.max(1) as f64).sqrt(),
            "moves_per_episode": moves,
            "decisions": self.lookup_ns.len(),
            "declarations": self.declarations,
            "lookup_us_p50": quantile(&ns, 0.5) * 1e-3,
            "lookup_us_p99": quantile(&ns, 0.99) * 1e-3,
            "lookup_us_max": ns.last().map_or(f64::NAN, |v| v * 1e-3),
            "policy_swaps": self.swaps,
            "policy_version": self.last_version.unwrap_or(0.0),
            "fallbacks": self.fallbacks,
            "position_error_median": quantile(&err, 0.5),
            "truth_gaps": self.truth_gaps,
        })
    }
}
