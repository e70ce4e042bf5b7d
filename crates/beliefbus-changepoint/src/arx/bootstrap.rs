//! The bootstrap particle filter on θ_t for the change-point ARX model
//! (Gordon et al. 1993): propagate each θ^(j) by the prior transition
//! (keep it with probability 1 − ρ, else draw N(μ, V)), weight by
//! N(y_t; θ^(j)ᵀφ_t, 1) and resample every step. The baseline that neither
//! adapts its proposal to y_t nor integrates θ out; it compares per-step
//! cost at equal M with the fast filter ([`super::rbpf`]). Nothing
//! allocates after construction.

use super::linalg::{cholesky, dot, Matrix, Vector};
use super::ThetaPrior;
use crate::error::ChangepointError;
use crate::resample::{gather, resample, Scheme};
use crate::rng::SimRng;
use crate::weights::{log_normal_pdf, normalise};
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};

/// Bootstrap PF with preallocated buffers.
#[derive(Clone, Debug)]
pub struct ArxBootstrap<const D: usize> {
    mu: Vector<D>,
    chol: Matrix<D>,
    rho: f64,
    scheme: Scheme,
    theta: Vec<Vector<D>>,
    logw: Vec<f64>,
    w: Vec<f64>,
    anc: Vec<usize>,
    scratch_f: Vec<f64>,
    scratch_th: Vec<Vector<D>>,
    started: bool,
    rng: SimRng,
}

impl<const D: usize> ArxBootstrap<D> {
    /// M particles, change rate ρ, θ law `prior`.
    pub fn new(
        prior: ThetaPrior<D>,
        rho: f64,
        particles: usize,
        scheme: Scheme,
        rng: SimRng,
    ) -> Result<Self, ChangepointError> {
        let prior = ThetaPrior::new(prior.mu, prior.v)?;
        crate::meanshift::check_probability("rho", rho)?;
        if particles < 1 {
            return Err(ChangepointError::TooSmall {
                name: "particles",
                value: particles,
                min: 1,
            });
        }
        let chol =
            cholesky(&prior.v).ok_or(ChangepointError::NotPositiveDefinite { name: "prior V" })?;
        Ok(Self {
            mu: prior.mu,
            chol,
            rho,
            scheme,
            theta: vec![prior.mu; particles],
            logw: vec![0.0; particles],
            w: vec![0.0; particles],
            anc: vec![0; particles],
            scratch_f: vec![0.0; particles],
            scratch_th: vec![prior.mu; particles],
            started: false,
            rng,
        })
    }

    fn draw(&mut self) -> Vector<D> {
        let mut th = self.mu;
        let z: [f64; D] = std::array::from_fn(|_| StandardNormal.sample(&mut self.rng));
        for i in 0..D {
            for j in 0..=i {
                th[i] += self.chol[i][j] * z[j];
            }
        }
        th
    }

    /// Assimilate (y_t, φ_t) (the first call is t₀, where every particle
    /// is a fresh draw); returns the weighted mean of θ_t.
    pub fn step(&mut self, y: f64, phi: &Vector<D>) -> Result<Vector<D>, ChangepointError> {
        if !y.is_finite() || phi.iter().any(|v| !v.is_finite()) {
            return Err(ChangepointError::NonFinite {
                name: "y or phi",
                value: y,
            });
        }
        for j in 0..self.theta.len() {
            if !self.started || self.rng.random::<f64>() < self.rho {
                self.theta[j] = self.draw();
            }
            self.logw[j] = log_normal_pdf(y, dot(&self.theta[j], phi), 1.0);
        }
        self.started = true;
        if !normalise(&self.logw, &mut self.w).is_finite() {
            return Err(ChangepointError::WeightsVanished { step: 0 });
        }
        let mut est = [0.0; D];
        for (w, th) in self.w.iter().zip(&self.theta) {
            for i in 0..D {
                est[i] += w * th[i];
            }
        }
        resample(
            self.scheme,
            &self.w,
            &mut self.rng,
            &mut self.anc,
            &mut self.scratch_f,
        );
        gather(&mut self.theta, &mut self.scratch_th, &self.anc);
        Ok(est)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arx::rbpf::{ArxRbpf, ArxRbpfConfig};
    use crate::rng::stream;

    /// Over the first steps (no change-point, ρ tiny) both filters target
    /// the Kalman posterior of θ; the RBPF is that posterior exactly, the
    /// bootstrap's estimate with M = 20000 lies within 0.05 of it.
    #[test]
    fn it_targets_the_same_posterior_as_the_fast_filter() {
        let prior = ThetaPrior::<3>::standard();
        let mut b =
            ArxBootstrap::new(prior, 1e-6, 20_000, Scheme::Systematic, stream(1, 1)).unwrap();
        let cfg = ArxRbpfConfig {
            rho: 1e-6,
            ..ArxRbpfConfig::default()
        };
        let mut r = ArxRbpf::new(prior, cfg, stream(1, 2)).unwrap();
        let mut data = stream(1, 3);
        let theta = [-0.4, 0.3, 0.8];
        let (mut y1, mut y2, mut u1) = (0.5, -0.2, 1.0);
        for _ in 0..6 {
            let phi = [-y1, -y2, u1];
            let e: f64 = StandardNormal.sample(&mut data);
            let y = dot(&theta, &phi) + e;
            let eb = b.step(y, &phi).unwrap();
            let er = r.step(y, &phi).unwrap();
            for i in 0..3 {
                assert!((eb[i] - er[i]).abs() < 0.05, "{eb:?} vs {er:?}");
            }
            let u: f64 = StandardNormal.sample(&mut data);
            (y2, y1, u1) = (y1, y, u);
        }
    }
}
