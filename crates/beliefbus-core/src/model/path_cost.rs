//! The state costs of a control problem, one trait for every controller:
//! MPPI (Williams et al. 2017), the implicit-sampling path-integral
//! controller and naive path-integral Monte Carlo (paper 003 eq. 15, E2).
//!
//! ```text
//! S = Σ_t [ q(x_t) + ½ uₜᵀ R uₜ ] Δt + φ(x_T)
//! ```
//!
//! A cost states q = V (running) and φ = Φ (terminal) of the state; the
//! implicit sampler's Newton minimisation of the path functional F needs
//! their gradients and Hessians, MPPI scores K rollouts at once in
//! structure-of-arrays layout. The control cost is not part of the trait:
//! path-integral control requires it quadratic, ½ uᵀRu with R tied to the
//! noise by condition (8), so each controller owns R (MPPI's
//! `control_weight`, the PI controllers' `control_cost`). Nor is the time:
//! a goal that moves is set with [`PathCost::set_goal`], and a wall at one
//! time step is a [`Gate`], the hard constraint of the double slit (§3.1).
//!
//! Required: [`PathCost::running`], [`PathCost::terminal`]. Provided, to be
//! overridden where an analytic or faster form exists: the derivatives
//! (central finite differences) and the batch scores (one state at a time).
//! The costs belong to the problem, like its dynamics, so a model that
//! states its control problem (the double slit, Himmelblau) implements them
//! here, below the controllers that consume them.

use crate::MAX_STATE;

/// Step of the finite-difference defaults, relative to max(1, |xᵢ|): about
/// the cube root of the machine epsilon, which balances truncation (O(h²))
/// against rounding (O(ε/h)) for central differences of the gradient;
/// the Hessian's second differences lose more (O(ε/h²) ≈ 1e-5 relative).
const FD_STEP: f64 = 6e-6;

/// Running and terminal state costs q(x) = V(x), φ(x) = Φ(x). Hessians are
/// m×m column-major with m = `x.len()`, written, not accumulated.
pub trait PathCost: Send + Sync {
    /// V(x).
    fn running(&self, x: &[f64]) -> f64;
    /// Φ(x).
    fn terminal(&self, x: &[f64]) -> f64;
    /// V(x), ∇V into `g`, ∇²V into `h`. Default: central differences of
    /// [`PathCost::running`] (2m + 2m² evaluations).
    fn running_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        fd_derivatives(|y| self.running(y), x, g, h)
    }
    /// Φ(x), ∇Φ into `g`, ∇²Φ into `h`. Default: central differences of
    /// [`PathCost::terminal`].
    fn terminal_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        fd_derivatives(|y| self.terminal(y), x, g, h)
    }
    /// Move the target; costs without a target ignore it.
    fn set_goal(&mut self, _goal: &[f64]) {}
    /// Whether the cost can be evaluated on states of dimension `state`
    /// (a controller checks it at construction); the reason if not.
    fn check_state_dim(&self, _state: usize) -> Result<(), String> {
        Ok(())
    }
    /// s_k += scale · V(x_k) for the K = `k` states of `x` in
    /// structure-of-arrays layout (x[i·K + k], dimension `x.len() / k`).
    /// Default: one state at a time.
    fn add_running_soa(&self, scale: f64, k: usize, x: &[f64], s: &mut [f64]) {
        add_soa_each(|y| self.running(y), scale, k, x, s)
    }
    /// s_k += scale · Φ(x_k), layout as [`PathCost::add_running_soa`].
    fn add_terminal_soa(&self, scale: f64, k: usize, x: &[f64], s: &mut [f64]) {
        add_soa_each(|y| self.terminal(y), scale, k, x, s)
    }
}

/// s_k += scale · f(x_k), gathering each state of the structure-of-arrays
/// block into a stack buffer (no allocation).
fn add_soa_each(f: impl Fn(&[f64]) -> f64, scale: f64, k: usize, x: &[f64], s: &mut [f64]) {
    if k == 0 {
        return;
    }
    let d = (x.len() / k).min(MAX_STATE);
    let mut y = [0.0; MAX_STATE];
    for (n, sn) in s[..k].iter_mut().enumerate() {
        for (i, yi) in y[..d].iter_mut().enumerate() {
            *yi = x[i * k + n];
        }
        *sn += scale * f(&y[..d]);
    }
}

