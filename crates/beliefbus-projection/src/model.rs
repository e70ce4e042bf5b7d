//! The model traits the filters and the MDP builder are generic over.
//!
//! A discrete-time POMDP (paper §II, eq. 1–2): x_{k+1} = f(x_k, a_k, u_k),
//! y_k = h(x_k, v_k), a finite action set A and a one-step cost g. The
//! filters need only [`FilterModel`] (sample the transition, evaluate the
//! observation log-likelihood), so any sampled-observation model — an
//! Euler–Maruyama step of an SDE with Gaussian sensor noise included — is
//! a few lines of adapter. The projected-belief MDP builder additionally
//! needs [`Pomdp`]: the finite actions, observation sampling and the cost.
//!
//! States, observations and controls are `&[f64]` slices written in place,
//! so per-step code never allocates.

use crate::rng::SimRng;

/// What a particle filter needs from a model.
pub trait FilterModel: Sync {
    /// d, the state dimension.
    fn state_dim(&self) -> usize;
    /// The observation dimension.
    fn obs_dim(&self) -> usize;
    /// Replace `x` by a draw x' ~ p(· | x, u) (control `u`).
    fn sample_transition(&self, x: &mut [f64], u: &[f64], rng: &mut SimRng);
    /// log p(y | x), up to an additive constant independent of x.
    fn obs_log_likelihood(&self, x: &[f64], y: &[f64]) -> f64;
    /// Map a draw from a projected density into the state space S.
    ///
    /// An exponential-family belief may put mass outside S (a Gaussian on
    /// an inventory level that cannot be negative); a state drawn there is
    /// moved to the nearest point of S, i.e. the draw is from the projected
    /// density censored to S. The default is S = R^d (no change).
    fn constrain(&self, _x: &mut [f64]) {}
}

/// A POMDP with finitely many actions, for the projected-belief MDP.
pub trait Pomdp: FilterModel {
    /// |A|; actions are 0..num_actions().
    fn num_actions(&self) -> usize;
    /// The control vector of action `a` (what [`FilterModel::sample_transition`]
    /// receives when the controller picks `a`).
    fn action_control(&self, a: usize) -> &[f64];
    /// One period under action `a`: replace `x` by x' = f(x, a, u) with a
    /// fresh noise draw u, and return the cost g(x, a, u) of the period.
    /// Must advance `x` exactly as `sample_transition(x, action_control(a))`.
    fn sample_step(&self, x: &mut [f64], a: usize, rng: &mut SimRng) -> f64;
    /// Write a draw y ~ p(· | x) into `y`.
    fn sample_observation(&self, x: &[f64], y: &mut [f64], rng: &mut SimRng);
}

/// Normalise log-weights into `w` (max-shifted, so no underflow of the
/// largest); returns Σ exp(logw − max) before normalisation.
///
/// Errors when no weight is positive and finite: the observation is
/// impossible under every particle.
pub fn normalize_log_weights(logw: &[f64], w: &mut [f64]) -> Result<f64, crate::ProjectionError> {
    let max = logw.iter().fold(
        f64::NEG_INFINITY,
        |m, &l| {
            if l.is_nan() {
                m
            } else {
                m.max(l)
            }
        },
    );
    if !max.is_finite() {
        return Err(crate::ProjectionError::NoSupport);
    }
    let mut total = 0.0;
    for (wi, &l) in w.iter_mut().zip(logw) {
        *wi = if l.is_nan() { 0.0 } else { (l - max).exp() };
        total += *wi;
    }
    let inv = 1.0 / total;
    for wi in w.iter_mut() {
        *wi *= inv;
    }
    Ok(total)
}
