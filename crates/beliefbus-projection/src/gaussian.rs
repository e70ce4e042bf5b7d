//! The Gaussian family N(m, Σ) in any dimension d, the family the paper
//! uses (§VI). Sufficient statistics c(x) = (x_i, x_i x_j for i ≤ j), so
//! moment matching (eq. 14) is closed form:
//!
//! ```text
//! m̂ = Σ_i w_i x_i,        Σ̂ = Σ_i w_i (x_i − m̂)(x_i − m̂)ᵀ
//! ```
//!
//! (the centred two-pass form of Σ w x xᵀ − m̂ m̂ᵀ: it cannot go negative
//! through cancellation). Sampling is x = m̂ + L z, z ~ N(0, I), with L the
//! lower Cholesky factor of Σ̂.
//!
//! **Degenerate projections.** When the particles collapse (all equal, or
//! lying in a subspace) Σ̂ is only positive semi-definite and a plain
//! Cholesky fails. The factorisation here is the semi-definite one: a pivot
//! at or below `rel_tol · max_j Σ̂_jj` (or below `(rel_tol · max_i |m̂_i|)²`,
//! the rounding level of identical particles) marks a direction with no
//! variance left, its column of L is set to zero, and draws along it equal the mean.
//! Σ̂ = 0 is the point mass at m̂ (the std = 0 row of the paper's grid).

use crate::family::ExpFamily;
use crate::rng::SimRng;
use crate::ProjectionError;
use nalgebra::{DMatrix, DVector};
use rand::RngExt;
use rand_distr::StandardNormal;

/// The Gaussian family in dimension `d`.
#[derive(Clone, Debug)]
pub struct Gaussian {
    d: usize,
    rel_tol: f64,
}

/// A member N(mean, cov) with the (semi-definite) Cholesky factor of cov.
#[derive(Clone, Debug, PartialEq)]
pub struct GaussianParams {
    pub mean: DVector<f64>,
    pub cov: DMatrix<f64>,
    /// Lower-triangular L with L Lᵀ = cov; zero columns along degenerate
    /// directions.
    pub chol: DMatrix<f64>,
    /// The number of non-degenerate directions (d for a proper Gaussian,
    /// 0 for a point mass).
    pub rank: usize,
}

impl GaussianParams {
    /// Standard deviation of component i.
    pub fn std(&self, i: usize) -> f64 {
        self.cov[(i, i)].max(0.0).sqrt()
    }
}

impl Gaussian {
    /// Default relative tolerance below which a Cholesky pivot counts as a
    /// degenerate direction: roughly where rounding of the d² sums
    /// dominates the variance.
    pub const DEFAULT_REL_TOL: f64 = 1e-12;

    /// The Gaussian family on R^d.
    pub fn new(d: usize) -> Result<Self, ProjectionError> {
        if d == 0 {
            return Err(ProjectionError::invalid(
                "state dimension",
                "must be at least 1",
            ));
        }
        Ok(Self {
            d,
            rel_tol: Self::DEFAULT_REL_TOL,
        })
    }

    /// Set the degenerate-direction tolerance (relative to the largest
    /// variance).
    pub fn with_rel_tol(mut self, rel_tol: f64) -> Result<Self, ProjectionError> {
        if !(0.0..1.0).contains(&rel_tol) {
            return Err(ProjectionError::invalid(
                "rel_tol",
                format!("{rel_tol} not in [0, 1)"),
            ));
        }
        self.rel_tol = rel_tol;
        Ok(self)
    }

    /// N(mean, cov) with cov checked symmetric and positive semi-definite.
    pub fn params(&self, mean: &[f64], cov: &[f64]) -> Result<GaussianParams, ProjectionError> {
        ProjectionError::check_len("mean", self.d, mean.len())?;
        ProjectionError::check_len("covariance", self.d * self.d, cov.len())?;
        let mut p = self.new_params();
        p.mean.copy_from_slice(mean);
        for i in 0..self.d {
            for j in 0..self.d {
                let v = cov[i * self.d + j];
                if !v.is_finite() || (v - cov[j * self.d + i]).abs() > 1e-12 * (1.0 + v.abs()) {
                    return Err(ProjectionError::invalid(
                        "covariance",
                        "not finite and symmetric",
                    ));
                }
                p.cov[(i, j)] = v;
            }
        }
        if mean.iter().any(|m| !m.is_finite()) {
            return Err(ProjectionError::invalid("mean", "not finite"));
        }
        self.factor(&mut p)?;
        Ok(p)
    }

