//! Log-domain importance weights: normalisation and the squared coefficient
//! of variation that triggers rejuvenation, eq. (8) of Chen, Lai & Wu §2.2,
//! cv² = var_Q(w)/E_Q²(w).
//!
//! Over 10⁴ steps the products (6), (11) and (12) under- and overflow any
//! float, so weights are kept as logarithms and only exponentiated after
//! subtracting their maximum.
//!
//! The paper estimates cv² from the M weights without saying which variance:
//! we use the 1/M (plug-in) variance, so cv² = M Σw²/(Σw)² − 1 and
//! ESS = M/(1 + cv²): a bound of 1 is the familiar ESS ≤ M/2.

/// Exponentiate `logw` into `w` normalised to sum 1; returns log Σ exp(logw)
/// (−∞ when every weight is zero, NaN if any is NaN).
pub fn normalise(logw: &[f64], w: &mut [f64]) -> f64 {
    debug_assert_eq!(logw.len(), w.len());
    let m = logw.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !m.is_finite() {
        w.fill(0.0);
        return m;
    }
    let mut sum = 0.0;
    for (wi, &l) in w.iter_mut().zip(logw) {
        *wi = (l - m).exp();
        sum += *wi;
    }
    let inv = 1.0 / sum;
    for wi in w.iter_mut() {
        *wi *= inv;
    }
    m + sum.ln()
}

/// cv² of normalised weights `w` (summing to 1) with the 1/M variance.
pub fn cv2(w: &[f64]) -> f64 {
    let m = w.len() as f64;
    let s2: f64 = w.iter().map(|x| x * x).sum();
    (m * s2 - 1.0).max(0.0)
}

/// log of N(x; mean, var).
#[inline]
pub fn log_normal_pdf(x: f64, mean: f64, var: f64) -> f64 {
    const LN_2PI: f64 = 1.837_877_066_409_345_5;
    let d = x - mean;
    -0.5 * (LN_2PI + var.ln() + d * d / var)
}

/// log(exp(a) + exp(b)) without overflow.
#[inline]
pub fn log_add(a: f64, b: f64) -> f64 {
    let (hi, lo) = if a > b { (a, b) } else { (b, a) };
    if hi == f64::NEG_INFINITY {
        return hi;
    }
    hi + (lo - hi).exp().ln_1p()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cv2_matches_its_definition() {
        let logw = [0.0f64, 1.0, -2.0, 0.5];
        let mut w = [0.0; 4];
        let lse = normalise(&logw, &mut w);
        let raw: Vec<f64> = logw.iter().map(|l| l.exp()).collect();
        let sum: f64 = raw.iter().sum();
        assert!((lse - sum.ln()).abs() < 1e-12);
        let mean = sum / 4.0;
        let var = raw.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / 4.0;
        assert!((cv2(&w) - var / (mean * mean)).abs() < 1e-12);
    }

    #[test]
    fn normalise_survives_huge_log_weights() {
        let logw = [-1e5, -1e5 + 2.0_f64.ln()];
        let mut w = [0.0; 2];
        normalise(&logw, &mut w);
        assert!((w[0] - 1.0 / 3.0).abs() < 1e-12 && (w[1] - 2.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn log_add_and_normal_pdf_are_exact() {
        assert!((log_add(1.0, 2.0) - (1f64.exp() + 2f64.exp()).ln()).abs() < 1e-12);
        let p = (-0.5f64 * 0.25 / 2.0).exp() / (2.0 * std::f64::consts::PI * 2.0).sqrt();
        assert!((log_normal_pdf(1.5, 1.0, 2.0) - p.ln()).abs() < 1e-12);
    }
}
