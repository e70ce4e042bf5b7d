//! State cost terms shared by the sampling controllers (MPPI and
//! path-integral control): a quadratic pull to a goal, a terminal weight and
//! a soft barrier keeping a pair of coordinates inside a disc.
//!
//! ```text
//! q(x)   = Σ_i w_i (x_i − g_i)² + w_wall · max(0, ‖(x_a, x_b)‖ − R_safe)²
//! φ(x_T) = Σ_i wf_i (x_i − g_i)² + w_wall · max(0, ‖(x_a, x_b)‖ − R_safe)²
//! ```

use crate::MAX_STATE;
use serde::{Deserialize, Serialize};

/// A soft disc constraint on two coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DiscBarrier {
    /// The two state coordinates the disc constrains.
    pub axes: (usize, usize),
    /// Radius of the disc; the wall acts beyond it.
    pub radius: f64,
    /// Weight of the quadratic penalty on the distance beyond the radius.
    pub weight: f64,
}

/// Quadratic goal tracking with an optional disc barrier.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackingCost {
    pub dim: usize,
    pub goal: [f64; MAX_STATE],
    /// Running weights w_i per unit time.
    pub q: [f64; MAX_STATE],
    /// Terminal weights wf_i.
    pub qf: [f64; MAX_STATE],
    pub barrier: Option<DiscBarrier>,
}

impl TrackingCost {
    /// A cost with running weights `q`, terminal weights `qf`, goal at 0.
    pub fn new(q: &[f64], qf: &[f64], barrier: Option<DiscBarrier>) -> Self {
        assert_eq!(q.len(), qf.len());
        let dim = q.len();
        let mut c = Self {
            dim,
            goal: [0.0; MAX_STATE],
            q: [0.0; MAX_STATE],
            qf: [0.0; MAX_STATE],
            barrier,
        };
        c.q[..dim].copy_from_slice(q);
        c.qf[..dim].copy_from_slice(qf);
        c
    }

    /// Set the goal state (components beyond `dim` ignored; a shorter goal
    /// sets only the leading components).
    pub fn set_goal(&mut self, goal: &[f64]) {
        let n = goal.len().min(self.dim);
        self.goal[..n].copy_from_slice(&goal[..n]);
    }

    fn barrier_cost(&self, x: &[f64]) -> f64 {
        match self.barrier {
            Some(b) => {
                let excess = (x[b.axes.0].hypot(x[b.axes.1]) - b.radius).max(0.0);
                b.weight * excess * excess
            }
            None => 0.0,
        }
    }

    /// Running state cost q(x).
    pub fn running(&self, x: &[f64]) -> f64 {
        let mut c = self.barrier_cost(x);
        for i in 0..self.dim {
            let e = x[i] - self.goal[i];
            c += self.q[i] * e * e;
        }
        c
    }

    /// Terminal cost φ(x).
    pub fn terminal(&self, x: &[f64]) -> f64 {
        let mut c = self.barrier_cost(x);
        for i in 0..self.dim {
            let e = x[i] - self.goal[i];
            c += self.qf[i] * e * e;
        }
        c
    }

    /// Gradient of q(x), written into `grad`.
    pub fn running_grad(&self, x: &[f64], grad: &mut [f64]) {
        for i in 0..self.dim {
            grad[i] = 2.0 * self.q[i] * (x[i] - self.goal[i]);
        }
        self.add_barrier_grad(x, grad);
    }

    /// Gradient of φ(x), written into `grad`.
    pub fn terminal_grad(&self, x: &[f64], grad: &mut [f64]) {
        for i in 0..self.dim {
            grad[i] = 2.0 * self.qf[i] * (x[i] - self.goal[i]);
        }
        self.add_barrier_grad(x, grad);
    }

    fn add_barrier_grad(&self, x: &[f64], grad: &mut [f64]) {
        if let Some(b) = self.barrier {
            let rho = x[b.axes.0].hypot(x[b.axes.1]);
            let excess = rho - b.radius;
            if excess > 0.0 && rho > 0.0 {
                let k = 2.0 * b.weight * excess / rho;
                grad[b.axes.0] += k * x[b.axes.0];
                grad[b.axes.1] += k * x[b.axes.1];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradients_match_finite_differences() {
        let mut c = TrackingCost::new(
            &[1.0, 2.0, 0.1, 0.1],
            &[5.0, 5.0, 1.0, 1.0],
            Some(DiscBarrier {
                axes: (0, 1),
                radius: 2.0,
                weight: 30.0,
            }),
        );
        c.set_goal(&[1.0, -1.0]);
        for x in [[0.3, 0.4, 1.0, -2.0], [2.5, 1.7, 0.0, 0.3]] {
            let mut g = [0.0; 4];
            let mut gf = [0.0; 4];
            c.running_grad(&x, &mut g);
            c.terminal_grad(&x, &mut gf);
            for i in 0..4 {
                let mut xp = x;
                let mut xm = x;
                xp[i] += 1e-6;
                xm[i] -= 1e-6;
                let fd = (c.running(&xp) - c.running(&xm)) / 2e-6;
                let fdf = (c.terminal(&xp) - c.terminal(&xm)) / 2e-6;
                assert!((fd - g[i]).abs() < 1e-5, "running {i}: {fd} vs {}", g[i]);
                assert!(
                    (fdf - gf[i]).abs() < 1e-5,
                    "terminal {i}: {fdf} vs {}",
                    gf[i]
                );
            }
        }
    }
}