    /// Semi-definite Cholesky of `p.cov` into `p.chol` (see module docs).
    fn factor(&self, p: &mut GaussianParams) -> Result<(), ProjectionError> {
        let d = self.d;
        let max_diag = (0..d).map(|i| p.cov[(i, i)]).fold(0.0, f64::max);
        // Below either floor a pivot is rounding noise: relative to the
        // largest variance, or (when every variance is itself rounding
        // noise, e.g. identical particles whose weighted mean rounds) to
        // the squared size of the mean.
        let max_mean = p.mean.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let tol = (self.rel_tol * max_diag).max((self.rel_tol * max_mean).powi(2));
        p.chol.fill(0.0);
        p.rank = 0;
        for j in 0..d {
            let mut pivot = p.cov[(j, j)];
            for k in 0..j {
                pivot -= p.chol[(j, k)] * p.chol[(j, k)];
            }
            if pivot < -1e-8 * max_diag.max(f64::MIN_POSITIVE) {
                return Err(ProjectionError::invalid(
                    "covariance",
                    format!("not positive semi-definite (pivot {pivot:.3e} at {j})"),
                ));
            }
            if pivot <= tol {
                continue; // degenerate direction: column j stays zero
            }
            let ljj = pivot.sqrt();
            p.chol[(j, j)] = ljj;
            p.rank += 1;
            for i in j + 1..d {
                let mut s = p.cov[(i, j)];
                for k in 0..j {
                    s -= p.chol[(i, k)] * p.chol[(j, k)];
                }
                p.chol[(i, j)] = s / ljj;
            }
        }
        Ok(())
    }
}

impl ExpFamily for Gaussian {
    type Params = GaussianParams;

    fn name(&self) -> &'static str {
        "gaussian"
    }

    fn state_dim(&self) -> usize {
        self.d
    }

    fn new_params(&self) -> GaussianParams {
        GaussianParams {
            mean: DVector::zeros(self.d),
            cov: DMatrix::zeros(self.d, self.d),
            chol: DMatrix::zeros(self.d, self.d),
            rank: 0,
        }
    }

    fn num_stats(&self) -> usize {
        self.d + self.d * (self.d + 1) / 2
    }

    fn stats(&self, x: &[f64], out: &mut [f64]) {
        let d = self.d;
        out[..d].copy_from_slice(&x[..d]);
        let mut k = d;
        for i in 0..d {
            for j in i..d {
                out[k] = x[i] * x[j];
                k += 1;
            }
        }
    }

    fn expected_stats(&self, p: &GaussianParams, out: &mut [f64]) {
        let d = self.d;
        for i in 0..d {
            out[i] = p.mean[i];
        }
        let mut k = d;
        for i in 0..d {
            for j in i..d {
                out[k] = p.cov[(i, j)] + p.mean[i] * p.mean[j];
                k += 1;
            }
        }
    }

    fn project(
        &self,
        particles: &[f64],
        weights: &[f64],
        out: &mut GaussianParams,
    ) -> Result<(), ProjectionError> {
        let d = self.d;
        let n = weights.len();
        if n == 0 {
            return Err(ProjectionError::invalid("particles", "none to project"));
        }
        ProjectionError::check_len("particles", n * d, particles.len())?;
        out.mean.fill(0.0);
        for (x, &w) in particles.chunks_exact(d).zip(weights) {
            for i in 0..d {
                out.mean[i] += w * x[i];
            }
        }
        if out.mean.iter().any(|m| !m.is_finite()) {
            return Err(ProjectionError::invalid(
                "particles",
                "non-finite state or weight",
            ));
        }
        out.cov.fill(0.0);
        for (x, &w) in particles.chunks_exact(d).zip(weights) {
            for i in 0..d {
                let di = x[i] - out.mean[i];
                for j in 0..=i {
                    out.cov[(i, j)] += w * di * (x[j] - out.mean[j]);
                }
            }
        }
        for i in 0..d {
            for j in 0..i {
                out.cov[(j, i)] = out.cov[(i, j)];
            }
        }
        self.factor(out)
    }

    fn sample(&self, p: &GaussianParams, rng: &mut SimRng, x: &mut [f64]) {
        let d = self.d;
        for z in x[..d].iter_mut() {
            *z = rng.sample(StandardNormal);
        }
        // x = m + L z in place: row i of L only reads z_0..z_i, so going
        // downwards never reads an already overwritten entry.
        for i in (0..d).rev() {
            let mut v = p.mean[i];
            for j in 0..=i {
                v += p.chol[(i, j)] * x[j];
            }
            x[i] = v;
        }
    }

    fn grid_dim(&self) -> usize {
        2 * self.d
    }

    fn grid_coords(&self, p: &GaussianParams, out: &mut [f64]) {
        for i in 0..self.d {
            out[i] = p.mean[i];
            out[self.d + i] = p.std(i);
        }
    }

    /// Grid coordinates (means, standard deviations) define a Gaussian with
    /// diagonal covariance: the grid spans marginal spreads only.
    fn params_from_grid(
        &self,
        coords: &[f64],
        out: &mut GaussianParams,
    ) -> Result<(), ProjectionError> {
        ProjectionError::check_len("grid coordinates", 2 * self.d, coords.len())?;
        if coords.iter().any(|c| !c.is_finite()) || coords[self.d..].iter().any(|&s| s < 0.0) {
            return Err(ProjectionError::invalid(
                "grid coordinates",
                format!("{coords:?}: means must be finite, stds finite and >= 0"),
            ));
        }
        out.cov.fill(0.0);
        for i in 0..self.d {
            out.mean[i] = coords[i];
            out.cov[(i, i)] = coords[self.d + i] * coords[self.d + i];
        }
        self.factor(out)
    }
}
