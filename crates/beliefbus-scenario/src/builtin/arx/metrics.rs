//! `scenario_metrics.arx`: the live run's figures.
//!
//! - `tracking_mse`: mean over counted steps of (y_t − y*_t)²;
//! - `oracle_tracking_mse`, `oracle_ratio`: the same for an oracle that
//!   knows θ_t and applies the exact one-step minimiser (19) under
//!   θ_{t+1} = θ_t w.p. 1 − ρ, ~ N(μ, V) w.p. ρ (no threshold; the
//!   `arx-control` experiment's oracle), run as a shadow system on the
//!   same θ path and the same noise: ε_t = y_t − θ_tᵀφ_t is recovered
//!   exactly from consecutive truths (a lost truth re-synchronises the
//!   shadow to the plant and is counted in `truth_gaps`); ratio = ours /
//!   oracle's;
//! - `controlled_fraction`: counted steps whose input u_{t−1} is the
//!   control computed from the belief of step t − 1 (matched by the
//!   control's sensor sequence number and its value);
//! - `detection_delays`: for each true change-point τ (the plant's run
//!   length back to 0) after the warm-up, the first t ≥ τ at which the
//!   posterior probability of a change in [τ, t] exceeds ½ — from the
//!   belief's median run length r̂_t: P(C_t ≥ τ) > ½ ⇔ t − r̂_t ≥ τ — and
//!   `delay` = t − τ steps (null: not detected by the end); with their
//!   count, mean and median.

use super::control::predictive;
use super::{ArxSystem, B1, RUN_LENGTH, T0};
use crate::metrics::{BeliefView, ControlView, RunMetrics, TruthView};
use beliefbus_changepoint::arx::control::uncertainty_adjusted;
use beliefbus_core::belief::Gaussian;
use serde_json::{json, Value};

/// Controls and applied inputs kept for matching.
const RING: usize = 4096;

/// One true change-point.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Change {
    step: u64,
    delay: Option<u64>,
}

/// The oracle's shadow system.
#[derive(Clone, Copy, Debug, Default)]
struct Shadow {
    /// y_t, y_{t−1} of the shadow, its next input, the plant's last truth
    /// (seq, y_{t−1} of the plant at that truth).
    y: [f64; 2],
    u: f64,
    last: Option<(u64, f64)>,
}

/// The accumulator.
pub struct ArxMetrics {
    sys: ArxSystem,
    se: f64,
    se_oracle: f64,
    n: u64,
    controlled: u64,
    gaps: u64,
    shadow: Shadow,
    changes: Vec<Change>,
    /// (seq, u) of controls by their sensor seq; (seq, u applied) of
    /// truths by seq − 1; matched whichever arrives second.
    controls: Vec<Option<(u64, f64)>>,
    applied: Vec<Option<(u64, f64)>>,
}

impl ArxMetrics {
    pub fn new(sys: &ArxSystem) -> Self {
        Self {
            sys: sys.clone(),
            se: 0.0,
            se_oracle: 0.0,
            n: 0,
            controlled: 0,
            gaps: 0,
            shadow: Shadow::default(),
            changes: Vec::new(),
            controls: vec![None; RING],
            applied: vec![None; RING],
        }
    }

    /// The oracle's step t: y^o_t from the shadow's regressor, θ_t and the
    /// plant's ε_t; then its input for t + 1.
    fn oracle_step(&mut self, t: &TruthView, step: u64) -> f64 {
        let th = [t.x[0], t.x[1], t.x[2]];
        let (y, y1, u) = (t.x[3], t.x[4], t.u.first().copied().unwrap_or(0.0));
        // y_{t−2} of the plant: the previous truth's y_{t−1}.
        let y2 = match self.shadow.last {
            Some((seq, y_prev1)) if seq + 1 == t.seq => Some(y_prev1),
            None if t.seq == 0 => Some(0.0),
            _ => None,
        };
        self.shadow.last = Some((t.seq, y1));
        let s = &mut self.shadow;
        let yo = match y2 {
            Some(y2) => {
                let eps = y - (th[0] * -y1 + th[1] * -y2 + th[2] * u);
                th[0] * -s.y[0] + th[1] * -s.y[1] + th[2] * s.u + eps
            }
            None => {
                // A lost truth: the shadow restarts from the plant.
                self.gaps += 1;
                s.y[0] = y1;
                y
            }
        };
        s.y = [yo, s.y[0]];
        let p = &self.sys.params;
        let target = p.reference(step + 1);
        s.u = if step < T0 {
            target
        } else {
            let mut g = Gaussian::zeros(3);
            g.mean[..3].copy_from_slice(&th);
            let (mean, second) = predictive(&g, p.rho, &self.sys.theta_prior());
            uncertainty_adjusted(&mean, &second, &[-yo, -s.y[1], 0.0], B1, target, 0.0, 0.0)
        };
        yo
    }

