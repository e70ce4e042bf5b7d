//! What the world is: stochastic differential equation models and their
//! discrete-time views. A model describes the maths only — drift, diffusion,
//! observation mean and noise, bounds — and every filter and controller is
//! generic over it (the `particles` habit: a model is a few methods).
//!
//! The continuous-time model (thesis eq. 3.3–3.4, paper 001 eq. 1–2):
//!
//! ```text
//! dx = f(x, u) dt + F(x) dw,        x ∈ S ⊂ R^d, w a k-dim Wiener process
//! y_k = g(x(t_k)) + v_k,            v_k ~ N(0, diag(σ²))   (sampled sensor)
//! ```
//!
//! Observations are modelled as **sampled** measurements with independent
//! per-component noise `σ` ([`SdeModel::obs_std`]). The papers' continuous
//! observation `dy = g dt + G dv`, observed as increments over an interval Δ,
//! is the same thing with `y_k = Δy/Δ` and `σ = G/√Δ`; the experiments build
//! their models that way (see [`continuous_obs_std`]).

pub mod affine;
pub mod arm;
pub mod bounds;
pub mod discrete;
pub mod double_slit;
#[cfg(any(test, feature = "test-support"))]
pub mod forwarding_check;
pub mod himmelblau;
pub mod linear;
pub mod lorenz;
pub mod param_estimation;
pub mod path_cost;
pub mod planar_quadrotor;
pub mod sample;
pub mod scale;
pub mod ship;
pub mod vanderpol;

pub use bounds::{Bounds, BoundsError, Disc};
pub use discrete::{em_step, obs_log_likelihood, simulate_observation};

use crate::{MAX_OBS, MAX_STATE};

/// Dimensions of a model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dims {
    /// d, the state dimension.
    pub state: usize,
    /// k, the dimension of the Wiener process w.
    pub noise: usize,
    /// m, the observation dimension.
    pub obs: usize,
    /// The control dimension (0 for an uncontrolled model).
    pub control: usize,
}

/// A controlled diffusion with a sampled observation model.
///
/// Matrices are written into caller-provided column-major slices so the hot
/// paths never allocate.
pub trait SdeModel: Send + Sync {
    /// A short name (scenario id).
    fn name(&self) -> &str;
    /// The model's dimensions.
    fn dims(&self) -> Dims;
    /// Drift f(x, u), written into `f` (length d). `u` has length
    /// `dims().control` (empty for an uncontrolled model).
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]);
    /// Drift of `n` states at once, in structure-of-arrays layout:
    /// component i of state k is `x[i·n + k]` (d × n), control j of state k
    /// is `u[j·n + k]` (c × n), and f(x_k, u_k)_i goes to `f[i·n + k]`.
    ///
    /// Samplers that advance many states in lockstep (MPPI rollouts) call
    /// this; a model overrides it with branch-free loops over k so that the
    /// compiler vectorises them. The default gathers each state and calls
    /// [`SdeModel::drift`].
    fn drift_soa(&self, n: usize, x: &[f64], u: &[f64], f: &mut [f64]) {
        let dims = self.dims();
        let (d, c) = (dims.state, dims.control);
        let mut xk = [0.0; MAX_STATE];
        let mut uk = [0.0; crate::MAX_CONTROL];
        let mut fk = [0.0; MAX_STATE];
        for k in 0..n {
            for i in 0..d {
                xk[i] = x[i * n + k];
            }
            for j in 0..c {
                uk[j] = u[j * n + k];
            }
            self.drift(&xk[..d], &uk[..c], &mut fk[..d]);
            for i in 0..d {
                f[i * n + k] = fk[i];
            }
        }
    }
    /// Diffusion F(x), d × k column-major, written into `big_f`.
    fn diffusion(&self, x: &[f64], big_f: &mut [f64]);
    /// Observation mean g(x), written into `g` (length m).
    fn obs_mean(&self, x: &[f64], g: &mut [f64]);
    /// Standard deviation of each component of one sampled measurement.
    fn obs_std(&self, std: &mut [f64]);
    /// Innovation y − ŷ. Override for angular components (wrap to (−π, π]).
    fn obs_residual(&self, y: &[f64], yhat: &[f64], r: &mut [f64]) {
        for ((r, y), yh) in r.iter_mut().zip(y).zip(yhat) {
            *r = y - yh;
        }
    }
    /// The compact set S the state lives in (chains are built inside it).
    fn bounds(&self) -> &Bounds;
}

