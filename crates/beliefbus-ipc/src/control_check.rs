//! What an actuator may apply: a control of the run's dimension, finite,
//! inside the controller's limits. Anything that can open the `control`
//! service can publish on it, so the plant and every actuator check each
//! control before applying it and hold the last good one otherwise
//! (`docs/security.md`).

use super::messages::Control;
use crate::MAX_CONTROL;

/// Why a control was refused (report names `control_<snake_case>`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::IntoStaticStr, strum::VariantNames)]
#[strum(prefix = "control_", serialize_all = "snake_case")]
pub enum ControlReject {
    /// `dim` is not the run's control dimension.
    Dimension,
    /// A component of `u` (or the goal) is NaN or infinite.
    NonFinite,
    /// A component of `u` is outside the controller's limits.
    Limit,
}

impl ControlReject {
    /// Report name.
    pub fn name(self) -> &'static str {
        self.into()
    }
}

/// The controls an actuator accepts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlLimits {
    dim: usize,
    lo: [f64; MAX_CONTROL],
    hi: [f64; MAX_CONTROL],
}

impl ControlLimits {
    /// Controls of dimension `lo.len()` (at most [`MAX_CONTROL`]) with
    /// `lo[j] <= u[j] <= hi[j]`.
    pub fn new(lo: &[f64], hi: &[f64]) -> Self {
        let dim = lo.len().min(hi.len()).min(MAX_CONTROL);
        let mut l = [f64::NEG_INFINITY; MAX_CONTROL];
        let mut h = [f64::INFINITY; MAX_CONTROL];
        l[..dim].copy_from_slice(&lo[..dim]);
        h[..dim].copy_from_slice(&hi[..dim]);
        Self { dim, lo: l, hi: h }
    }

    /// Controls of dimension `dim`, any finite value.
    pub fn finite(dim: usize) -> Self {
        let dim = dim.min(MAX_CONTROL);
        Self {
            dim,
            lo: [f64::NEG_INFINITY; MAX_CONTROL],
            hi: [f64::INFINITY; MAX_CONTROL],
        }
    }

    /// The accepted dimension.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Check `c`.
    pub fn check(&self, c: &Control) -> Result<(), ControlReject> {
        if c.dim as usize != self.dim {
            return Err(ControlReject::Dimension);
        }
        let u = &c.u[..self.dim];
        if u.iter().chain(&c.goal).any(|v| !v.is_finite()) {
            return Err(ControlReject::NonFinite);
        }
        // A hair of slack: a controller clamps exactly to the limit, and a
        // limit converted through text may differ in its last bit.
        let slack = |b: f64| 1e-9 * b.abs().max(1.0);
        let out = u
            .iter()
            .zip(&self.lo[..self.dim])
            .zip(&self.hi[..self.dim])
            .any(|((&v, &lo), &hi)| v < lo - slack(lo) || v > hi + slack(hi));
        if out {
            return Err(ControlReject::Limit);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn control(dim: u32, u: &[f64]) -> Control {
        let mut c = Control {
            dim,
            ..Control::default()
        };
        c.u[..u.len()].copy_from_slice(u);
        c
    }

    #[test]
    fn dimension_finiteness_and_limits_are_checked_in_that_order() {
        let l = ControlLimits::new(&[-3.0, -3.0], &[3.0, 3.0]);
        assert_eq!(l.check(&control(2, &[3.0, -3.0])), Ok(()));
        assert_eq!(l.check(&control(2, &[0.5, 0.0])), Ok(()));
        assert_eq!(l.check(&control(1, &[0.5])), Err(ControlReject::Dimension));
        assert_eq!(
            l.check(&control(MAX_CONTROL as u32 + 7, &[])),
            Err(ControlReject::Dimension)
        );
        assert_eq!(
            l.check(&control(2, &[f64::NAN, 0.0])),
            Err(ControlReject::NonFinite)
        );
        assert_eq!(
            l.check(&control(2, &[0.0, f64::INFINITY])),
            Err(ControlReject::NonFinite)
        );
        assert_eq!(
            l.check(&control(2, &[50.0, 0.0])),
            Err(ControlReject::Limit)
        );
        assert_eq!(
            l.check(&control(2, &[0.0, -50.0])),
            Err(ControlReject::Limit)
        );
        let mut c = control(2, &[0.0, 0.0]);
        c.goal[0] = f64::NAN;
        assert_eq!(l.check(&c), Err(ControlReject::NonFinite));
        // Unbounded: only dimension and finiteness.
        let f = ControlLimits::finite(2);
        assert_eq!(f.check(&control(2, &[1e6, -1e6])), Ok(()));
        assert_eq!(
            f.check(&control(2, &[f64::NAN, 0.0])),
            Err(ControlReject::NonFinite)
        );
    }
}
