//! The tracking cost of the ship and of the pipeline's controllers (MPPI and
//! path-integral control): a quadratic pull to a goal, a terminal weight and
//! a soft barrier keeping a pair of coordinates inside a disc. It implements
//! the one cost trait, [`PathCost`]: analytic derivatives for the implicit
//! sampler, and a branch-free batch score for MPPI's rollouts.
//!
//! ```text
//! q(x)   = Σ_i w_i (x_i − g_i)² + w_wall · max(0, ‖(x_a, x_b)‖ − R_safe)²
//! φ(x_T) = Σ_i wf_i (x_i − g_i)² + w_wall · max(0, ‖(x_a, x_b)‖ − R_safe)²
//! ```
//!
//! [`DiagonalQuadraticCost`] is the same pull with the ½ convention and no
//! barrier (the arm, the double slit's tests).

pub use crate::model::path_cost::PathCost;
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

    /// Σ wᵢ(xᵢ − gᵢ)² + w_b max(0, ρ − R)² (ρ² compared first: no square
    /// root inside the disc).
    fn value(&self, w: &[f64; MAX_STATE], x: &[f64]) -> f64 {
        let mut v = 0.0;
        for i in 0..self.dim {
            let e = x[i] - self.goal[i];
            v += w[i] * e * e;
        }
        if let Some(b) = self.barrier {
            let rho2 = x[b.axes.0] * x[b.axes.0] + x[b.axes.1] * x[b.axes.1];
            if rho2 > b.radius * b.radius {
                let ex = rho2.sqrt() - b.radius;
                v += b.weight * ex * ex;
            }
        }
        v
    }

    /// Value, gradient and Hessian of [`Self::value`]; on the disc axes the
    /// barrier adds 2w_b [(ρ − R) x/ρ] to the gradient and
    /// 2w_b [x xᵀ/ρ² + (ρ − R)(I/ρ − x xᵀ/ρ³)] to the Hessian.
    fn derivatives(&self, w: &[f64; MAX_STATE], x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        let d = self.dim;
        h[..d * d].fill(0.0);
        let mut v = 0.0;
        for i in 0..d {
            let e = x[i] - self.goal[i];
            v += w[i] * e * e;
            g[i] = 2.0 * w[i] * e;
            h[i + i * d] = 2.0 * w[i];
        }
        if let Some(b) = self.barrier {
            let (ia, ib) = b.axes;
            let rho2 = x[ia] * x[ia] + x[ib] * x[ib];
            if rho2 > b.radius * b.radius {
                let rho = rho2.sqrt();
                let ex = rho - b.radius;
                v += b.weight * ex * ex;
                let xs = [x[ia], x[ib]];
                let idx = [ia, ib];
                for (p, &i) in idx.iter().enumerate() {
                    g[i] += 2.0 * b.weight * ex * xs[p] / rho;
                    for (q, &j) in idx.iter().enumerate() {
                        let delta = if p == q { 1.0 } else { 0.0 };
                        let outer = xs[p] * xs[q];
                        h[i + j * d] += 2.0
                            * b.weight
                            * (outer / rho2 + ex * (delta / rho - outer / (rho2 * rho)));
                    }
                }
            }
        }
        v
    }

    /// S_k += scale · (Σ_i w_i (x_ik − goal_i)² + barrier(x_k)) for the K
    /// states of `x` (structure-of-arrays), branch-free so that the loops
    /// over k vectorise; the barrier's radius is compared squared (a `sqrt`
    /// only outside the disc, no `hypot`: the latter costs ≈ 25 ns, as much
    /// as a whole MPPI rollout step).
    #[inline(always)]
    fn add_soa(&self, w: &[f64; MAX_STATE], scale: f64, k: usize, x: &[f64], s: &mut [f64]) {
        let s = &mut s[..k];
        for i in 0..self.dim {
            let (g, wi) = (self.goal[i], w[i] * scale);
            if wi == 0.0 {
                continue;
            }
            let xi = &x[i * k..(i + 1) * k];
            for n in 0..k {
                let e = xi[n] - g;
                s[n] += wi * (e * e);
            }
        }
        if let Some(b) = self.barrier.filter(|b| b.weight != 0.0) {
            let (a, bx) = b.axes;
            let (r, r2) = (b.radius, b.radius * b.radius);
            let (xa, xb) = (&x[a * k..(a + 1) * k], &x[bx * k..(bx + 1) * k]);
            let bw = b.weight * scale;
            for n in 0..k {
                let rho2 = xa[n] * xa[n] + xb[n] * xb[n];
                // max(·, R²) keeps e = 0 inside the disc without a branch.
                let e = rho2.max(r2).sqrt() - r;
                s[n] += bw * (e * e);
            }
        }
    }
}

