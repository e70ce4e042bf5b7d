//! Regularised resampling (Musso, Oudjane & Le Gland 2001, "Improving
//! regularised particle filters", in Doucet, de Freitas & Gordon,
//! *Sequential Monte Carlo Methods in Practice*, ch. 12) and the count of
//! collapsed steps shared by the particle and chain filters.
//!
//! **Kernel jitter.** After resampling, every particle is moved by a draw
//! from a Gaussian kernel scaled by the weighted empirical covariance S of
//! the particles *before* resampling (S = L Lᵀ):
//!
//! ```text
//! x⁽ⁱ⁾ ← x⁽ⁱ⁾ + c · h_opt · L ε,   ε ~ N(0, I_d)
//! h_opt = A · N^{−1/(d+4)},   A = (4 / (d + 2))^{1/(d+4)}
//! ```
//!
//! h_opt minimises the mean integrated squared error of the kernel density
//! estimate when the density is Gaussian with covariance S (the Gaussian
//! kernel's optimal bandwidth, Musso et al. eq. 12.13); c is the configured
//! factor (`regularisation`, 0 = off). Duplicated particles after a
//! collapse become distinct again, at the price of a variance inflation of
//! (c h_opt)² S, which vanishes as N grows. S is factored semi-definitely,
//! so a coordinate on which every particle agrees (a noise-free state
//! component, or a single surviving ancestor) is not jittered.
//!
//! **Collapse.** A step *collapses* when the reweighting by the likelihood
//! leaves fewer than a fraction f of the effective support it had:
//!
//! ```text
//! ρ = (Σ_i φ_i L_i)² / (Σ_i φ_i · Σ_i φ_i L_i²)  <  f      (f = 1 % by default)
//! ```
//!
//! with φ the predicted weights and L the likelihood. For a particle filter
//! whose predicted weights are equal (after a resampling) ρ = ESS / N, the
//! ESS of the updated weights as a fraction of the particle count; the PF
//! counts ESS (before resampling) < max(f·N, 2), the usual reading (the
//! floor of two effective particles makes the count meaningful for
//! N < 1/f, where f·N < 1 ≤ ESS would never trigger). For the chain
//! filter, φ is the predicted mass over the chain's states: ρ does not
//! depend on how finely the chain resolves the belief (1/ρ − 1 is the χ²
//! divergence of the posterior from the prior), so one threshold serves
//! both filters. An update whose weights all vanish or are not finite (the
//! observation is impossible under every particle or state with mass)
//! collapses too. A collapse is counted, not refused: the filter's stats
//! and the run report say how many steps collapsed.

use crate::math::linalg::cholesky_psd;
use crate::rng::SimRng;
use crate::MAX_STATE;
use rand::RngExt;
use rand_distr::StandardNormal;

/// Default collapse threshold f (see the module doc): an update that keeps
/// less than 1 % of the effective support it had.
pub const DEFAULT_COLLAPSE_FRACTION: f64 = 0.01;

/// The ESS below which a PF update of `n` particles collapsed: f·n, but
/// at least 2 (fewer than two effective particles is a collapse whatever
/// N; f·n alone would never trigger below N = 1/f); 0 when f = 0 (only
/// vanished weights count).
pub fn collapse_threshold(fraction: f64, n: usize) -> f64 {
    if fraction > 0.0 {
        (fraction * n as f64).max(2.0)
    } else {
        0.0
    }
}

/// The Gaussian kernel's optimal bandwidth h_opt = A · N^{−1/(d+4)},
/// A = (4/(d+2))^{1/(d+4)}, for N particles in d dimensions.
pub fn optimal_bandwidth(n: usize, d: usize) -> f64 {
    let d = d as f64;
    let e = 1.0 / (d + 4.0);
    (4.0 / (d + 2.0)).powf(e) * (n.max(1) as f64).powf(-e)
}

/// The lower factor L (column-major, d × d, L Lᵀ = S) of the weighted
/// covariance S = Σ wᵢ (xᵢ − m)(xᵢ − m)ᵀ of particle-major `x` with
/// normalised weights `w`, into `l`. Semi-definite: a zero-variance
/// direction gets a zero column. Returns false when S is not finite.
pub fn weighted_cov_factor(x: &[f64], w: &[f64], d: usize, l: &mut [f64]) -> bool {
    let mut mean = [0.0; MAX_STATE];
    for (xi, &wi) in x.chunks_exact(d).zip(w) {
        if wi > 0.0 {
            for r in 0..d {
                mean[r] += wi * xi[r];
            }
        }
    }
    let l = &mut l[..d * d];
    l.fill(0.0);
    for (xi, &wi) in x.chunks_exact(d).zip(w) {
        if wi > 0.0 {
            for c in 0..d {
                let wc = wi * (xi[c] - mean[c]);
                for r in c..d {
                    l[r + c * d] += wc * (xi[r] - mean[r]);
                }
            }
        }
    }
    l.iter().all(|v| v.is_finite()) && cholesky_psd(l, d)
}