/// f(x), its central-difference gradient and Hessian (symmetric, from the
/// four-point mixed differences), with a stack copy of x (m ≤ MAX_STATE).
fn fd_derivatives(f: impl Fn(&[f64]) -> f64, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
    let m = x.len().min(MAX_STATE);
    let mut y = [0.0; MAX_STATE];
    y[..m].copy_from_slice(&x[..m]);
    let f0 = f(&y[..m]);
    let step = |v: f64| FD_STEP * v.abs().max(1.0);
    for i in 0..m {
        let hi = step(x[i]);
        y[i] = x[i] + hi;
        let fp = f(&y[..m]);
        y[i] = x[i] - hi;
        let fm = f(&y[..m]);
        y[i] = x[i];
        g[i] = (fp - fm) / (2.0 * hi);
        h[i + i * m] = (fp - 2.0 * f0 + fm) / (hi * hi);
    }
    for i in 0..m {
        for j in 0..i {
            let (hi, hj) = (step(x[i]), step(x[j]));
            let mut corner = |si: f64, sj: f64| {
                y[i] = x[i] + si * hi;
                y[j] = x[j] + sj * hj;
                let v = f(&y[..m]);
                y[i] = x[i];
                y[j] = x[j];
                v
            };
            let v = (corner(1.0, 1.0) - corner(1.0, -1.0) - corner(-1.0, 1.0) + corner(-1.0, -1.0))
                / (4.0 * hi * hj);
            h[i + j * m] = v;
            h[j + i * m] = v;
        }
    }
    f0
}

/// Most slit intervals a gate may have.
pub const MAX_GATE_INTERVALS: usize = 4;

/// A hard wall at one time step: V = +∞ unless coordinate `coord` of the
/// path point at step `step` lies in one of the intervals (the double slit,
/// §3.1). Each interval is a basin of F (one constrained minimum each).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gate {
    /// Path step i ≥ 1 (time τ_i = t + iΔt).
    pub step: usize,
    pub coord: usize,
    pub intervals: [(f64, f64); MAX_GATE_INTERVALS],
    pub count: usize,
}

impl Gate {
    /// A gate with the given (lo, hi) intervals (at most 4).
    pub fn new(step: usize, coord: usize, intervals: &[(f64, f64)]) -> Self {
        assert!(!intervals.is_empty() && intervals.len() <= MAX_GATE_INTERVALS);
        let mut iv = [(0.0, 0.0); MAX_GATE_INTERVALS];
        iv[..intervals.len()].copy_from_slice(intervals);
        Self {
            step,
            coord,
            intervals: iv,
            count: intervals.len(),
        }
    }
    /// Index of the interval containing `v`, if any.
    pub fn interval_of(&self, v: f64) -> Option<usize> {
        self.intervals[..self.count]
            .iter()
            .position(|&(lo, hi)| v >= lo && v <= hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::himmelblau::{self, HimmelblauCost};

    /// Himmelblau's f as Φ with only the required methods: the provided
    /// derivatives and batch score fall back to the defaults.
    struct ValuesOnly;
    impl PathCost for ValuesOnly {
        fn running(&self, x: &[f64]) -> f64 {
            0.25 * himmelblau::f(x)
        }
        fn terminal(&self, x: &[f64]) -> f64 {
            himmelblau::f(x)
        }
    }

    #[test]
    fn finite_difference_defaults_match_the_analytic_derivatives() {
        for x in [[-1.0, -4.0], [0.3, 2.7], [3.5, -1.9], [-12.0, 40.0]] {
            let (mut g, mut h) = ([0.0; 2], [0.0; 4]);
            let (mut ga, mut ha) = ([0.0; 2], [0.0; 4]);
            let v = ValuesOnly.terminal_derivatives(&x, &mut g, &mut h);
            let va = HimmelblauCost.terminal_derivatives(&x, &mut ga, &mut ha);
            assert_eq!(v, va);
            let gs = ga.iter().fold(1.0f64, |a, b| a.max(b.abs()));
            let hs = ha.iter().fold(1.0f64, |a, b| a.max(b.abs()));
            for i in 0..2 {
                assert!(
                    (g[i] - ga[i]).abs() < 1e-8 * gs.max(va),
                    "g {x:?}: {g:?} vs {ga:?}"
                );
            }
            for i in 0..4 {
                assert!(
                    (h[i] - ha[i]).abs() < 1e-4 * hs.max(va),
                    "h {x:?}: {h:?} vs {ha:?}"
                );
            }
            assert_eq!(h[1], h[2], "symmetric");
            let vr = ValuesOnly.running_derivatives(&x, &mut g, &mut h);
            assert_eq!(vr, 0.25 * va);
            assert!((g[0] - 0.25 * ga[0]).abs() < 1e-8 * gs.max(va));
        }
    }

    #[test]
    fn default_batch_score_is_the_per_state_cost() {
        // K = 3 states of dimension 2, structure-of-arrays.
        let x = [1.0, -2.0, 0.5, 3.0, 0.25, -1.5];
        let mut s = [1.0, 2.0, 3.0];
        ValuesOnly.add_terminal_soa(0.5, 3, &x, &mut s);
        let mut r = [0.0; 3];
        ValuesOnly.add_running_soa(2.0, 3, &x, &mut r);
        for n in 0..3 {
            let y = [x[n], x[3 + n]];
            assert_eq!(s[n], (n + 1) as f64 + 0.5 * himmelblau::f(&y));
            assert_eq!(r[n], 2.0 * 0.25 * himmelblau::f(&y));
        }
    }
}
