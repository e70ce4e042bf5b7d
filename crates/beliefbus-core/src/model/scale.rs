//! Time scales of a model, measured on its prior predictive: how fast the
//! drift moves a state (the drift Jacobian's spectral radius) and how
//! strongly it diffuses (‖F Fᵀ‖), at points of simulated trajectories
//! started from the prior.
//!
//! ```text
//! ρ(x) = max |λ_i(∂f/∂x (x, 0))|,        q(x) = ‖F Fᵀ(x)‖₂
//! points: x₀ ~ prior (restricted to S), and x(t_j) on EM trajectories from them,
//!         t_j = j H/J, j = 1..J, H the probe horizon
//! ```
//!
//! Integrators and chains pick their step from ρ: an explicit step h
//! resolves a linear mode e^{λt} with relative error O(|λ| h) (Euler–
//! Maruyama) or O((|λ| h)⁵) (RK4), so h·ρ bounded by a constant bounds the
//! bias on the fastest mode the trajectories meet ([`crate::filter::pf`]
//! checks its `max_dt` against it; [`crate::filter::chain_spec`] derives δ
//! from it). The probe is data-free and seeded.

use crate::belief::Gaussian;
use crate::model::sample::Sampler;
use crate::model::{em_step, SdeModel};
use crate::rng::SimRng;
use crate::{MAX_NOISE, MAX_STATE};

/// Trajectories of the probe.
pub const PROBE_TRAJECTORIES: usize = 32;
/// Recorded points per trajectory (besides its start).
pub const PROBE_POINTS: usize = 16;
/// Probe horizon in units of the prior's median time constant 1/ρ when
/// the caller gives none: long enough for the trajectories to leave the
/// prior and meet the dynamics a filter will meet (with 20 the Lorenz-63
/// probe saw one wing of the attractor and found a 2× coarser admissible
/// Euler step than over 10 s).
pub const PROBE_TIME_CONSTANTS: f64 = 100.0;
/// EM step of the probe's own trajectories: h = this / (largest ρ seen).
const PROBE_RATE_STEP: f64 = 0.05;

/// What [`probe`] measured.
#[derive(Clone, Debug, PartialEq)]
pub struct TimeScales {
    /// Median spectral radius ρ of the drift Jacobian over the points (1/s).
    pub rate_median: f64,
    /// 99th percentile of ρ (1/s): the fastest rate a filter must resolve.
    pub rate_p99: f64,
    /// Median ‖F Fᵀ‖₂ over the points.
    pub diffusion_median: f64,
    /// Median ‖f‖ over the points.
    pub speed_median: f64,
    /// 99th percentile of ‖(∂f/∂x) f‖ = ‖d²x/dt²‖ of the deterministic
    /// flow: an explicit Euler step h errs by ≈ h²/2 times it.
    pub accel_p99: f64,
    /// Mean of ‖(∂f/∂x) f‖ over the points (≈ its time average along the
    /// trajectories: the rate at which Euler's drift error accumulates).
    pub accel_mean: f64,
    /// Horizon the trajectories ran (s).
    pub horizon: f64,
    /// Number of points measured.
    pub points: usize,
}

/// Why a probe failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScaleError {
    /// The prior covariance is not positive definite.
    #[error("time-scale probe: prior covariance is not positive definite")]
    Prior,
    /// The drift or its Jacobian is not finite at any probed point.
    #[error("time-scale probe: drift not finite at the prior's points")]
    NonFinite,
}

/// ∂f/∂x at (x, u) by central differences (the [`super::SdeJacobians`]
/// default), for models without Jacobians. `jac` is d × d column-major.
pub fn fd_drift_jacobian<M: SdeModel + ?Sized>(model: &M, x: &[f64], u: &[f64], jac: &mut [f64]) {
    let d = model.dims().state;
    let mut xp = [0.0; MAX_STATE];
    let mut fp = [0.0; MAX_STATE];
    let mut fm = [0.0; MAX_STATE];
    xp[..d].copy_from_slice(x);
    for j in 0..d {
        let h = super::fd_step(x[j]);
        xp[j] = x[j] + h;
        model.drift(&xp[..d], u, &mut fp[..d]);
        xp[j] = x[j] - h;
        model.drift(&xp[..d], u, &mut fm[..d]);
        xp[j] = x[j];
        for i in 0..d {
            jac[i + j * d] = (fp[i] - fm[i]) / (2.0 * h);
        }
    }
}

/// Spectral radius max |λ_i| of the d × d column-major matrix `a`
/// (eigenvalues of its real Schur form). NaN if `a` is not finite.
pub fn spectral_radius(a: &[f64], d: usize) -> f64 {
    if a[..d * d].iter().any(|v| !v.is_finite()) {
        return f64::NAN;
    }
    let m = nalgebra::DMatrix::from_column_slice(d, d, &a[..d * d]);
    m.complex_eigenvalues()
        .iter()
        .map(|l| l.norm())
        .fold(0.0, f64::max)
}

