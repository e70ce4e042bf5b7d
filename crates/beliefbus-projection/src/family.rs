//! Exponential families and the density projection (paper §III).
//!
//! Ω = {f(x, θ) = exp(θᵀc(x) − φ(θ))}, c = (c_1..c_m) the sufficient
//! statistics. Proj_Ω(b) = argmin_f D_KL(b‖f) is the unique θ with
//! E_b[c_j(X)] = E_θ[c_j(X)], j = 1..m (eq. 9); for weighted particles
//! E_b[c_j] = Σ_i w_i c_j(x_i) (eq. 14).

use crate::rng::SimRng;
use crate::ProjectionError;

/// An exponential family with a moment-matching projection.
///
/// Parameters live in caller-owned [`ExpFamily::Params`] values allocated
/// once ([`ExpFamily::new_params`]) and overwritten in place, so projecting
/// and sampling never allocate.
pub trait ExpFamily: Sync {
    /// The family's parameters in whatever form sampling needs (for the
    /// Gaussian: mean, covariance and its Cholesky factor).
    type Params: Clone + Send + Sync + std::fmt::Debug;

    /// A short name, recorded in policy files.
    fn name(&self) -> &'static str;
    /// The dimension of x.
    fn state_dim(&self) -> usize;
    /// Freshly allocated parameters (a valid member of the family).
    fn new_params(&self) -> Self::Params;

    /// m, the number of sufficient statistics.
    fn num_stats(&self) -> usize;
    /// c(x) into `out` (length m).
    fn stats(&self, x: &[f64], out: &mut [f64]);
    /// E_θ[c(X)] into `out` (length m).
    fn expected_stats(&self, params: &Self::Params, out: &mut [f64]);

    /// Moment matching (eq. 14): the θ with E_θ[c] = Σ_i w_i c(x_i).
    /// `particles` is n × d row-major, `weights` sums to one.
    fn project(
        &self,
        particles: &[f64],
        weights: &[f64],
        out: &mut Self::Params,
    ) -> Result<(), ProjectionError>;

    /// Replace `x` (length d) by a draw from f(·, θ).
    fn sample(&self, params: &Self::Params, rng: &mut SimRng, x: &mut [f64]);

    /// The number of coordinates a policy grid is laid on.
    fn grid_dim(&self) -> usize;
    /// The grid coordinates of θ (for the Gaussian: means then standard
    /// deviations) into `out`.
    fn grid_coords(&self, params: &Self::Params, out: &mut [f64]);
    /// The member of the family at grid coordinates `coords`.
    fn params_from_grid(
        &self,
        coords: &[f64],
        out: &mut Self::Params,
    ) -> Result<(), ProjectionError>;
}