impl PathCost for TrackingCost {
    fn running(&self, x: &[f64]) -> f64 {
        self.value(&self.q, x)
    }
    fn terminal(&self, x: &[f64]) -> f64 {
        self.value(&self.qf, x)
    }
    fn running_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        self.derivatives(&self.q, x, g, h)
    }
    fn terminal_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        self.derivatives(&self.qf, x, g, h)
    }
    fn set_goal(&mut self, goal: &[f64]) {
        TrackingCost::set_goal(self, goal)
    }
    fn check_state_dim(&self, state: usize) -> Result<(), String> {
        if self.dim > state {
            return Err(format!(
                "cost dimension {} exceeds the state dimension {state}",
                self.dim
            ));
        }
        if let Some(b) = self.barrier {
            if b.axes.0 >= state || b.axes.1 >= state {
                return Err("barrier axes outside the state".into());
            }
        }
        Ok(())
    }
    #[inline(always)]
    fn add_running_soa(&self, scale: f64, k: usize, x: &[f64], s: &mut [f64]) {
        self.add_soa(&self.q, scale, k, x, s)
    }
    #[inline(always)]
    fn add_terminal_soa(&self, scale: f64, k: usize, x: &[f64], s: &mut [f64]) {
        self.add_soa(&self.qf, scale, k, x, s)
    }
}

/// A quadratic cost ½(x−g)ᵀW(x−g) for V and ½(x−g)ᵀW_f(x−g) for Φ with
/// diagonal weights (tests, the arm, the double slit's Φ = x²/2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiagonalQuadraticCost {
    pub dim: usize,
    pub goal: [f64; MAX_STATE],
    pub w: [f64; MAX_STATE],
    pub wf: [f64; MAX_STATE],
}

impl DiagonalQuadraticCost {
    /// V = ½ Σ w_i (x_i − g_i)², Φ = ½ Σ wf_i (x_i − g_i)², goal 0.
    pub fn new(w: &[f64], wf: &[f64]) -> Self {
        assert_eq!(w.len(), wf.len());
        let mut c = Self {
            dim: w.len(),
            goal: [0.0; MAX_STATE],
            w: [0.0; MAX_STATE],
            wf: [0.0; MAX_STATE],
        };
        c.w[..w.len()].copy_from_slice(w);
        c.wf[..wf.len()].copy_from_slice(wf);
        c
    }

    fn quad(&self, wt: &[f64; MAX_STATE], x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        let d = self.dim;
        h[..d * d].fill(0.0);
        let mut v = 0.0;
        for i in 0..d {
            let e = x[i] - self.goal[i];
            v += 0.5 * wt[i] * e * e;
            g[i] = wt[i] * e;
            h[i + i * d] = wt[i];
        }
        v
    }
}