/// ρ(x), q(x) = ‖F Fᵀ(x)‖₂, ‖f(x)‖ and ‖(∂f/∂x) f‖ of an uncontrolled
/// model (finite-difference Jacobian).
pub fn local_scales<M: SdeModel + ?Sized>(model: &M, x: &[f64]) -> (f64, f64, f64, f64) {
    let dims = model.dims();
    let (d, k) = (dims.state, dims.noise);
    let u = [0.0; crate::MAX_CONTROL];
    let u = &u[..dims.control];
    let mut jac = [0.0; MAX_STATE * MAX_STATE];
    fd_drift_jacobian(model, x, u, &mut jac[..d * d]);
    let mut f = [0.0; MAX_STATE];
    model.drift(x, u, &mut f[..d]);
    let mut big_f = [0.0; MAX_STATE * MAX_NOISE];
    model.diffusion(x, &mut big_f[..d * k]);
    let mut ff = [0.0; MAX_STATE * MAX_STATE];
    for i in 0..d {
        for j in 0..d {
            ff[i + j * d] = (0..k).map(|c| big_f[i + c * d] * big_f[j + c * d]).sum();
        }
    }
    let q = crate::math::linalg::sym_spectral_norm(&ff[..d * d], d);
    let speed = f[..d].iter().map(|v| v * v).sum::<f64>().sqrt();
    let accel = (0..d)
        .map(|i| (0..d).map(|j| jac[i + j * d] * f[j]).sum::<f64>().powi(2))
        .sum::<f64>()
        .sqrt();
    (spectral_radius(&jac[..d * d], d), q, speed, accel)
}

/// Measure the time scales of `model` over its prior predictive:
/// [`PROBE_TRAJECTORIES`] Euler–Maruyama trajectories from draws of
/// `prior` (restricted to S, projected back onto S after every step), run
/// to `horizon` (default [`PROBE_TIME_CONSTANTS`] / median ρ at the prior
/// draws, or 1 s for a drift-free model) with step 0.05/ρ_max (ρ_max the
/// largest rate seen so far), [`PROBE_POINTS`] points recorded on each.
pub fn probe<M: SdeModel + ?Sized>(
    model: &M,
    prior: &Gaussian,
    horizon: Option<f64>,
    rng: &mut SimRng,
) -> Result<TimeScales, ScaleError> {
    // The prior restricted to S, as the chain's placement draws it.
    let sampler = Sampler::around(prior, 1.0, 0.0).ok_or(ScaleError::Prior)?;
    let d = prior.dim;
    let u = vec![0.0; model.dims().control];
    let mut starts = vec![0.0; PROBE_TRAJECTORIES * d];
    let mut rates = Vec::with_capacity(PROBE_TRAJECTORIES * (PROBE_POINTS + 1));
    let mut diffs = Vec::with_capacity(rates.capacity());
    let mut speeds = Vec::with_capacity(rates.capacity());
    let mut accels = Vec::with_capacity(rates.capacity());
    let mut record = |x: &[f64], rates: &mut Vec<f64>| {
        let (r, q, s, a) = local_scales(model, x);
        if r.is_finite() && q.is_finite() && s.is_finite() && a.is_finite() {
            rates.push(r);
            diffs.push(q);
            speeds.push(s);
            accels.push(a);
        }
    };
    for x in starts.chunks_exact_mut(d) {
        sampler.sample(model.bounds(), rng, x);
        record(x, &mut rates);
    }
    if rates.is_empty() {
        return Err(ScaleError::NonFinite);
    }
    let rho0 = quantile(&rates, 0.5);
    let horizon = horizon
        .filter(|h| h.is_finite() && *h > 0.0)
        .unwrap_or(if rho0 > 0.0 {
            PROBE_TIME_CONSTANTS / rho0
        } else {
            1.0
        });
    let mut rho_max = rates.iter().copied().fold(0.0, f64::max);
    let seg = horizon / PROBE_POINTS as f64;
    let mut x = [0.0; MAX_STATE];
    let mut y = [0.0; MAX_STATE];
    for s in starts.chunks_exact(d) {
        x[..d].copy_from_slice(s);
        for _ in 0..PROBE_POINTS {
            let steps = if rho_max > 0.0 {
                (seg * rho_max / PROBE_RATE_STEP).ceil().max(1.0)
            } else {
                16.0
            };
            let h = seg / steps;
            for _ in 0..steps as usize {
                em_step(model, &x[..d], &u, h, rng, &mut y[..d]);
                model.bounds().project(&mut y[..d]);
                std::mem::swap(&mut x, &mut y);
            }
            if x[..d].iter().all(|v| v.is_finite()) {
                let before = rates.len();
                record(&x[..d], &mut rates);
                if rates.len() > before {
                    rho_max = rho_max.max(rates[before]);
                }
            } else {
                break;
            }
        }
    }
    Ok(TimeScales {
        rate_median: quantile(&rates, 0.5),
        rate_p99: quantile(&rates, 0.99),
        diffusion_median: quantile(&diffs, 0.5),
        speed_median: quantile(&speeds, 0.5),
        accel_p99: quantile(&accels, 0.99),
        accel_mean: accels.iter().sum::<f64>() / accels.len().max(1) as f64,
        horizon,
        points: rates.len(),
    })
}

