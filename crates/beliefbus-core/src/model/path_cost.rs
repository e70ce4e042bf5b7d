//! The state costs of a path-integral control problem (paper 003 eq. 15,
//! E2): running cost V(x) and terminal cost Φ(x) with analytic derivatives,
//! and the hard wall of the double slit as a [`Gate`]. They belong to the
//! problem, like its dynamics, so a model that states its control problem
//! (the double slit, Himmelblau) names them here; the path functional and
//! the controllers ([`crate::control::implicit`]) consume them.

/// Running and terminal state costs V(x), Φ(x) with analytic derivatives
/// (Hessians m×m column-major, written, not accumulated).
pub trait PathCost: Send + Sync {
    /// V(x).
    fn running(&self, x: &[f64]) -> f64;
    /// V(x), ∇V into `g`, ∇²V into `h`.
    fn running_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64;
    /// Φ(x).
    fn terminal(&self, x: &[f64]) -> f64;
    /// Φ(x), ∇Φ into `g`, ∇²Φ into `h`.
    fn terminal_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64;
    /// Move the target; costs without a target ignore it.
    fn set_goal(&mut self, _goal: &[f64]) {}
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
