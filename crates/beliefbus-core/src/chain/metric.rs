//! An anisotropic metric for chains of degenerate diffusions: the model
//! seen in scaled coordinates x' = S x, S = diag(s),
//!
//! ```text
//! dx' = S f(S⁻¹x', u) dt + S F(S⁻¹x') dw,     y = g(S⁻¹x') + v
//! ```
//!
//! A chain built on the scaled model takes its Near sets, radii and
//! holding times in the metric ‖S Δx‖. With s = λ > 1 on the noise-free
//! coordinates, the neighbours' spacing there is 1/λ of the noisy
//! coordinates', so the numerical diffusion of the degenerate kernel
//! ([`super::degenerate`]) falls as 1/λ² (see
//! `docs/degenerate-chains.md` for the rate at which λ may grow with n
//! while the chain stays locally consistent). Estimates come out in scaled
//! coordinates: [`ScaledCoords::unscale`] maps them back.

use crate::model::{Bounds, BoundsError, Dims, SdeJacobians, SdeModel};
use crate::{MAX_NOISE, MAX_STATE};

/// A model in the coordinates x' = diag(s) x.
#[derive(Clone, Debug)]
pub struct ScaledCoords<M> {
    pub inner: M,
    scale: [f64; MAX_STATE],
    bounds: Bounds,
    name: String,
}

/// Why a scaling was refused.
#[derive(Debug, thiserror::Error)]
pub enum MetricError {
    #[error("metric: one positive finite scale per state coordinate expected")]
    Scale,
    #[error("metric: a disc constraint needs equal scales on its two axes")]
    Disc,
    #[error(transparent)]
    Bounds(#[from] BoundsError),
}

impl<M: SdeModel> ScaledCoords<M> {
    /// `inner` seen in x' = diag(`scale`) x.
    pub fn new(inner: M, scale: &[f64]) -> Result<Self, MetricError> {
        let d = inner.dims().state;
        if scale.len() != d || scale.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(MetricError::Scale);
        }
        let b = inner.bounds();
        let lo: Vec<f64> = (0..d).map(|i| b.lo()[i] * scale[i]).collect();
        let hi: Vec<f64> = (0..d).map(|i| b.hi()[i] * scale[i]).collect();
        let mut bounds = Bounds::new_box(&lo, &hi)?;
        if let Some(disc) = b.disc() {
            let (a, c) = disc.axes;
            if scale[a] != scale[c] {
                return Err(MetricError::Disc);
            }
            bounds = bounds.with_disc(disc.axes, disc.radius * scale[a])?;
        }
        let mut s = [1.0; MAX_STATE];
        s[..d].copy_from_slice(scale);
        let name = format!("{}-scaled", inner.name());
        Ok(Self {
            inner,
            scale: s,
            bounds,
            name,
        })
    }

    /// The scales s.
    pub fn scale(&self) -> &[f64] {
        &self.scale[..self.inner.dims().state]
    }

    /// x = S⁻¹ x' in place.
    pub fn unscale(&self, x: &mut [f64]) {
        for (v, s) in x.iter_mut().zip(&self.scale) {
            *v /= s;
        }
    }

    /// x' = S x in place.
    pub fn rescale(&self, x: &mut [f64]) {
        for (v, s) in x.iter_mut().zip(&self.scale) {
            *v *= s;
        }
    }

    fn to_inner(&self, x: &[f64]) -> [f64; MAX_STATE] {
        let mut y = [0.0; MAX_STATE];
        for i in 0..x.len() {
            y[i] = x[i] / self.scale[i];
        }
        y
    }
}

impl<M: SdeModel> SdeModel for ScaledCoords<M> {
    fn name(&self) -> &str {
        &self.name
    }
    fn dims(&self) -> Dims {
        self.inner.dims()
    }
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
        let y = self.to_inner(x);
        self.inner.drift(&y[..x.len()], u, f);
        for (v, s) in f.iter_mut().zip(&self.scale) {
            *v *= s;
        }
    }
    fn diffusion(&self, x: &[f64], big_f: &mut [f64]) {
        let d = x.len();
        let y = self.to_inner(x);
        self.inner.diffusion(&y[..d], big_f);
        // F is d × k column-major.
        let k = self.inner.dims().noise;
        debug_assert!(k <= MAX_NOISE);
        for j in 0..k {
            for i in 0..d {
                big_f[i + j * d] *= self.scale[i];
            }
        }
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        let y = self.to_inner(x);
        self.inner.obs_mean(&y[..x.len()], g)
    }
    fn obs_std(&self, std: &mut [f64]) {
        self.inner.obs_std(std)
    }
    fn obs_residual(&self, y: &[f64], yhat: &[f64], r: &mut [f64]) {
        self.inner.obs_residual(y, yhat, r)
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

/// Chain rule: ∂f'/∂x' = S (∂f/∂x) S⁻¹, ∂g/∂x' = (∂g/∂x) S⁻¹.
impl<M: SdeJacobians> SdeJacobians for ScaledCoords<M> {
    fn drift_jacobian(&self, x: &[f64], u: &[f64], jac: &mut [f64]) {
        let d = x.len();
        let y = self.to_inner(x);
        self.inner.drift_jacobian(&y[..d], u, jac);
        for c in 0..d {
            for r in 0..d {
                jac[r + c * d] *= self.scale[r] / self.scale[c];
            }
        }
    }
    fn obs_jacobian(&self, x: &[f64], jac: &mut [f64]) {
        let d = x.len();
        let m = self.inner.dims().obs;
        let y = self.to_inner(x);
        self.inner.obs_jacobian(&y[..d], jac);
        for c in 0..d {
            for r in 0..m {
                jac[r + c * m] /= self.scale[c];
            }
        }
    }
}

/// Scale λ of the noise-free coordinates for a chain of `n` states in
/// dimension `d` with `d_free` noise-free coordinates:
/// λ = [`SCALE_CONSTANT`] · n^{1/(2d + d_free)}, the rate that balances the
/// degenerate kernel's numerical diffusion (∝ 1/λ²) against the noisy
/// coordinates' spacing (∝ (λ^{d_free}/n)^{1/d}); see
/// `docs/degenerate-chains.md`.
pub fn degenerate_scale(n: usize, d: usize, d_free: usize) -> f64 {
    SCALE_CONSTANT * (n.max(1) as f64).powf(1.0 / (2 * d + d_free) as f64)
}

/// The constant of [`degenerate_scale`], measured on the damped double
/// integrator (advected chains, gap to Kalman: λ = 4 was the best of
/// λ ∈ {1, 2, 4, 8} at n = 500 and 8000, within 3 % of λ = 8 at 2000).
pub const SCALE_CONSTANT: f64 = 1.0;
