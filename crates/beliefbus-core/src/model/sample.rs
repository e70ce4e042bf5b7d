//! `Sample` (thesis §2.4.1; concentration heuristic of §3.3.3).
//!
//! - [`Sampler::Uniform`]: independent uniform draws on the compact set S
//!   (the papers' procedure).
//! - [`Sampler::Gaussian`]: "concentrate the samples around the estimated
//!   posterior" (§3.3.3). The thesis leaves the distribution open; here a
//!   draw is, with probability `uniform_fraction`, uniform on S, and
//!   otherwise from N(mean, cov) restricted to S (rejection, then uniform
//!   after 64 failed tries). The uniform share keeps the chain exploring so
//!   that a wrong estimated posterior is still corrected.

use crate::belief::Gaussian;
use crate::model::Bounds;
use crate::rng::SimRng;
use crate::MAX_STATE;
use rand::RngExt;
use rand_distr::StandardNormal;

use crate::math::linalg::cholesky;

/// A sampling distribution over S.
#[derive(Clone, Debug)]
#[allow(clippy::large_enum_variant)] // fixed-size on purpose: no allocation
pub enum Sampler {
    /// Uniform on S.
    Uniform,
    /// Mixture of N(mean, cov) (restricted to S) and uniform on S.
    Gaussian {
        dim: usize,
        mean: [f64; MAX_STATE],
        /// Cholesky factor of the covariance (lower, column-major dim × dim).
        chol: [f64; MAX_STATE * MAX_STATE],
        uniform_fraction: f64,
    },
}

impl Sampler {
    /// Concentrate around `belief` with covariance inflated by `inflate²`,
    /// mixed with `uniform_fraction` uniform draws. Returns `None` when the
    /// covariance is not positive definite or the fraction is outside [0, 1].
    pub fn around(belief: &Gaussian, inflate: f64, uniform_fraction: f64) -> Option<Self> {
        if !(0.0..=1.0).contains(&uniform_fraction) || !(inflate > 0.0) {
            return None;
        }
        let d = belief.dim;
        let mut chol = [0.0; MAX_STATE * MAX_STATE];
        for (c, v) in chol[..d * d].iter_mut().zip(belief.cov()) {
            *c = v * inflate * inflate;
        }
        if !cholesky(&mut chol[..d * d], d) {
            return None;
        }
        let mut mean = [0.0; MAX_STATE];
        mean[..d].copy_from_slice(belief.mean());
        Some(Sampler::Gaussian {
            dim: d,
            mean,
            chol,
            uniform_fraction,
        })
    }

    /// Draw one state into `x` (length = bounds dimension).
    pub fn sample(&self, bounds: &Bounds, rng: &mut SimRng, x: &mut [f64]) {
        match self {
            Sampler::Uniform => bounds.sample_uniform(rng, x),
            Sampler::Gaussian {
                dim,
                mean,
                chol,
                uniform_fraction,
            } => {
                let d = *dim;
                if rng.random::<f64>() < *uniform_fraction {
                    bounds.sample_uniform(rng, x);
                    return;
                }
                let mut xi = [0.0; MAX_STATE];
                for _ in 0..64 {
                    for v in xi[..d].iter_mut() {
                        *v = rng.sample::<f64, _>(StandardNormal);
                    }
                    for i in 0..d {
                        let mut s = mean[i];
                        for c in 0..=i {
                            s += chol[i + c * d] * xi[c];
                        }
                        x[i] = s;
                    }
                    if bounds.contains(x) {
                        return;
                    }
                }
                bounds.sample_uniform(rng, x);
            }
        }
    }

    /// Draw `n` states, flat n × d.
    pub fn sample_many(&self, bounds: &Bounds, n: usize, rng: &mut SimRng) -> Vec<f64> {
        let d = bounds.dim();
        let mut out = vec![0.0; n * d];
        for chunk in out.chunks_exact_mut(d) {
            self.sample(bounds, rng, chunk);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_sampler_has_the_requested_moments() {
        let b = Bounds::new_box(&[-10.0, -10.0], &[10.0, 10.0]).unwrap();
        let mut g = Gaussian::diagonal(&[1.0, -2.0], &[0.5, 0.2]);
        g.set_cov(0, 1, 0.05);
        g.set_cov(1, 0, 0.05);
        let s = Sampler::around(&g, 1.0, 0.0).unwrap();
        let mut rng = crate::rng::stream(2, 0);
        let n = 40_000;
        let pts = s.sample_many(&b, n, &mut rng);
        let mean0 = pts.chunks(2).map(|p| p[0]).sum::<f64>() / n as f64;
        let cov01 = pts
            .chunks(2)
            .map(|p| (p[0] - 1.0) * (p[1] + 2.0))
            .sum::<f64>()
            / n as f64;
        // 5σ bounds: sd(mean0) = 0.5/√n, sd(cov01) ≈ sqrt(0.25·0.04 + 0.05²)/√n
        assert!((mean0 - 1.0).abs() < 5.0 * 0.5 / (n as f64).sqrt());
        assert!((cov01 - 0.05).abs() < 5.0 * 0.11 / (n as f64).sqrt());
        // With a uniform share, some draws land far from the mean.
        let s = Sampler::around(&g, 1.0, 0.5).unwrap();
        let pts = s.sample_many(&b, 2000, &mut rng);
        let far = pts.chunks(2).filter(|p| (p[0] - 1.0).abs() > 4.0).count();
        assert!(far > 500, "{far}");
    }
}
