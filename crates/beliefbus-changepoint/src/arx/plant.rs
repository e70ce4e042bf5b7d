//! A simulator of the change-point ARX model (13): θ_t jumps with
//! probability ρ for t ≥ t₀ + 1 to a draw from N(μ, V), optionally
//! restricted to the stability region Σ_i |a_i| < 1 of the AR part (the
//! paper's "|a₁| + |a₂| < 1" for k = 2; drawn by rejection). The noise is
//! ε_t ~ N(0, 1).

use super::linalg::{cholesky, dot, Matrix, Vector};
use super::{Regressor, ThetaPrior};
use crate::error::ChangepointError;
use rand::{Rng, RngExt};
use rand_distr::{Distribution, StandardNormal};

/// Where θ is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ThetaRegion {
    /// N(μ, V) restricted to Σ|a_i| < 1.
    StableAr,
    /// N(μ, V) unrestricted.
    Any,
}

/// The plant: true θ_t, lags and its own noise generator.
#[derive(Clone, Debug)]
pub struct ArxPlant<const D: usize> {
    prior: ThetaPrior<D>,
    chol: Matrix<D>,
    region: ThetaRegion,
    rho: f64,
    t0: u64,
    t: u64,
    theta: Vector<D>,
    reg: Regressor<D>,
}

impl<const D: usize> ArxPlant<D> {
    /// A plant with AR order k (input order D − k), change rate ρ, θ law
    /// `prior` on `region`; θ_1 is drawn now.
    pub fn new<R: Rng + ?Sized>(
        k: usize,
        rho: f64,
        prior: ThetaPrior<D>,
        region: ThetaRegion,
        rng: &mut R,
    ) -> Result<Self, ChangepointError> {
        crate::meanshift::check_probability("rho", rho)?;
        let reg = Regressor::new(k)?;
        let chol =
            cholesky(&prior.v).ok_or(ChangepointError::NotPositiveDefinite { name: "prior V" })?;
        let h = D - k;
        let mut p = Self {
            prior,
            chol,
            region,
            rho,
            t0: (k.max(h) + 1) as u64,
            t: 0,
            theta: prior.mu,
            reg,
        };
        p.theta = p.draw(rng);
        Ok(p)
    }

    fn draw<R: Rng + ?Sized>(&self, rng: &mut R) -> Vector<D> {
        loop {
            let mut z = [0.0; D];
            for zi in z.iter_mut() {
                *zi = StandardNormal.sample(rng);
            }
            let mut th = self.prior.mu;
            for i in 0..D {
                for j in 0..=i {
                    th[i] += self.chol[i][j] * z[j];
                }
            }
            let ar: f64 = th[..self.reg.k()].iter().map(|a| a.abs()).sum();
            if self.region == ThetaRegion::Any || ar < 1.0 {
                return th;
            }
        }
    }

    /// Produce y_t (t = 1, 2, …) from the current regressor; returns
    /// (y_t, φ_t, θ_t, whether θ jumped at t). Then call [`Self::apply`]
    /// with u_t.
    pub fn observe<R: Rng + ?Sized>(&mut self, rng: &mut R) -> (f64, Vector<D>, Vector<D>, bool) {
        self.t += 1;
        let mut jumped = false;
        if self.t > self.t0 && rng.random::<f64>() < self.rho {
            self.theta = self.draw(rng);
            jumped = true;
        }
        let phi = *self.reg.phi();
        let e: f64 = StandardNormal.sample(rng);
        let y = dot(&self.theta, &phi) + e;
        (y, phi, self.theta, jumped)
    }

    /// Apply u_t: φ_{t+1} = (−y_t, …, u_t, …).
    pub fn apply(&mut self, y: f64, u: f64) {
        self.reg.push(y, u);
    }

    /// t₀ = max(k, h) + 1: the first step the filters use.
    pub fn t0(&self) -> u64 {
        self.t0
    }

    /// The current regressor (φ_{t+1} after `apply`).
    pub fn phi(&self) -> &Vector<D> {
        self.reg.phi()
    }

    /// The current true θ_t.
    pub fn theta(&self) -> &Vector<D> {
        &self.theta
    }
}
