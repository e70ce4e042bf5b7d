//! Importance weights in the log domain — the crate's one place for
//! log-sum-exp, normalisation and the effective sample size (the particle
//! filter, the implicit path-integral weights of paper 003 §2 — W ∝ p/p₀,
//! eq. 6 for the linear map, the Jacobian (E1) for the random map — and the
//! double-slit density all use it).
//!
//! ψ in the double slit is ≈ 3.5·10⁻¹¹ and the exponents of F in the
//! controllers are O(10³), so weights are never exponentiated before the
//! largest has been subtracted:
//!
//! ```text
//! L = log Σ_j e^{ℓ_j} = ℓ_max + log Σ_j e^{ℓ_j − ℓ_max},   W_j = e^{ℓ_j − L}
//! ESS = (Σ_j w_j)² / Σ_j w_j² = 1 / Σ_j W_j²   (W normalised)
//! ```
//!
//! Names say which weights an ESS is taken over: [`ess_from_log`] reads log
//! weights ℓ (any shift), [`ess_from_linear`] non-negative linear weights w
//! (any positive scale), and [`normalise`] returns the ESS of the weights it
//! normalises. Entries equal to −∞ (zero weight, e.g. a path through the
//! double-slit wall or a diverged particle) are allowed; an all −∞ vector
//! has log-sum −∞ and ESS 0.

/// Summary of a set of log weights.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeightSummary {
    /// log Σ exp(lw_i).
    pub log_sum: f64,
    /// Effective sample size 1/Σ W_i² of the normalised weights.
    pub ess: f64,
}

/// log Σ e^{ℓ_j}, stable for any finite maximum; −∞ for an empty or all −∞
/// input; NaN if any ℓ is NaN; +∞ if one is +∞.
pub fn log_sum_exp(lw: &[f64]) -> f64 {
    let mx = lw.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if lw.iter().any(|v| v.is_nan()) {
        return f64::NAN;
    }
    if mx.is_infinite() {
        return mx;
    }
    mx + lw.iter().map(|&v| (v - mx).exp()).sum::<f64>().ln()
}

/// log of the mean (1/M) Σ e^{ℓ_j}.
pub fn log_mean_exp(lw: &[f64]) -> f64 {
    log_sum_exp(lw) - (lw.len() as f64).ln()
}

/// Normalise log weights `lw` into `w` (same length), W_j = e^{ℓ_j − L},
/// and return L and the ESS. Returns `None` — and leaves `w` untouched —
/// when the weights are degenerate (all −∞, a NaN or a +∞).
pub fn normalise(lw: &[f64], w: &mut [f64]) -> Option<WeightSummary> {
    debug_assert_eq!(lw.len(), w.len());
    let log_sum = log_sum_exp(lw);
    if !log_sum.is_finite() {
        return None;
    }
    let mut sq = 0.0;
    for (wi, &l) in w.iter_mut().zip(lw) {
        let v = (l - log_sum).exp();
        *wi = v;
        sq += v * v;
    }
    Some(WeightSummary {
        log_sum,
        ess: 1.0 / sq,
    })
}

/// ESS 1/Σ W_j² of log weights `lw` (0 if all vanish or one is NaN).
pub fn ess_from_log(lw: &[f64]) -> f64 {
    let lse = log_sum_exp(lw);
    if !lse.is_finite() {
        return 0.0;
    }
    let s2: f64 = lw.iter().map(|&l| (2.0 * (l - lse)).exp()).sum();
    1.0 / s2
}

/// ESS (Σ w)² / Σ w² of non-negative linear weights `w`, normalised or not
/// (0 if all vanish).
pub fn ess_from_linear(w: &[f64]) -> f64 {
    let (s, sq) = w.iter().fold((0.0, 0.0), |(s, sq), &v| (s + v, sq + v * v));
    if sq > 0.0 {
        s * s / sq
    } else {
        0.0
    }
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
        normalise(&lw, &mut wn).unwrap();
        for i in 0..4 {
            assert!((wn[i] - w[i] / s).abs() < 1e-15);
        }
        let e = s * s / w.iter().map(|v| v * v).sum::<f64>();
        assert!((ess_from_log(&lw) - e).abs() < 1e-12);
        assert!((ess_from_linear(&w) - e).abs() < 1e-12);
        assert!((ess_from_linear(&wn) - e).abs() < 1e-12);
        // Shifting every log weight by a huge constant changes nothing.
        let shifted: Vec<f64> = lw.iter().map(|v| v - 5000.0).collect();
        assert!((ess_from_log(&shifted) - e).abs() < 1e-12);
        assert!((log_sum_exp(&shifted) - (s.ln() - 5000.0)).abs() < 1e-10);
    }

    #[test]
    fn zero_weights() {
        let lw = [f64::NEG_INFINITY, 0.0, f64::NEG_INFINITY];
        assert!((ess_from_log(&lw) - 1.0).abs() < 1e-15);
        let none = [f64::NEG_INFINITY; 3];
        assert_eq!(log_sum_exp(&none), f64::NEG_INFINITY);
        assert_eq!(ess_from_log(&none), 0.0);
        assert_eq!(ess_from_linear(&[0.0; 3]), 0.0);
        assert!((log_mean_exp(&[0.0, 0.0]) - 0.0).abs() < 1e-15);
    }

    #[test]
    fn ess_and_normalisation_are_exact_on_known_weights() {
        // W = (1, 1, 2, 4)/8: ESS = 1/(1/64 + 1/64 + 4/64 + 16/64) = 64/22.
        let base = [1.0f64, 1.0, 2.0, 4.0];
        for shift in [0.0, -1000.0, 700.0] {
            let lw: Vec<f64> = base.iter().map(|v| v.ln() + shift).collect();
            let mut w = [0.0; 4];
            let s = normalise(&lw, &mut w).unwrap();
            assert!((s.ess - 64.0 / 22.0).abs() < 1e-12, "{}", s.ess);
            assert!((s.log_sum - (8.0f64.ln() + shift)).abs() < 1e-9);
            for i in 0..4 {
                assert!((w[i] - base[i] / 8.0).abs() < 1e-12);
            }
        }
        assert!((ess_from_linear(&base) - 64.0 / 22.0).abs() < 1e-12);
        // Equal weights: ESS = N; one surviving weight: ESS = 1.
        let mut w = [0.0; 5];
        assert!((normalise(&[3.0; 5], &mut w).unwrap().ess - 5.0).abs() < 1e-12);
        let lw = [f64::NEG_INFINITY, 2.0, f64::NEG_INFINITY];
        let mut w = [0.0; 3];
        assert_eq!(normalise(&lw, &mut w).unwrap().ess, 1.0);
        assert_eq!(w, [0.0, 1.0, 0.0]);
    }

    #[test]
    fn degenerate_weights_are_reported() {
        let mut w = [7.0; 3];
        assert!(normalise(&[f64::NEG_INFINITY; 3], &mut w).is_none());
        assert!(normalise(&[0.0, f64::NAN, 0.0], &mut w).is_none());
        assert!(normalise(&[0.0, f64::INFINITY, 0.0], &mut w).is_none());
        assert_eq!(w, [7.0; 3]);
        assert!(log_sum_exp(&[0.0, f64::NAN]).is_nan());
        assert_eq!(ess_from_log(&[0.0, f64::NAN]), 0.0);
    }
}
