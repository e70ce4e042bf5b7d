//! Importance weights in the log domain (paper 003 §2: weights W ∝ p/p₀,
//! eq. 6 for the linear map, the Jacobian (E1) for the random map).
//!
//! ψ in the double slit is ≈ 3.5·10⁻¹¹ and the exponents of F in the
//! controllers are O(10³), so weights are never exponentiated before the
//! largest has been subtracted:
//!
//! ```text
//! log Σ_j e^{ℓ_j} = ℓ_max + log Σ_j e^{ℓ_j − ℓ_max},   W_j = e^{ℓ_j − log Σ e^ℓ}
//! ESS = (Σ_j W_j)² / Σ_j W_j² = 1 / Σ_j W_j²   (normalised W)
//! ```
//!
//! Entries equal to −∞ (zero weight, e.g. a path through the double-slit
//! wall) are allowed; an all −∞ vector has log-sum −∞ and ESS 0.

/// log Σ e^{ℓ_j} (−∞ for an empty or all −∞ input; NaN propagates).
pub fn log_sum_exp(lw: &[f64]) -> f64 {
    let m = lw.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY || m.is_nan() {
        return if lw.iter().any(|v| v.is_nan()) {
            f64::NAN
        } else {
            f64::NEG_INFINITY
        };
    }
    if m == f64::INFINITY {
        return f64::INFINITY;
    }
    m + lw.iter().map(|&v| (v - m).exp()).sum::<f64>().ln()
}

/// log of the mean (1/M) Σ e^{ℓ_j}.
pub fn log_mean_exp(lw: &[f64]) -> f64 {
    log_sum_exp(lw) - (lw.len() as f64).ln()
}

/// Normalised weights W_j = e^{ℓ_j}/Σe^ℓ into `w`; returns log Σ e^ℓ. With
/// all weights zero, `w` is filled with zeros.
pub fn normalise(lw: &[f64], w: &mut [f64]) -> f64 {
    let lse = log_sum_exp(lw);
    if !lse.is_finite() {
        w[..lw.len()].fill(0.0);
        return lse;
    }
    for (wi, &l) in w.iter_mut().zip(lw) {
        *wi = (l - lse).exp();
    }
    lse
}

/// Effective sample size 1/Σ W_j² of log weights (0 if all vanish).
pub fn ess(lw: &[f64]) -> f64 {
    let lse = log_sum_exp(lw);
    if !lse.is_finite() {
        return 0.0;
    }
    let s2: f64 = lw.iter().map(|&l| (2.0 * (l - lse)).exp()).sum();
    1.0 / s2
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_domain_matches_linear_domain() {
        let w = [0.1, 2.0, 0.7, 1e-3];
        let lw: Vec<f64> = w.iter().map(|v: &f64| v.ln()).collect();
        let s: f64 = w.iter().sum();
        assert!((log_sum_exp(&lw) - s.ln()).abs() < 1e-14);
        let mut wn = [0.0; 4];
        normalise(&lw, &mut wn);
        for i in 0..4 {
            assert!((wn[i] - w[i] / s).abs() < 1e-15);
        }
        let e = s * s / w.iter().map(|v| v * v).sum::<f64>();
        assert!((ess(&lw) - e).abs() < 1e-12);
        // Shifting every log weight by a huge constant changes nothing.
        let shifted: Vec<f64> = lw.iter().map(|v| v - 5000.0).collect();
        assert!((ess(&shifted) - e).abs() < 1e-12);
        assert!((log_sum_exp(&shifted) - (s.ln() - 5000.0)).abs() < 1e-10);
    }

    #[test]
    fn zero_weights() {
        let lw = [f64::NEG_INFINITY, 0.0, f64::NEG_INFINITY];
        assert!((ess(&lw) - 1.0).abs() < 1e-15);
        let none = [f64::NEG_INFINITY; 3];
        assert_eq!(log_sum_exp(&none), f64::NEG_INFINITY);
        assert_eq!(ess(&none), 0.0);
        assert!((log_mean_exp(&[0.0, 0.0]) - 0.0).abs() < 1e-15);
    }
}
