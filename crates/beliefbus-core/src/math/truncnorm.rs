//! The standard normal restricted to an interval [a, b], stable far in the
//! tails (the double-slit gate sits 6 standard deviations out):
//!
//! ```text
//! log P(a ≤ Z ≤ b) = log(Φ(b) − Φ(a)),     Φ(x) = ½ erfc(−x/√2)
//! Z = Φ⁻¹(Φ(a) + U (Φ(b) − Φ(a)))          (inverse CDF, U ~ U(0, 1))
//! ```
//!
//! Differences of Φ are taken as differences of erfc on the side of the
//! interval away from 0 (no cancellation), Φ⁻¹ is Acklam's rational
//! approximation polished by two Halley steps on erfc, and beyond 37σ
//! (where erfc underflows) the tail is the exponential e^{−a x} it tends to.

use std::f64::consts::{FRAC_1_SQRT_2, PI};

/// ln erfc(x), accurate in the far tail (asymptotic series beyond x = 20).
pub fn ln_erfc(x: f64) -> f64 {
    if x < 20.0 {
        libm::erfc(x).ln()
    } else {
        // erfc(x) = e^{−x²}/(x√π) (1 − 1/(2x²) + 3/(4x⁴) − 15/(8x⁶) + …)
        let x2 = x * x;
        let series = 1.0 - 0.5 / x2 + 0.75 / (x2 * x2) - 1.875 / (x2 * x2 * x2);
        -x2 - (x * PI.sqrt()).ln() + series.ln()
    }
}

/// ln(erf(hi) − erf(lo)) for lo < hi without cancellation.
pub fn ln_erf_diff(lo: f64, hi: f64) -> f64 {
    if hi <= lo {
        return f64::NEG_INFINITY;
    }
    if lo >= 0.0 {
        let (a, b) = (ln_erfc(lo), ln_erfc(hi));
        a + (-(b - a).exp()).ln_1p()
    } else if hi <= 0.0 {
        ln_erf_diff(-hi, -lo)
    } else {
        (libm::erf(hi) - libm::erf(lo)).ln()
    }
}

/// ln(Φ(b) − Φ(a)) for the standard normal.
pub fn ln_mass(a: f64, b: f64) -> f64 {
    ln_erf_diff(a * FRAC_1_SQRT_2, b * FRAC_1_SQRT_2) - std::f64::consts::LN_2
}

/// Upper tail Q(x) = 1 − Φ(x).
fn q_tail(x: f64) -> f64 {
    0.5 * libm::erfc(x * FRAC_1_SQRT_2)
}

/// Φ⁻¹(p) for 0 < p < 1 (Acklam 2003, then Halley refinement).
pub fn inv_phi(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    if p <= 0.0 {
        return f64::NEG_INFINITY;
    }
    if p >= 1.0 {
        return f64::INFINITY;
    }
    let plow = 0.02425;
    let mut x = if p < plow {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - plow {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        let q = (-2.0 * (1.0 - p).ln()).sqrt();
        -(((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    // Halley steps on Φ(x) − p, with Φ from erfc (relative accuracy in the tails).
    for _ in 0..2 {
        let e = 0.5 * libm::erfc(-x * FRAC_1_SQRT_2) - p;
        let u = e * (2.0 * PI).sqrt() * (0.5 * x * x).exp();
        x -= u / (1.0 + 0.5 * x * u);
    }
    x
}

/// The point of [a, b] at CDF level `u` ∈ (0, 1) of the standard normal
/// truncated to [a, b] (a < b).
pub fn quantile(a: f64, b: f64, u: f64) -> f64 {
    if a >= 0.0 {
        // Right tail: work with Q = 1 − Φ, which is accurate there.
        let (qa, qb) = (q_tail(a), q_tail(b));
        if qa > 1e-300 {
            let q = qa - u * (qa - qb);
            return (-inv_phi(q)).clamp(a, b);
        }
        // Beyond ~37σ: density ∝ e^{−a x} on [a, b] to leading order.
        let w = b - a;
        let x = a - (1.0 - u * (1.0 - (-a * w).exp())).ln() / a;
        return x.clamp(a, b);
    }
    if b <= 0.0 {
        return -quantile(-b, -a, 1.0 - u);
    }
    let (pa, pb) = (
        0.5 * libm::erfc(-a * FRAC_1_SQRT_2),
        0.5 * libm::erfc(-b * FRAC_1_SQRT_2),
    );
    inv_phi(pa + u * (pb - pa)).clamp(a, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_cdf_round_trips_into_the_tails() {
        for &p in &[1e-300, 1e-20, 1e-10, 0.001, 0.02, 0.3, 0.5, 0.9, 0.999] {
            let x = inv_phi(p);
            let back = 0.5 * libm::erfc(-x * FRAC_1_SQRT_2);
            assert!((back - p).abs() < 1e-12 * p, "p={p}: x={x}, Φ(x)={back}");
        }
    }

    #[test]
    fn truncated_quantiles_have_the_right_distribution() {
        // Median of the truncation and moments by quadrature, in three regimes.
        for &(a, b) in &[(-1.0, 2.0), (6.0, 9.0), (-9.0, -6.2), (40.0, 41.0)] {
            let n = 20_000;
            let mean_q: f64 = (0..n)
                .map(|j| quantile(a, b, (j as f64 + 0.5) / n as f64))
                .sum::<f64>()
                / n as f64;
            // Quadrature of the truncated mean: ∫ x φ(x) / ∫ φ(x) (shifted for stability).
            let m = 200_000;
            let h = (b - a) / m as f64;
            let c = if a > 0.0 {
                a
            } else if b < 0.0 {
                b
            } else {
                0.0
            };
            let (mut s0, mut s1) = (0.0, 0.0);
            for i in 0..m {
                let x = a + (i as f64 + 0.5) * h;
                let w = (-(x * x - c * c) / 2.0).exp();
                s0 += w;
                s1 += w * x;
            }
            let mean = s1 / s0;
            assert!(
                (mean_q - mean).abs() < 1e-3 * (1.0 + mean.abs()),
                "[{a},{b}]: {mean_q} vs {mean}"
            );
            for u in [0.0, 0.3, 1.0] {
                let x = quantile(a, b, u);
                assert!(x >= a && x <= b);
            }
        }
        // ln mass against the direct formula where it is accurate.
        let direct =
            (0.5 * libm::erfc(-2.0 * FRAC_1_SQRT_2) - 0.5 * libm::erfc(1.0 * FRAC_1_SQRT_2)).ln();
        assert!((ln_mass(-1.0, 2.0) - direct).abs() < 1e-13);
        assert!(ln_mass(6.0, 9.0).is_finite() && ln_mass(40.0, 41.0).is_finite());
    }
}
