//! The comparators of Chen & Lai (2007) (Benveniste et al. 1987):
//! - sliding window θ̂^(W): least squares on the last `window` pairs
//!   (y_s, φ_s);
//! - forgetting factor θ̂^(F): minimiser of Σ_s p^{t−s}(y_s − θᵀφ_s)²,
//!   computed by exponentially weighted recursive least squares.
//!
//! Both start from the same N(μ, V) prior as the Bayes filter, entered as a
//! ridge term V⁻¹ (for W, scaled by 1e-6 so the window fit is least squares
//! in substance but is defined before the window has d points; for F it
//! decays as p^t like everything else), so no method gets information the
//! others lack.

use super::linalg::{cholesky, cholesky_solve, dot, mat_vec, spd_inverse, Matrix, Vector};
use super::ThetaPrior;
use crate::error::ChangepointError;

/// Least squares over a sliding window, O(d²) per step: running sums
/// Σφφᵀ and Σyφ updated by adding the new pair and removing the oldest, and
/// recomputed from the ring buffer every `window` steps against drift.
#[derive(Clone, Debug)]
pub struct SlidingWindowLs<const D: usize> {
    window: usize,
    ridge: Matrix<D>,
    ridge_rhs: Vector<D>,
    ys: Vec<f64>,
    phis: Vec<Vector<D>>,
    len: usize,
    head: usize,
    a: Matrix<D>,
    b: Vector<D>,
    since_refresh: usize,
    theta: Vector<D>,
}

impl<const D: usize> SlidingWindowLs<D> {
    /// Window of `window` ≥ 1 pairs.
    pub fn new(window: usize, prior: ThetaPrior<D>) -> Result<Self, ChangepointError> {
        if window < 1 {
            return Err(ChangepointError::TooSmall {
                name: "window",
                value: window,
                min: 1,
            });
        }
        let vinv = spd_inverse(&prior.v)
            .ok_or(ChangepointError::NotPositiveDefinite { name: "prior V" })?;
        let mut ridge = vinv;
        for row in ridge.iter_mut() {
            for x in row.iter_mut() {
                *x *= 1e-6;
            }
        }
        let ridge_rhs = mat_vec(&ridge, &prior.mu);
        Ok(Self {
            window,
            ridge,
            ridge_rhs,
            ys: vec![0.0; window],
            phis: vec![[0.0; D]; window],
            len: 0,
            head: 0,
            a: [[0.0; D]; D],
            b: [0.0; D],
            since_refresh: 0,
            theta: prior.mu,
        })
    }

    /// Add (y_t, φ_t); returns θ̂_t^(W).
    pub fn step(&mut self, y: f64, phi: &Vector<D>) -> Vector<D> {
        if self.len == self.window {
            let (yo, po) = (self.ys[self.head], self.phis[self.head]);
            accumulate(&mut self.a, &mut self.b, &po, yo, -1.0);
        } else {
            self.len += 1;
        }
        self.ys[self.head] = y;
        self.phis[self.head] = *phi;
        self.head = (self.head + 1) % self.window;
        accumulate(&mut self.a, &mut self.b, phi, y, 1.0);
        self.since_refresh += 1;
        if self.since_refresh >= self.window {
            self.since_refresh = 0;
            self.a = [[0.0; D]; D];
            self.b = [0.0; D];
            for i in 0..self.len {
                accumulate(&mut self.a, &mut self.b, &self.phis[i], self.ys[i], 1.0);
            }
        }
        let mut m = self.a;
        let mut rhs = self.b;
        for i in 0..D {
            rhs[i] += self.ridge_rhs[i];
            for j in 0..D {
                m[i][j] += self.ridge[i][j];
            }
        }
        if let Some(l) = cholesky(&m) {
            self.theta = cholesky_solve(&l, &rhs);
        }
        self.theta
    }

    /// The current estimate.
    pub fn estimate(&self) -> Vector<D> {
        self.theta
    }
}

fn accumulate<const D: usize>(
    a: &mut Matrix<D>,
    b: &mut Vector<D>,
    phi: &Vector<D>,
    y: f64,
    sign: f64,
) {
    for i in 0..D {
        b[i] += sign * y * phi[i];
        for j in 0..D {
            a[i][j] += sign * phi[i] * phi[j];
        }
    }
}

/// Exponentially weighted recursive least squares with forgetting factor p:
/// k = Pφ/(p + φᵀPφ), θ ← θ + k(y − φᵀθ), P ← (P − kφᵀP)/p.
#[derive(Clone, Debug)]
pub struct ForgettingRls<const D: usize> {
    p: f64,
    theta: Vector<D>,
    cov: Matrix<D>,
}

impl<const D: usize> ForgettingRls<D> {
    /// Forgetting factor p in (0, 1].
    pub fn new(p: f64, prior: ThetaPrior<D>) -> Result<Self, ChangepointError> {
        if !(p > 0.0 && p <= 1.0) {
            return Err(ChangepointError::Probability {
                name: "forgetting factor",
                value: p,
            });
        }
        Ok(Self {
            p,
            theta: prior.mu,
            cov: prior.v,
        })
    }

    /// Add (y_t, φ_t); returns θ̂_t^(F).
    pub fn step(&mut self, y: f64, phi: &Vector<D>) -> Vector<D> {
        let pphi = mat_vec(&self.cov, phi);
        let den = self.p + dot(phi, &pphi);
        let r = y - dot(phi, &self.theta);
        for i in 0..D {
            self.theta[i] += pphi[i] / den * r;
        }
        for i in 0..D {
            for j in 0..D {
                self.cov[i][j] = (self.cov[i][j] - pphi[i] * pphi[j] / den) / self.p;
            }
        }
        self.theta
    }

    /// The current estimate.
    pub fn estimate(&self) -> Vector<D> {
        self.theta
    }
}
