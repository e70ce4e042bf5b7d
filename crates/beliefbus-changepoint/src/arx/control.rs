//! Adaptive control rules of Chen & Lai (2007) §IIIB (Chen, Lai & Wu §3.4):
//! choose u_t so that y_{t+1} = b₁u_t + γᵀψ_t + ε_{t+1} is near y*_{t+1},
//! where b₁ is θ's entry k (0-based) and γ, ψ_t the other entries of θ and
//! φ_{t+1} (ψ_t = φ_{t+1} with the u_t slot removed).
//! - certainty equivalence (18): u_t = (y* − γ̂ᵀψ_t)/b̂₁ if |b̂₁| ≥ δ_t,
//!   else y* + ω_t;
//! - uncertainty adjusted (20), the minimiser (19) of E_t(y_{t+1} − y*)²:
//!   u_t = (y* E_t b₁ − E_t(b₁γᵀ)ψ_t)/E_t b₁² if √(E_t b₁²) ≥ δ_t, else
//!   y* + ω_t.

use super::linalg::{Matrix, Vector};

/// Rule (18) from a point prediction θ̂_{t+1|t}. `phi_next` is φ_{t+1}
/// with any value in the u_t slot `e`; `omega` the excitation draw.
pub fn certainty_equivalence<const D: usize>(
    theta: &Vector<D>,
    phi_next: &Vector<D>,
    e: usize,
    y_star: f64,
    delta: f64,
    omega: f64,
) -> f64 {
    let b1 = theta[e];
    if b1.abs() >= delta && b1 != 0.0 {
        let mut g = 0.0;
        for i in 0..D {
            if i != e {
                g += theta[i] * phi_next[i];
            }
        }
        (y_star - g) / b1
    } else {
        y_star + omega
    }
}

/// Rule (20) from the predictive mean and second moment of θ_{t+1}.
pub fn uncertainty_adjusted<const D: usize>(
    mean: &Vector<D>,
    second: &Matrix<D>,
    phi_next: &Vector<D>,
    e: usize,
    y_star: f64,
    delta: f64,
    omega: f64,
) -> f64 {
    let eb2 = second[e][e];
    if eb2.sqrt() >= delta && eb2 > 0.0 {
        let mut g = 0.0;
        for i in 0..D {
            if i != e {
                g += second[e][i] * phi_next[i];
            }
        }
        (y_star * mean[e] - g) / eb2
    } else {
        y_star + omega
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// With no uncertainty (second = mean meanᵀ) rule (20) is rule (18),
    /// and both make θᵀφ_{t+1} = y* exactly.
    #[test]
    fn rules_agree_without_uncertainty_and_hit_the_reference() {
        let th = [0.3, -0.2, 0.8];
        let mut second = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                second[i][j] = th[i] * th[j];
            }
        }
        let mut phi = [-1.5, 0.7, 0.0];
        let u1 = certainty_equivalence(&th, &phi, 2, 2.0, 0.25, 0.0);
        let u2 = uncertainty_adjusted(&th, &second, &phi, 2, 2.0, 0.25, 0.0);
        assert!((u1 - u2).abs() < 1e-12);
        phi[2] = u1;
        let pred: f64 = (0..3).map(|i| th[i] * phi[i]).sum();
        assert!((pred - 2.0).abs() < 1e-12);
        // Below the threshold: the excitation branch.
        let small = [0.3, -0.2, 0.1];
        assert_eq!(certainty_equivalence(&small, &phi, 2, 2.0, 0.25, 0.5), 2.5);
    }

    /// Rule (20) minimises E(b₁u + γᵀψ − y*)²: its value beats nearby u
    /// under a mixture with uncertainty (finite-difference check).
    #[test]
    fn uncertainty_adjusted_rule_minimises_the_expected_square() {
        let mean = [0.2, 0.1, 0.6];
        // second = mean meanᵀ + Σ with Σ = diag(0.1, 0.05, 0.3) + coupling.
        let mut second = [[0.0; 3]; 3];
        let cov = [[0.1, 0.0, 0.03], [0.0, 0.05, -0.02], [0.03, -0.02, 0.3]];
        for i in 0..3 {
            for j in 0..3 {
                second[i][j] = mean[i] * mean[j] + cov[i][j];
            }
        }
        let phi = [-1.0, 0.4, 0.0];
        let ys = 1.3;
        let cost = |u: f64| {
            // E(b u + g - y*)², b = θ₂, g = θ₀φ₀ + θ₁φ₁, from the moments.
            let w = [phi[0], phi[1], u];
            let mut e2 = 0.0;
            for i in 0..3 {
                for j in 0..3 {
                    e2 += w[i] * w[j] * second[i][j];
                }
            }
            let m: f64 = (0..3).map(|i| w[i] * mean[i]).sum();
            e2 - 2.0 * ys * m + ys * ys
        };
        let u = uncertainty_adjusted(&mean, &second, &phi, 2, ys, 0.0, 0.0);
        for du in [-1e-3, 1e-3, -0.1, 0.1] {
            assert!(cost(u) < cost(u + du));
        }
    }
}
