//! Controllers behind one trait. A controller maps the current belief to the
//! control to apply now; it owns its seeded noise generator and warm-starts
//! from its previous solution. Backends: MPPI (baseline) and implicit-sampling
//! path-integral control (paper 003).

pub mod cost;
pub mod implicit;
pub mod mppi;
pub mod naive_pi;
pub mod path_integral;
pub mod waypoints;

use crate::belief::Gaussian;

/// Why a controller could not produce a control. The caller keeps applying
/// a safe control (zero or the last one) and counts the failure.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ControlError {
    #[error("belief has dimension {got}, controller expects {expected}")]
    Dimension { got: usize, expected: usize },
    #[error("belief is not finite")]
    NonFinite,
    #[error("model violates the controller's assumption: {0}")]
    Model(String),
    #[error("numerical failure: {0}")]
    Numerical(&'static str),
}

/// Diagnostics of one control computation.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ControlInfo {
    /// The optimiser's estimate of the cost-to-go of the returned plan.
    pub cost: f64,
    /// Rollouts or samples used.
    pub samples: usize,
    /// Effective sample size of the importance weights.
    pub ess: f64,
}

/// A feedback controller acting on a belief.
pub trait Controller: Send {
    /// Backend name (`mppi`, `implicit`, ...).
    fn name(&self) -> &'static str;
    /// Control dimension.
    fn control_dim(&self) -> usize;
    /// Set the target the cost function tracks (a full state; components the
    /// cost does not weigh are ignored).
    fn set_goal(&mut self, goal: &[f64]);
    /// Forget the warm start (e.g. after a goal switch or a restart).
    fn reset(&mut self);
    /// Off-critical-path work for the next call (e.g. drawing the next
    /// rollouts' noise). A stage calls it right after publishing a control;
    /// `compute` stays correct when it was not called.
    fn prepare(&mut self) {}
    /// The step of the next belief: the sequence number of the sensor
    /// sample it was updated with (a discrete-time system's time index).
    /// A stage calls it before each `compute`; continuous-time controllers
    /// use `compute`'s `t` and ignore it.
    fn set_step(&mut self, _k: u64) {}
    /// Compute the control to apply at time `t` given the belief, into `u`.
    fn compute(
        &mut self,
        t: f64,
        belief: &Gaussian,
        u: &mut [f64],
    ) -> Result<ControlInfo, ControlError>;
}