/// The q-quantile of a sample (nearest rank), NaN when empty.
pub fn quantile(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut w = v.to_vec();
    w.sort_by(f64::total_cmp);
    let i = ((q * w.len() as f64).ceil() as usize).clamp(1, w.len()) - 1;
    w[i]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::linear::LinearSde;
    use crate::model::Bounds;
    use nalgebra::DMatrix;

    #[test]
    fn spectral_radius_of_known_matrices() {
        // rotation-scaling [[a, −b], [b, a]]: eigenvalues a ± ib
        let a = [1.5, 2.0, -2.0, 1.5];
        assert!((spectral_radius(&a, 2) - 2.5).abs() < 1e-12);
        // upper triangular: the diagonal
        let t = [-3.0, 0.0, 0.0, 7.0, 1.0, 0.0, 2.0, 5.0, -9.5];
        assert!((spectral_radius(&t, 3) - 9.5).abs() < 1e-10);
    }

    #[test]
    fn linear_model_rates_are_its_eigenvalues_everywhere() {
        // dx = A x dt + F dw with eigenvalues −1 ± 4i: ρ = √17 at every
        // point; ‖FFᵀ‖ = 0.09; the default horizon is 100/√17.
        let model = LinearSde::new(
            "osc",
            DMatrix::from_row_slice(2, 2, &[-1.0, 4.0, -4.0, -1.0]),
            DMatrix::zeros(2, 0),
            DMatrix::from_row_slice(2, 2, &[0.3, 0.0, 0.0, 0.1]),
            DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            vec![0.1],
            Bounds::new_box(&[-5.0, -5.0], &[5.0, 5.0]).unwrap(),
        );
        let prior = Gaussian::diagonal(&[1.0, 0.0], &[0.3, 0.3]);
        let mut rng = crate::rng::stream(3, 0);
        let s = probe(&model, &prior, None, &mut rng).unwrap();
        let r = 17f64.sqrt();
        assert!((s.rate_median - r).abs() < 1e-6, "{s:?}");
        assert!((s.rate_p99 - r).abs() < 1e-6, "{s:?}");
        assert!((s.diffusion_median - 0.09).abs() < 1e-12, "{s:?}");
        assert!((s.horizon - PROBE_TIME_CONSTANTS / r).abs() < 1e-9);
        assert_eq!(s.points, PROBE_TRAJECTORIES * (PROBE_POINTS + 1));
    }

    #[test]
    fn lorenz_rates_exceed_the_prior_rates_on_the_attractor() {
        // The Jacobian's trace is −(σ + 1 + β) = −13.67 everywhere, the
        // sum of its eigenvalues, so ρ(x) ≥ 13.67/3 at every point: a
        // lower bound on every quantile. At the origin (an unstable
        // equilibrium, never on the attractor) ρ = 22.8 is the largest
        // rate near it; on the attractor the probe meets rates above the
        // x–y contraction σ + 1 = 11. Seeded: two probes agree exactly.
        use crate::model::lorenz::{Lorenz, LorenzParams};
        let model = Lorenz::new(LorenzParams::default()).unwrap();
        let prior = Gaussian::diagonal(&[-6.0, -6.0, 25.0], &[1.0, 1.0, 1.0]);
        let a = probe(&model, &prior, Some(2.0), &mut crate::rng::stream(1, 0)).unwrap();
        let b = probe(&model, &prior, Some(2.0), &mut crate::rng::stream(1, 0)).unwrap();
        assert_eq!(a, b);
        let trace = 10.0 + 1.0 + 8.0 / 3.0;
        assert!(a.rate_median >= trace / 3.0 - 1e-6, "{a:?}");
        assert!(a.rate_p99 > 11.0 && a.rate_p99 < 30.0, "{a:?}");
        assert!((a.diffusion_median - 1.0).abs() < 1e-12);
    }

    #[test]
    fn quantile_is_nearest_rank() {
        let v = [5.0, 1.0, 3.0, 2.0, 4.0];
        assert_eq!(quantile(&v, 0.5), 3.0);
        assert_eq!(quantile(&v, 0.99), 5.0);
        assert_eq!(quantile(&v, 0.0), 1.0);
        assert!(quantile(&[], 0.5).is_nan());
    }
}