impl PathCost for DiagonalQuadraticCost {
    fn running(&self, x: &[f64]) -> f64 {
        (0..self.dim)
            .map(|i| 0.5 * self.w[i] * (x[i] - self.goal[i]).powi(2))
            .sum()
    }
    fn running_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        self.quad(&self.w, x, g, h)
    }
    fn terminal(&self, x: &[f64]) -> f64 {
        (0..self.dim)
            .map(|i| 0.5 * self.wf[i] * (x[i] - self.goal[i]).powi(2))
            .sum()
    }
    fn terminal_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        self.quad(&self.wf, x, g, h)
    }
    fn set_goal(&mut self, goal: &[f64]) {
        let k = goal.len().min(self.dim);
        self.goal[..k].copy_from_slice(&goal[..k]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng;
    use rand::RngExt;

    fn walled() -> TrackingCost {
        TrackingCost::new(
            &[1.0, 2.0, 0.1, 0.1],
            &[5.0, 5.0, 1.0, 1.0],
            Some(DiscBarrier {
                axes: (0, 1),
                radius: 2.0,
                weight: 30.0,
            }),
        )
    }

    /// The value by `hypot`, independent of the implementation's ρ² test.
    fn reference(c: &TrackingCost, w: &[f64], x: &[f64]) -> f64 {
        let b = c.barrier.unwrap();
        let ex = (x[b.axes.0].hypot(x[b.axes.1]) - b.radius).max(0.0);
        let pull: f64 = (0..c.dim).map(|i| w[i] * (x[i] - c.goal[i]).powi(2)).sum();
        pull + b.weight * ex * ex
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let mut c = walled();
        c.set_goal(&[1.0, -1.0]);
        for x in [
            [0.3, 0.4, 1.0, -2.0],
            [2.5, 1.7, 0.0, 0.3],
            [7.0, 6.0, 0.2, 0.1],
        ] {
            let (mut g, mut h) = ([0.0; 4], [0.0; 16]);
            let (mut gf, mut hf) = ([0.0; 4], [0.0; 16]);
            let v = c.running_derivatives(&x, &mut g, &mut h);
            let vf = c.terminal_derivatives(&x, &mut gf, &mut hf);
            assert_eq!(v, c.running(&x));
            assert_eq!(vf, c.terminal(&x));
            assert!((v - reference(&c, &c.q, &x)).abs() < 1e-12 * v.max(1.0));
            assert!((vf - reference(&c, &c.qf, &x)).abs() < 1e-12 * vf.max(1.0));
            for j in 0..4 {
                let (mut xp, mut xm) = (x, x);
                xp[j] += 1e-6;
                xm[j] -= 1e-6;
                let fd = (c.running(&xp) - c.running(&xm)) / 2e-6;
                let fdf = (c.terminal(&xp) - c.terminal(&xm)) / 2e-6;
                assert!((fd - g[j]).abs() < 1e-5, "running {j}: {fd} vs {}", g[j]);
                assert!(
                    (fdf - gf[j]).abs() < 1e-5,
                    "terminal {j}: {fdf} vs {}",
                    gf[j]
                );
                let (mut gp, mut gm, mut hh) = ([0.0; 4], [0.0; 4], [0.0; 16]);
                c.running_derivatives(&xp, &mut gp, &mut hh);
                c.running_derivatives(&xm, &mut gm, &mut hh);
                for i in 0..4 {
                    let fd = (gp[i] - gm[i]) / 2e-6;
                    let want = h[i + 4 * j];
                    assert!((fd - want).abs() < 1e-4, "({i},{j}) {fd} vs {want}");
                }
            }
        }
    }

    #[test]
    fn batch_score_equals_the_per_state_cost() {
        let mut c = TrackingCost::new(
            &[1.0, 2.0, 0.1, 0.3],
            &[5.0, 4.0, 1.0, 0.5],
            Some(DiscBarrier {
                axes: (0, 1),
                radius: 3.0,
                weight: 40.0,
            }),
        );
        c.set_goal(&[1.0, -2.0, 0.5]);
        let plain = TrackingCost::new(&[1.0; 4], &[2.0; 4], None);
        let mut rng = rng::stream(8, 8);
        // 1001 states (not a multiple of any lane count), SoA.
        let n = 1001;
        let mut x = vec![0.0; 4 * n];
        for v in x.iter_mut() {
            *v = rng.random_range(-5.0..5.0);
        }
        let (dt, prior) = (0.04, 0.7);
        let (mut run, mut term, mut pl) = (vec![prior; n], vec![prior; n], vec![0.0; n]);
        c.add_running_soa(dt, n, &x, &mut run);
        c.add_terminal_soa(1.0, n, &x, &mut term);
        plain.add_running_soa(1.0, n, &x, &mut pl);
        let mut inside = 0;
        for k in 0..n {
            let xk: [f64; 4] = std::array::from_fn(|i| x[i * n + k]);
            if xk[0].hypot(xk[1]) <= 3.0 {
                inside += 1;
            }
            for (a, b) in [
                (run[k], prior + dt * c.running(&xk)),
                (term[k], prior + c.terminal(&xk)),
            ] {
                assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0), "{a} vs {b}");
            }
            let want: f64 = xk.iter().map(|v| v * v).sum();
            assert!((pl[k] - want).abs() < 1e-12);
        }
        assert!(inside > 0 && inside < n, "both sides of the barrier");
    }

    #[test]
    fn state_dimension_is_checked() {
        let c = walled();
        assert!(c.check_state_dim(4).is_ok());
        assert!(c.check_state_dim(3).unwrap_err().contains("exceeds"));
        let far = TrackingCost::new(
            &[1.0],
            &[1.0],
            Some(DiscBarrier {
                axes: (0, 5),
                radius: 1.0,
                weight: 1.0,
            }),
        );
        assert!(far.check_state_dim(4).unwrap_err().contains("axes"));
    }
}