/// Jacobians of drift and observation, for the EKF, UKF-free linearisations
/// and Newton solvers. The provided methods use central finite differences;
/// models with closed forms override them.
pub trait SdeJacobians: SdeModel {
    /// ∂f/∂x at (x, u), d × d column-major.
    fn drift_jacobian(&self, x: &[f64], u: &[f64], jac: &mut [f64]) {
        scale::fd_drift_jacobian(self, x, u, jac)
    }

    /// ∂g/∂x at x, m × d column-major.
    fn obs_jacobian(&self, x: &[f64], jac: &mut [f64]) {
        let Dims {
            state: d, obs: m, ..
        } = self.dims();
        let mut xp = [0.0; MAX_STATE];
        let mut gp = [0.0; MAX_OBS];
        let mut gm = [0.0; MAX_OBS];
        let mut r = [0.0; MAX_OBS];
        xp[..d].copy_from_slice(x);
        for j in 0..d {
            let h = fd_step(x[j]);
            xp[j] = x[j] + h;
            self.obs_mean(&xp[..d], &mut gp[..m]);
            xp[j] = x[j] - h;
            self.obs_mean(&xp[..d], &mut gm[..m]);
            xp[j] = x[j];
            self.obs_residual(&gp[..m], &gm[..m], &mut r[..m]);
            for i in 0..m {
                jac[i + j * m] = r[i] / (2.0 * h);
            }
        }
    }
}

/// Central-difference step for a coordinate of magnitude |x|.
pub fn fd_step(x: f64) -> f64 {
    1e-6 * x.abs().max(1.0)
}

/// σ of the sampled observation equivalent to `dy = g dt + G dv` observed as
/// increments over `dt`: `y = Δy/Δt`, so `σ = G/√Δt`.
pub fn continuous_obs_std(g_coeff: f64, dt: f64) -> f64 {
    g_coeff / dt.sqrt()
}

/// Which observation components a measurement carries (bit i = component i).
///
/// A sensor channel usually provides only part of the observation vector
/// (range/bearing from one sensor, odometry from another); filters use only
/// the masked components in their likelihood.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ObsMask(pub u32);

impl ObsMask {
    /// All of the first `m` components.
    pub fn all(m: usize) -> Self {
        debug_assert!(m <= 32);
        Self(if m >= 32 { u32::MAX } else { (1u32 << m) - 1 })
    }
    /// Whether component `i` is present.
    pub fn contains(self, i: usize) -> bool {
        i < 32 && self.0 & (1 << i) != 0
    }
    /// Number of components present.
    pub fn count(self) -> usize {
        self.0.count_ones() as usize
    }
    /// Iterator over the present components, ascending.
    pub fn iter(self) -> impl Iterator<Item = usize> {
        (0..32).filter(move |&i| self.contains(i))
    }
}

/// One measurement handed to a filter's update.
#[derive(Clone, Copy, Debug)]
pub struct Measurement<'a> {
    /// Observation vector of the model's full dimension m; components outside
    /// `mask` are ignored.
    pub y: &'a [f64],
    /// The components this measurement carries.
    pub mask: ObsMask,
    /// Per-component σ overriding the model's [`SdeModel::obs_std`].
    pub std: Option<&'a [f64]>,
}

impl<'a> Measurement<'a> {
    /// A measurement of every component with the model's noise.
    pub fn full(y: &'a [f64]) -> Self {
        Self {
            y,
            mask: ObsMask::all(y.len()),
            std: None,
        }
    }
}
