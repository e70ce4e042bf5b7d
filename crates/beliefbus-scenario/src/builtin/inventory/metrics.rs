//! `scenario_metrics.inventory`: the live run's figures.
//!
//! - `average_cost`: (1/K) Σ g_k over the counted periods (the plant
//!   records each period's cost in the state), with a batch-means standard
//!   error (20 batches);
//! - `full_obs_cost`: the same for the full-observation threshold policy
//!   (order iff x < L*, the `threshold` parameter) run as a shadow store on
//!   the same demands — d_k is in the plant's state — from the same x_0; a
//!   lost truth re-synchronises the shadow to the plant (`truth_gaps`);
//! - `deviation`, `deviation_pct`: ours − full observation (paired, same
//!   demands, batch-means s.e.) and 100·(ours / full − 1), the paper's
//!   parenthesised figure;
//! - `controlled_fraction`: counted periods whose order was computed from
//!   the belief of the sample before (matched by sequence number and
//!   value), i.e. the control arrived before the next period began.
//!
//! The per-step control compute is the control stage's (`stages.control`
//! in the report); `beliefbus solve inventory` prints the table lookup's
//! time alone.

use super::InventorySystem;
use crate::metrics::{BeliefView, ControlView, RunMetrics, TruthView};
use beliefbus_projection::inventory::policies::threshold_action;
use beliefbus_projection::inventory::sim::batch_means;
use beliefbus_projection::inventory::Inventory;
use serde_json::{json, Value};

/// Controls and applied orders kept for matching.
const RING: usize = 4096;
/// Batches of the batch-means standard errors.
const BATCHES: usize = 20;

/// The accumulator.
pub struct InventoryMetrics {
    model: Inventory,
    threshold: f64,
    /// Per counted period: our cost and the shadow's.
    ours: Vec<f64>,
    full: Vec<f64>,
    /// The shadow store's inventory and the last truth's sequence number.
    shadow: f64,
    last_seq: Option<u64>,
    gaps: u64,
    controlled: u64,
    orders: u64,
    err_sq: f64,
    raw_sq: f64,
    beliefs: u64,
    controls: Vec<Option<(u64, f64)>>,
    applied: Vec<Option<(u64, f64)>>,
}

impl InventoryMetrics {
    pub fn new(sys: &InventorySystem) -> Self {
        Self {
            model: sys.model.clone(),
            threshold: sys.params.threshold,
            ours: Vec::new(),
            full: Vec::new(),
            shadow: sys.params.x0,
            last_seq: None,
            gaps: 0,
            controlled: 0,
            orders: 0,
            err_sq: 0.0,
            raw_sq: 0.0,
            beliefs: 0,
            controls: vec![None; RING],
            applied: vec![None; RING],
        }
    }

    fn matched(c: Option<(u64, f64)>, a: Option<(u64, f64)>, seq: u64) -> bool {
        matches!((c, a), (Some((cs, cu)), Some((as_, au))) if cs == seq && as_ == seq && cu == au)
    }
}

impl RunMetrics for InventoryMetrics {
    fn truth(&mut self, t: &TruthView) {
        let consecutive = matches!(self.last_seq, Some(s) if s + 1 == t.seq);
        let first = self.last_seq.is_none() && t.seq == 0;
        self.last_seq = Some(t.seq);
        if first {
            self.shadow = t.x[0];
            return;
        }
        if !consecutive {
            // The demand of a lost period is unknown: restart the shadow
            // from the plant.
            self.gaps += 1;
            self.shadow = t.x[0];
            return;
        }
        // The period that ended at this sample: demand d = x[1], our cost
        // x[2]; the shadow meets the same demand.
        let d = t.x[1];
        let a = threshold_action(self.shadow, self.threshold);
        let g_full = self.model.cost(self.shadow, a, d);
        self.shadow = self.model.next_state(self.shadow, a, d);
        // Its order came from the control of sample seq − 1.
        let prev = t.seq - 1;
        let applied = Some((prev, t.u.first().copied().unwrap_or(f64::NAN)));
        if !t.counted {
            return;
        }
        let i = prev as usize % RING;
        self.applied[i] = applied;
        self.ours.push(t.x[2]);
        self.full.push(g_full);
        if Self::matched(self.controls[i], applied, prev) {
            self.controlled += 1;
        }
        if t.u.first().is_some_and(|&u| u > 0.0) {
            self.orders += 1;
        }
    }

    fn belief(&mut self, b: &BeliefView, t: &TruthView) {
        self.err_sq += (b.mean[0] - t.x[0]).powi(2);
        self.raw_sq += (t.y[0] - t.x[0]).powi(2);
        self.beliefs += 1;
    }

    fn control(&mut self, c: &ControlView) {
        if !c.ok {
            return;
        }
        let e = Some((c.sensor_seq, c.u.first().copied().unwrap_or(f64::NAN)));
        let i = c.sensor_seq as usize % RING;
        self.controls[i] = e;
        // Counted by whichever of the control and the next truth arrives
        // second.
        if Self::matched(e, self.applied[i], c.sensor_seq) {
            self.controlled += 1;
        }
    }

    fn report(&self) -> Value {
        let n = self.ours.len();
        let some = |v: f64| (n > 0).then_some(v);
        let (c, c_se) = batch_means(&self.ours, BATCHES);
        let (f, f_se) = batch_means(&self.full, BATCHES);
        let diff: Vec<f64> = self
            .ours
            .iter()
            .zip(&self.full)
            .map(|(a, b)| a - b)
            .collect();
        let (dv, dv_se) = batch_means(&diff, BATCHES);
        let b = self.beliefs as f64;
        json!({
            "sigma": self.model.sigma,
            "threshold": self.threshold,
            "periods": n,
            "average_cost": some(c),
            "average_cost_se": some(c_se),
            "full_obs_cost": some(f),
            "full_obs_cost_se": some(f_se),
            "deviation": some(dv),
            "deviation_se": some(dv_se),
            "deviation_pct": some(100.0 * (c / f - 1.0)),
            "order_fraction": some(self.orders as f64 / n as f64),
            "controlled_fraction": some(self.controlled as f64 / n as f64),
            "truth_gaps": self.gaps,
            "filter_rmse": (self.beliefs > 0).then(|| (self.err_sq / b).sqrt()),
            "raw_rmse": (self.beliefs > 0).then(|| (self.raw_sq / b).sqrt()),
        })
    }
}
