//! Optimisation by stochastic control (paper 003 §3.3): to minimise
//! Himmelblau's function f, steer dx = u dt + √σ dW with cost
//! E[f(x(t_f)) + ∫ ½ uᵀRu dt] (E2) — the noise lets the controlled process
//! escape the saddle that plain Newton converges to.
//!
//! ```text
//! f(x₁, x₂) = (x₁² + x₂ − 11)² + (x₁ + x₂² − 7)²
//! F = (1/(2σΔt)) Σ |y_i − y_{i−1}|² + f(y_n)/γ,   γ = σR (condition 8)
//! ```
//!
//! Undamped Newton from (−1, −4) goes to the saddle (−0.127961, −1.953715),
//! f = 178.3372 (Table 4's Newton column; notes Appendix A check 1).

use super::path_cost::PathCost;

/// Himmelblau's function.
pub fn f(x: &[f64]) -> f64 {
    let a = x[0] * x[0] + x[1] - 11.0;
    let b = x[0] + x[1] * x[1] - 7.0;
    a * a + b * b
}

/// f, ∇f into `g`, ∇²f (2×2 column-major) into `h`.
pub fn derivatives(x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
    let a = x[0] * x[0] + x[1] - 11.0;
    let b = x[0] + x[1] * x[1] - 7.0;
    g[0] = 4.0 * a * x[0] + 2.0 * b;
    g[1] = 2.0 * a + 4.0 * b * x[1];
    h[0] = 12.0 * x[0] * x[0] + 4.0 * x[1] - 42.0;
    h[1] = 4.0 * (x[0] + x[1]);
    h[2] = h[1];
    h[3] = 4.0 * x[0] + 12.0 * x[1] * x[1] - 26.0;
    a * a + b * b
}

/// Plain (undamped) Newton iterates x ← x − ∇²f⁻¹∇f, the paper's baseline;
/// returns f at every iterate including the start.
pub fn newton_iterates(x0: [f64; 2], iterations: usize) -> Vec<(f64, [f64; 2])> {
    let mut x = x0;
    let mut out = vec![(f(&x), x)];
    let (mut g, mut h) = ([0.0; 2], [0.0; 4]);
    for _ in 0..iterations {
        derivatives(&x, &mut g, &mut h);
        let det = h[0] * h[3] - h[1] * h[2];
        if det == 0.0 {
            break;
        }
        let dx0 = (h[3] * g[0] - h[2] * g[1]) / det;
        let dx1 = (-h[1] * g[0] + h[0] * g[1]) / det;
        x = [x[0] - dx0, x[1] - dx1];
        out.push((f(&x), x));
    }
    out
}

/// The four minima of f (all with f = 0).
pub const MINIMA: [[f64; 2]; 4] = [
    [3.0, 2.0],
    [-2.805118, 3.131312],
    [-3.779310, -3.283186],
    [3.584428, -1.848126],
];

/// V = 0, Φ = f.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HimmelblauCost;

impl PathCost for HimmelblauCost {
    fn running(&self, _x: &[f64]) -> f64 {
        0.0
    }
    fn running_derivatives(&self, _x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        g[..2].fill(0.0);
        h[..4].fill(0.0);
        0.0
    }
    fn terminal(&self, x: &[f64]) -> f64 {
        f(x)
    }
    fn terminal_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        derivatives(x, g, h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivatives_match_finite_differences() {
        for x in [[-1.0, -4.0], [0.3, 2.2], [3.5, -1.9]] {
            let (mut g, mut h) = ([0.0; 2], [0.0; 4]);
            derivatives(&x, &mut g, &mut h);
            for i in 0..2 {
                let e = 1e-6;
                let (mut xp, mut xm) = (x, x);
                xp[i] += e;
                xm[i] -= e;
                assert!(((f(&xp) - f(&xm)) / (2.0 * e) - g[i]).abs() < 1e-5);
                let (mut gp, mut gm, mut hh) = ([0.0; 2], [0.0; 2], [0.0; 4]);
                derivatives(&xp, &mut gp, &mut hh);
                derivatives(&xm, &mut gm, &mut hh);
                for j in 0..2 {
                    assert!(((gp[j] - gm[j]) / (2.0 * e) - h[j + 2 * i]).abs() < 1e-4);
                }
            }
        }
        for m in MINIMA {
            assert!(f(&m) < 1e-9);
        }
    }

    /// Table 4's Newton column and the saddle it ends at (notes check 1).
    #[test]
    fn undamped_newton_reaches_the_saddle() {
        let it = newton_iterates([-1.0, -4.0], 8);
        let paper = [260.00, 195.36, 180.19, 178.43, 178.34];
        for (k, &p) in paper.iter().enumerate() {
            assert!(
                (it[k].0 - p).abs() < 0.01,
                "iterate {k}: {} vs {p}",
                it[k].0
            );
        }
        let (fx, x) = it[8];
        assert!((fx - 178.3372).abs() < 1e-3);
        assert!((x[0] + 0.127961).abs() < 1e-5 && (x[1] + 1.953715).abs() < 1e-5);
        let (mut g, mut h) = ([0.0; 2], [0.0; 4]);
        derivatives(&x, &mut g, &mut h);
        assert!(
            h[0] * h[3] - h[1] * h[2] < 0.0,
            "a saddle: indefinite Hessian"
        );
    }
}