/// x⁽ⁱ⁾ ← x⁽ⁱ⁾ + h · L ε⁽ⁱ⁾ for every particle of particle-major `x`
/// (ε ~ N(0, I_d), L lower triangular column-major).
pub fn jitter(x: &mut [f64], d: usize, l: &[f64], h: f64, rng: &mut SimRng) {
    for xi in x.chunks_exact_mut(d) {
        let mut e = [0.0; MAX_STATE];
        for v in e[..d].iter_mut() {
            *v = rng.sample(StandardNormal);
        }
        for r in 0..d {
            let mut s = 0.0;
            for c in 0..=r {
                s += l[r + c * d] * e[c];
            }
            xi[r] += h * s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng;

    #[test]
    fn bandwidth_is_the_gaussian_kernel_formula() {
        // d = 1: A = (4/3)^{1/5} = 1.0592, h = 1.0592 N^{−1/5} (Silverman's
        // rule for a unit-variance Gaussian).
        assert!((optimal_bandwidth(1, 1) - (4.0f64 / 3.0).powf(0.2)).abs() < 1e-15);
        let h = optimal_bandwidth(100, 1);
        assert!((h - 1.0592 * 100f64.powf(-0.2)).abs() < 1e-4, "{h}");
        // d = 4: A = (4/6)^{1/8}, N^{−1/8}.
        let h4 = optimal_bandwidth(256, 4);
        assert!(
            (h4 - (2.0f64 / 3.0).powf(0.125) / 2.0).abs() < 1e-12,
            "{h4}"
        );
        // Shrinks with N.
        assert!(optimal_bandwidth(1000, 4) < optimal_bandwidth(100, 4));
    }

    #[test]
    fn covariance_factor_reproduces_the_weighted_covariance() {
        // Three particles in 2-D with weights 0.5, 0.25, 0.25.
        let x = [0.0, 0.0, 2.0, 1.0, -2.0, 1.0];
        let w = [0.5, 0.25, 0.25];
        let mut l = [0.0; 4];
        assert!(weighted_cov_factor(&x, &w, 2, &mut l));
        // mean (0, 0.5); S = [[2, 0], [0, 0.25]].
        let s = |r: usize, c: usize| (0..2).map(|k| l[r + k * 2] * l[c + k * 2]).sum::<f64>();
        assert!((s(0, 0) - 2.0).abs() < 1e-12);
        assert!(s(1, 0).abs() < 1e-12);
        assert!((s(1, 1) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn a_coordinate_every_particle_shares_is_not_jittered() {
        let mut x = [1.0, 5.0, 2.0, 5.0, 3.0, 5.0];
        let w = [1.0 / 3.0; 3];
        let mut l = [0.0; 4];
        assert!(weighted_cov_factor(&x, &w, 2, &mut l));
        let mut r = rng::stream(3, 1);
        jitter(&mut x, 2, &l, 0.5, &mut r);
        assert!(x.chunks(2).all(|p| p[1] == 5.0), "{x:?}");
        assert!(x[0] != 1.0 && x[2] != 2.0);
    }

    #[test]
    fn jitter_has_covariance_h2_s() {
        // Many copies of the origin jittered with S = [[4, 1], [1, 1]]:
        // the sample covariance is h² S within sampling error.
        let s = [4.0, 1.0, 1.0, 1.0];
        let mut l = s;
        assert!(cholesky_psd(&mut l, 2));
        let n = 40_000;
        let mut x = vec![0.0; 2 * n];
        let h = 0.3;
        jitter(&mut x, 2, &l, h, &mut rng::stream(9, 2));
        let mut c = [0.0; 4];
        for p in x.chunks(2) {
            for a in 0..2 {
                for b in 0..2 {
                    c[a + 2 * b] += p[a] * p[b] / n as f64;
                }
            }
        }
        for k in 0..4 {
            let want = h * h * s[k];
            // sd of a sample second moment ≈ h² √(2/n)·scale ≈ 0.7 % of 4h².
            assert!(
                (c[k] - want).abs() < 0.03 * h * h * 2.0,
                "{k}: {} vs {want}",
                c[k]
            );
        }
    }
}
