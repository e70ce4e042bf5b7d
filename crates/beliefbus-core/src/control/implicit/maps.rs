//! Steps 3–4 of implicit sampling (paper 003 §2.1–2.2): map a reference
//! draw ξ ~ N(0, I_N) to a sample X of p ∝ e^{−F} by solving
//! F(X) − φ = ½ ξᵀξ (eq. 1), and weight it.
//!
//! **Linear map** (§2.2, the quadratic approximation):
//! ```text
//! X = μ + L⁻ᵀ ξ,       F̂(X) − φ = ½ ξᵀξ,    F̂(x) = φ + ½ (x − μ)ᵀ H (x − μ)
//! log w = −log det L + F̂(X) − F(X)         (eq. 6 times the 1/det L of E8)
//! ```
//!
//! **Random map** (§2.1, eq. 2) with the corrected Jacobian (erratum E1):
//! ```text
//! ρ = ξᵀξ,  η = ξ/√ρ,  X = μ + λ L⁻ᵀ η,  λ > 0 solves F(μ + λ L⁻ᵀη) − φ = ½ ρ
//! |det ∂X/∂ξ| = (2/det L) ρ^{1−N/2} |λ^{N−1} dλ/dρ|,   dλ/dρ = 1 / (2 ∇F(X)·L⁻ᵀη)
//! log w = log |det ∂X/∂ξ|
//! ```
//! (the printed eq. 3/4 has ρ^{(1−N)/2} and an extra ½; it gives non-constant
//! weights even for a Gaussian F — see the tests).
//!
//! With both maps, ∫ e^{−F} dx = e^{−φ} (2π)^{N/2} E_ξ[w], so the log
//! weights returned here are directly comparable between maps and between
//! different F's (the E8 normalisation).

use super::banded::SymBand;
use super::newton::Objective;

/// X = μ + L⁻ᵀ ξ into `x`; returns ½ ξᵀξ.
pub fn linear_map(mu: &[f64], l: &SymBand, xi: &[f64], x: &mut [f64]) -> f64 {
    let n = l.dim();
    x[..n].copy_from_slice(&xi[..n]);
    l.solve_upper_in_place(&mut x[..n]);
    let mut half_rho = 0.0;
    for i in 0..n {
        x[i] += mu[i];
        half_rho += 0.5 * xi[i] * xi[i];
    }
    half_rho
}

/// Log weight of a linear-map sample: −log det L + ½ξᵀξ − (F(X) − φ).
pub fn linear_map_log_weight(half_rho: f64, f_x: f64, phi: f64, log_det_l: f64) -> f64 {
    if f_x == f64::INFINITY {
        return f64::NEG_INFINITY;
    }
    -log_det_l + half_rho - (f_x - phi)
}

/// Why a random-map sample could not be generated.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum MapError {
    #[error("F does not grow to φ + ρ/2 along the ray (not U-shaped)")]
    Unbounded,
    #[error("scalar root finding did not converge")]
    NoConvergence,
    #[error("degenerate reference draw (ξ = 0)")]
    ZeroDraw,
}

/// A random-map sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RandomMapSample {
    /// λ solving F(μ + λ L⁻ᵀη) − φ = ρ/2.
    pub lambda: f64,
    /// log |det ∂X/∂ξ| (corrected, E1).
    pub log_jacobian: f64,
    /// ∇F(X)·L⁻ᵀη, whose reciprocal halved is dλ/dρ.
    pub slope: f64,
}

/// Buffers of the random map.
#[derive(Clone, Debug)]
pub struct RandomMapWorkspace {
    dir: Vec<f64>,
    scratch: Vec<f64>,
}

impl RandomMapWorkspace {
    /// Buffers for dimension ≤ n.
    pub fn new(n: usize) -> Self {
        Self {
            dir: vec![0.0; n],
            scratch: vec![0.0; n],
        }
    }