    fn matched(c: Option<(u64, f64)>, a: Option<(u64, f64)>, seq: u64) -> bool {
        matches!((c, a), (Some((cs, cu)), Some((as_, au))) if cs == seq && as_ == seq && cu == au)
    }
}

impl RunMetrics for ArxMetrics {
    fn truth(&mut self, t: &TruthView) {
        let step = t.seq + 1;
        let yo = self.oracle_step(t, step);
        if !t.counted {
            return;
        }
        let ys = self.sys.params.reference(step);
        self.se += (t.x[3] - ys).powi(2);
        self.se_oracle += (yo - ys).powi(2);
        self.n += 1;
        if step > T0 && t.x[RUN_LENGTH] == 0.0 {
            self.changes.push(Change { step, delay: None });
        }
        // Its input came from the control of sample seq − 1.
        if let Some(prev) = t.seq.checked_sub(1) {
            let a = Some((prev, t.u.first().copied().unwrap_or(f64::NAN)));
            let i = prev as usize % RING;
            self.applied[i] = a;
            if Self::matched(self.controls[i], a, prev) {
                self.controlled += 1;
            }
        }
    }

    fn belief(&mut self, b: &BeliefView, t: &TruthView) {
        let step = t.seq + 1;
        let r_hat = (b.mean[RUN_LENGTH] / self.sys.sample_dt).round().max(0.0) as u64;
        let since = step.saturating_sub(r_hat);
        for c in self.changes.iter_mut().filter(|c| c.delay.is_none()) {
            if c.step <= step && since >= c.step {
                c.delay = Some(step - c.step);
            }
        }
    }

    fn control(&mut self, c: &ControlView) {
        if !c.ok {
            return;
        }
        let e = Some((c.sensor_seq, c.u.first().copied().unwrap_or(f64::NAN)));
        let i = c.sensor_seq as usize % RING;
        self.controls[i] = e;
        if Self::matched(e, self.applied[i], c.sensor_seq) {
            self.controlled += 1;
        }
    }

    fn report(&self) -> Value {
        let n = self.n as f64;
        let mse = (self.n > 0).then(|| self.se / n);
        let oracle = (self.n > 0).then(|| self.se_oracle / n);
        let mut delays: Vec<u64> = self.changes.iter().filter_map(|c| c.delay).collect();
        delays.sort_unstable();
        let mean =
            (!delays.is_empty()).then(|| delays.iter().sum::<u64>() as f64 / delays.len() as f64);
        let median = delays.get(delays.len().saturating_sub(1) / 2).copied();
        json!({
            "rule": self.sys.params.control.rule,
            "steps": self.n,
            "tracking_mse": mse,
            "oracle_tracking_mse": oracle,
            "oracle_ratio": mse.zip(oracle).map(|(a, o)| a / o),
            "controlled_fraction": (self.n > 0).then(|| self.controlled as f64 / n),
            "truth_gaps": self.gaps,
            "change_points": self.changes.len(),
            "detected": delays.len(),
            "detection_delay_mean": mean,
            "detection_delay_median": median,
            "detection_delays": self.changes.iter()
                .map(|c| json!({"step": c.step, "delay": c.delay}))
                .collect::<Vec<_>>(),
        })
    }
}