    /// Random-map sample for the reference draw `xi`, written into `x`.
    /// `l` is the factor of the Hessian at the minimiser μ, φ = F(μ).
    /// One function: the bracketing and the safeguarded Newton refine one
    /// bracket (lo, hi) and one evaluation closure.
    pub fn sample<O: Objective + ?Sized>(
        &mut self,
        obj: &O,
        mu: &[f64],
        phi: f64,
        l: &SymBand,
        xi: &[f64],
        x: &mut [f64],
    ) -> Result<RandomMapSample, MapError> {
        let n = obj.dim();
        let rho: f64 = xi[..n].iter().map(|v| v * v).sum();
        if !(rho > 0.0) {
            return Err(MapError::ZeroDraw);
        }
        let sr = rho.sqrt();
        let dir = &mut self.dir[..n];
        for i in 0..n {
            dir[i] = xi[i] / sr;
        }
        l.solve_upper_in_place(dir); // d = L⁻ᵀ η
        let target = 0.5 * rho;
        let eval = |lam: f64, x: &mut [f64]| {
            for i in 0..n {
                x[i] = mu[i] + lam * dir[i];
            }
            obj.value(&x[..n]) - phi - target
        };
        // Bracket the root in (lo, hi), starting at √ρ (exact for quadratic F).
        let mut lo = 0.0;
        let mut hi = f64::INFINITY;
        let mut lam = sr;
        let mut g = eval(lam, x);
        for _ in 0..200 {
            if g.is_nan() {
                return Err(MapError::NoConvergence);
            }
            if g > 0.0 {
                hi = lam;
                break;
            }
            lo = lam;
            lam *= 2.0;
            g = eval(lam, x);
        }
        if hi == f64::INFINITY {
            return Err(MapError::Unbounded);
        }
        // Safeguarded Newton in λ on g(λ) = F(μ + λd) − φ − ρ/2.
        let tol = 1e-13 * target.max(1.0);
        let mut slope = 0.0;
        let mut converged = false;
        lam = hi;
        g = eval(lam, x);
        for _ in 0..100 {
            if g.is_finite() {
                slope = obj.directional(&x[..n], dir, &mut self.scratch);
                if g.abs() <= tol {
                    converged = true;
                    break;
                }
            }
            if g > 0.0 {
                hi = lam;
            } else {
                lo = lam;
            }
            let newton = if g.is_finite() && slope > 0.0 {
                lam - g / slope
            } else {
                f64::NAN
            };
            lam = if newton > lo && newton < hi {
                newton
            } else {
                0.5 * (lo + hi)
            };
            g = eval(lam, x);
            if hi - lo <= 1e-15 * hi {
                slope = obj.directional(&x[..n], dir, &mut self.scratch);
                converged = g.is_finite();
                break;
            }
        }
        if !converged || !(slope > 0.0) {
            return Err(MapError::NoConvergence);
        }
        let nf = n as f64;
        let log_jacobian =
            -l.log_det_factor() + (1.0 - 0.5 * nf) * rho.ln() + (nf - 1.0) * lam.ln() - slope.ln();
        Ok(RandomMapSample {
            lambda: lam,
            log_jacobian,
            slope,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::newton::{DenseObjective, NewtonOptions, NewtonWorkspace};
    use super::super::weights;
    use super::*;
    use rand::RngExt;
    use rand_distr::StandardNormal;

    /// The printed eq. (3): ρ^{(1−m)/2} |λ^{m−1} / (2 ∇F L⁻ᵀη)| / det L.
    fn printed_log_jacobian(s: &RandomMapSample, rho: f64, n: usize, log_det_l: f64) -> f64 {
        let m = n as f64;
        -log_det_l + 0.5 * (1.0 - m) * rho.ln() + (m - 1.0) * s.lambda.ln() - (2.0 * s.slope).ln()
    }

    fn gaussian(n: usize) -> impl Objective {
        // F = ½ xᵀ A x with A tridiagonal SPD, plus a constant.
        DenseObjective {
            n,
            value: move |x: &[f64]| {
                let mut f = 3.0;
                for i in 0..x.len() {
                    f += 0.5 * 2.0 * x[i] * x[i];
                    if i > 0 {
                        f += 0.6 * x[i] * x[i - 1];
                    }
                }
                f
            },
            derivatives: move |x: &[f64], g: &mut [f64], h: &mut SymBand| {
                let k = x.len();
                let mut f = 3.0;
                for i in 0..k {
                    f += x[i] * x[i];
                    g[i] = 2.0 * x[i];
                    h.add(i, i, 2.0);
                    if i > 0 {
                        f += 0.6 * x[i] * x[i - 1];
                        g[i] += 0.6 * x[i - 1];
                        g[i - 1] += 0.6 * x[i];
                        h.add(i, i - 1, 0.6);
                    }
                }
                f
            },
        }
    }

    /// Acceptance test: for Gaussian F the random-map weights are constant
    /// (= 1/det L), with the corrected Jacobian; the printed one varies.
    #[test]
    fn random_map_weights_are_constant_for_gaussian_f() {
        let n = 5;
        let obj = gaussian(n);
        let mut ws = NewtonWorkspace::new(n, n - 1);
        let mut mu = vec![0.3; n];
        let r = ws
            .minimise(&obj, &mut mu, &NewtonOptions::default())
            .unwrap();
        let log_det_l = ws.l.log_det_factor();
        let mut rm = RandomMapWorkspace::new(n);
        let mut rng = crate::rng::stream(11, 0);
        let mut x = vec![0.0; n];
        let mut printed = vec![];
        for _ in 0..200 {
            let xi: Vec<f64> = (0..n).map(|_| rng.sample(StandardNormal)).collect();
            let rho: f64 = xi.iter().map(|v| v * v).sum();
            let s = rm.sample(&obj, &mu, r.phi, &ws.l, &xi, &mut x).unwrap();
            assert!((s.lambda - rho.sqrt()).abs() < 1e-9 * rho.sqrt());
            assert!(
                (s.log_jacobian + log_det_l).abs() < 1e-9,
                "log|J| = {} vs −log det L = {}",
                s.log_jacobian,
                -log_det_l
            );
            // F(X) − φ = ρ/2 holds.
            assert!((obj.value(&x) - r.phi - 0.5 * rho).abs() < 1e-9 * rho.max(1.0));
            printed.push(printed_log_jacobian(&s, rho, n, log_det_l));
        }
        let spread = printed.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
            - printed.iter().cloned().fold(f64::INFINITY, f64::min);
        assert!(
            spread > 1.0,
            "printed eq. (3) should not be constant: {spread}"
        );
    }

    /// A non-Gaussian convex 2-D target: E[x₁²] and the normaliser Z by the
    /// corrected random map agree with quadrature; the printed formula does
    /// not (notes, Appendix A check 2).
    /// Long: the quadrature reference is written out inline, beside the
    /// sampled moments it checks.
    #[test]
    fn random_map_moments_match_quadrature() {
        let f = |x: &[f64]| {
            0.5 * x[0] * x[0]
                + 0.5 * (x[1] - 0.5 * x[0]).powi(2)
                + 0.25 * x[0].powi(4)
                + 0.1 * x[1].powi(4)
                + 0.3 * x[0]
        };
        let obj = DenseObjective {
            n: 2,
            value: f,
            derivatives: move |x: &[f64], g: &mut [f64], h: &mut SymBand| {
                let e = x[1] - 0.5 * x[0];
                g[0] = x[0] - 0.5 * e + x[0].powi(3) + 0.3;
                g[1] = e + 0.4 * x[1].powi(3);
                h.set(0, 0, 1.0 + 0.25 + 3.0 * x[0] * x[0]);
                h.set(1, 0, -0.5);
                h.set(1, 1, 1.0 + 1.2 * x[1] * x[1]);
                f(x)
            },
        };
        // Quadrature on a fine grid.
        let (mut z, mut m2) = (0.0, 0.0);
        let h = 0.01;
        for i in -800..=800 {
            for j in -800..=800 {
                let x = [i as f64 * h, j as f64 * h];
                let p = (-f(&x)).exp() * h * h;
                z += p;
                m2 += p * x[0] * x[0];
            }
        }
        let m2 = m2 / z;
        let mut ws = NewtonWorkspace::new(2, 1);
        let mut mu = vec![0.0; 2];
        let r = ws
            .minimise(&obj, &mut mu, &NewtonOptions::default())
            .unwrap();
        let log_det_l = ws.l.log_det_factor();
        let mut rm = RandomMapWorkspace::new(2);
        let mut rng = crate::rng::stream(5, 0);
        let m = 40_000;
        let (mut lw, mut lw_printed, mut x1sq) = (vec![], vec![], vec![]);
        let mut x = [0.0; 2];
        for _ in 0..m {
            let xi: [f64; 2] = [rng.sample(StandardNormal), rng.sample(StandardNormal)];
            let s = rm.sample(&obj, &mu, r.phi, &ws.l, &xi, &mut x).unwrap();
            lw.push(s.log_jacobian);
            lw_printed.push(printed_log_jacobian(
                &s,
                xi[0] * xi[0] + xi[1] * xi[1],
                2,
                log_det_l,
            ));
            x1sq.push(x[0] * x[0]);
        }
        let est = |lw: &[f64]| {
            let mut w = vec![0.0; lw.len()];
            weights::normalise(lw, &mut w).expect("finite weights");
            let mean: f64 = w.iter().zip(&x1sq).map(|(w, v)| w * v).sum();
            let zhat = (-r.phi + weights::log_mean_exp(lw)).exp() * 2.0 * std::f64::consts::PI;
            (mean, zhat)
        };
        let (m2_c, z_c) = est(&lw);
        let (m2_p, z_p) = est(&lw_printed);
        assert!(
            (m2_c - m2).abs() < 0.02 * m2,
            "E[x1²]: {m2_c} vs quadrature {m2}"
        );
        assert!((z_c - z).abs() < 0.02 * z, "Z: {z_c} vs quadrature {z}");
        assert!((m2_p - m2).abs() > 0.1 * m2 || (z_p - z).abs() > 0.1 * z);
        // The linear map with weights (6) agrees too.
        let mut lw_lin = vec![];
        let mut x1sq_lin = vec![];
        for _ in 0..m {
            let xi: [f64; 2] = [rng.sample(StandardNormal), rng.sample(StandardNormal)];
            let hr = linear_map(&mu, &ws.l, &xi, &mut x);
            lw_lin.push(linear_map_log_weight(hr, obj.value(&x), r.phi, log_det_l));
            x1sq_lin.push(x[0] * x[0]);
        }
        let mut w = vec![0.0; m];
        weights::normalise(&lw_lin, &mut w).expect("finite weights");
        let m2_l: f64 = w.iter().zip(&x1sq_lin).map(|(w, v)| w * v).sum();
        let z_l = (-r.phi + weights::log_mean_exp(&lw_lin)).exp() * 2.0 * std::f64::consts::PI;
        assert!(
            (m2_l - m2).abs() < 0.02 * m2,
            "linear map E[x1²] {m2_l} vs {m2}"
        );
        assert!((z_l - z).abs() < 0.02 * z, "linear map Z {z_l} vs {z}");
        let _ = rng.random::<f64>();
    }

    /// Erratum E1 directly: the corrected log|det ∂X/∂ξ| equals the log
    /// determinant of the finite-difference Jacobian of the map ξ ↦ X on a
    /// non-Gaussian 3-D F (the printed eq. 3 is off by the factor 2√ρ).
    #[test]
    fn random_map_jacobian_matches_finite_differences_of_the_map() {
        let f = |x: &[f64]| {
            0.5 * (x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
                + 0.4 * x[0] * x[1]
                + 0.2 * x[0].powi(4)
                + 0.15 * (x[1] - x[2]).powi(4)
                + 0.5 * x[2]
        };
        let obj = DenseObjective {
            n: 3,
            value: f,
            derivatives: move |x: &[f64], g: &mut [f64], h: &mut SymBand| {
                let d = x[1] - x[2];
                g[0] = x[0] + 0.4 * x[1] + 0.8 * x[0].powi(3);
                g[1] = x[1] + 0.4 * x[0] + 0.6 * d.powi(3);
                g[2] = x[2] - 0.6 * d.powi(3) + 0.5;
                h.set(0, 0, 1.0 + 2.4 * x[0] * x[0]);
                h.set(1, 0, 0.4);
                h.set(2, 0, 0.0);
                h.set(1, 1, 1.0 + 1.8 * d * d);
                h.set(2, 1, -1.8 * d * d);
                h.set(2, 2, 1.0 + 1.8 * d * d);
                f(x)
            },
        };
        let mut ws = NewtonWorkspace::new(3, 2);
        let mut mu = vec![0.0; 3];
        let r = ws
            .minimise(&obj, &mut mu, &NewtonOptions::default())
            .unwrap();
        let log_det_l = ws.l.log_det_factor();
        let mut rm = RandomMapWorkspace::new(3);
        let mut rng = crate::rng::stream(21, 0);
        let (mut x, mut xp, mut xm) = ([0.0; 3], [0.0; 3], [0.0; 3]);
        let h = 1e-6;
        for _ in 0..20 {
            let xi: [f64; 3] = std::array::from_fn(|_| rng.sample(StandardNormal));
            let rho: f64 = xi.iter().map(|v| v * v).sum();
            let s = rm.sample(&obj, &mu, r.phi, &ws.l, &xi, &mut x).unwrap();
            let mut jac = nalgebra::Matrix3::zeros();
            for k in 0..3 {
                let (mut a, mut b) = (xi, xi);
                a[k] += h;
                b[k] -= h;
                rm.sample(&obj, &mu, r.phi, &ws.l, &a, &mut xp).unwrap();
                rm.sample(&obj, &mu, r.phi, &ws.l, &b, &mut xm).unwrap();
                for i in 0..3 {
                    jac[(i, k)] = (xp[i] - xm[i]) / (2.0 * h);
                }
            }
            let fd = jac.determinant().abs().ln();
            assert!(
                (s.log_jacobian - fd).abs() < 1e-5,
                "log|J| {} vs finite differences {fd}",
                s.log_jacobian
            );
            let printed = printed_log_jacobian(&s, rho, 3, log_det_l);
            // The printed form is off by the factor 2√ρ.
            assert!((printed - fd + (2.0 * rho.sqrt()).ln()).abs() < 1e-5);
        }
    }
}
