//! The double slit (paper 003 §3.1, after Kappen): a walker
//! dx = u dt + √σ dW must pass a wall at t₁ through one of two slits
//! [a, b] ∪ [c, d] and ends with cost Φ = x(t_f)²/2, running cost ½ r u²
//! (E2). Condition (8) gives γ = σ r (erratum E7; the printed γ = r√σ
//! coincides at σ = 1).
//!
//! Analytic solution (derived from eq. 11; erratum E7 corrects φ and the
//! path term), with s = t_f − t for t ≥ t₁ and ŝ = t₁ − t, s = t_f − t₁,
//! T = σ(t_f − t) + γ, A = 1/(σŝ) + 1/(γ + σs), c₀ = x/(σŝA), k = √(A/2) for
//! t < t₁:
//!
//! ```text
//! t ≥ t₁:  ψ = √(γ/(γ + σs)) exp(−x²/(2(γ + σs))),          u = −σ x/(γ + σs)
//! t < t₁:  ψ = √(γ/T) e^{−x²/(2T)} · ½ Σ_slits [erf((h − c₀)k) − erf((l − c₀)k)]
//!          u = σ ∂ₓ log ψ = σ [ −x/T − (2k/√π)(dc₀/dx) Σ (e^{−((h−c₀)k)²} − e^{−((l−c₀)k)²}) / Σ(erf ⋯) ]
//! ```
//!
//! With Table 1 (t_f = 2, t₁ = 1, slits [−6,−4] ∪ [6,8], σ = 1, r = 0.1):
//! ψ(1, 0) ≈ 3.5177·10⁻¹¹, u(1, 0) = −5.1095 (the notes round to ≈ −5.09). The erf differences are
//! evaluated as erfc differences in the log domain (they are ~10⁻¹⁰ here).

use super::affine::ControlledBrownian;
use super::path_cost::{Gate, PathCost};
use crate::math::truncnorm::ln_erf_diff;
use crate::math::weights::log_sum_exp;

/// Table 1 of the paper.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DoubleSlit {
    pub t_final: f64,
    pub t_wall: f64,
    /// Slits [a, b] and [c, d].
    pub slits: [(f64, f64); 2],
    pub x0: f64,
    /// Noise variance rate σ.
    pub sigma: f64,
    /// Control cost r (running cost ½ r u²).
    pub r: f64,
    /// Time step Δt.
    pub dt: f64,
}

impl Default for DoubleSlit {
    fn default() -> Self {
        Self {
            t_final: 2.0,
            t_wall: 1.0,
            slits: [(-6.0, -4.0), (6.0, 8.0)],
            x0: 1.0,
            sigma: 1.0,
            r: 0.1,
            dt: 0.02,
        }
    }
}

/// Φ = x²/2, V = 0 away from the wall (the wall is a [`Gate`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SlitCost;

impl PathCost for SlitCost {
    fn running(&self, _x: &[f64]) -> f64 {
        0.0
    }
    fn running_derivatives(&self, _x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        g[0] = 0.0;
        h[0] = 0.0;
        0.0
    }
    fn terminal(&self, x: &[f64]) -> f64 {
        0.5 * x[0] * x[0]
    }
    fn terminal_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        g[0] = x[0];
        h[0] = 1.0;
        0.5 * x[0] * x[0]
    }
}

impl DoubleSlit {
    /// γ = σ r (condition 8, E7).
    pub fn gamma(&self) -> f64 {
        self.sigma * self.r
    }

    /// The controlled walker as a control-affine model.
    pub fn model(&self) -> ControlledBrownian {
        ControlledBrownian {
            dim: 1,
            sigma: self.sigma,
        }
    }

    /// Number of steps from t to t_f.
    pub fn steps_from(&self, t: f64) -> usize {
        ((self.t_final - t) / self.dt).round().max(0.0) as usize
    }

    /// The wall as a gate for a path starting at t (None once t ≥ t₁).
    pub fn gate_from(&self, t: f64) -> Option<Gate> {
        let k = ((self.t_wall - t) / self.dt).round();
        if k >= 1.0 {
            Some(Gate::new(k as usize, 0, &self.slits))
        } else {
            None
        }
    }

    /// Whether t is at or after the wall (up to rounding on the grid).
    fn after_wall(&self, t: f64) -> bool {
        t >= self.t_wall - 1e-9 * self.dt
    }

    /// Analytic log ψ(x, t).
    pub fn log_psi(&self, x: f64, t: f64) -> f64 {
        let (g, sg) = (self.gamma(), self.sigma);
        if self.after_wall(t) {
            let v = g + sg * (self.t_final - t);
            return 0.5 * (g / v).ln() - x * x / (2.0 * v);
        }
        let (tt, a, c0, k) = self.before_wall(x, t);
        let mut terms = [0.0; 2];
        for (i, &(l, h)) in self.slits.iter().enumerate() {
            terms[i] = ln_erf_diff((l - c0) * k, (h - c0) * k);
        }
        let _ = a;
        0.5 * (g / tt).ln() - x * x / (2.0 * tt) + log_sum_exp(&terms) - std::f64::consts::LN_2
    }

    fn before_wall(&self, x: f64, t: f64) -> (f64, f64, f64, f64) {
        let (g, sg) = (self.gamma(), self.sigma);
        let tt = sg * (self.t_final - t) + g;
        let sh = self.t_wall - t;
        let s = self.t_final - self.t_wall;
        let a = 1.0 / (sg * sh) + 1.0 / (g + sg * s);
        let c0 = x / (sg * sh * a);
        (tt, a, c0, (a / 2.0).sqrt())
    }

    /// Analytic optimal control u(x, t) = σ ∂ₓ log ψ.
    pub fn control(&self, x: f64, t: f64) -> f64 {
        let (g, sg) = (self.gamma(), self.sigma);
        if self.after_wall(t) {
            return -sg * x / (g + sg * (self.t_final - t));
        }
        let (tt, a, c0, k) = self.before_wall(x, t);
        let sh = self.t_wall - t;
        let dc0 = 1.0 / (sg * sh * a);
        let mut terms = [0.0; 2];
        for (i, &(l, h)) in self.slits.iter().enumerate() {
            terms[i] = ln_erf_diff((l - c0) * k, (h - c0) * k);
        }
        let log_s = log_sum_exp(&terms);
        let mut num = 0.0;
        for &(l, h) in &self.slits {
            let (hh, ll) = ((h - c0) * k, (l - c0) * k);
            num += (-hh * hh - log_s).exp() - (-ll * ll - log_s).exp();
        }
        let dlog = -x / tt - dc0 * 2.0 * k / std::f64::consts::PI.sqrt() * num;
        sg * dlog
    }

    /// Whether x passes the wall.
    pub fn in_slit(&self, x: f64) -> bool {
        self.slits.iter().any(|&(l, h)| x >= l && x <= h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::truncnorm::ln_erfc;

    /// ψ before the wall by Simpson quadrature of its defining integral:
    /// ψ = ∫_slits N(y₁; x, σŝ) √(γ/(γ+σs)) e^{−y₁²/(2(γ+σs))} dy₁.
    fn psi_quadrature(p: &DoubleSlit, x: f64, t: f64) -> f64 {
        let (g, sg) = (p.gamma(), p.sigma);
        let sh = p.t_wall - t;
        let s = p.t_final - p.t_wall;
        let mut total = 0.0;
        for &(l, h) in &p.slits {
            let n = 20_000;
            let dx = (h - l) / n as f64;
            for i in 0..=n {
                let y = l + i as f64 * dx;
                let w = if i == 0 || i == n {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                let f = (-(y - x).powi(2) / (2.0 * sg * sh)).exp()
                    / (2.0 * std::f64::consts::PI * sg * sh).sqrt()
                    * (g / (g + sg * s)).sqrt()
                    * (-y * y / (2.0 * (g + sg * s))).exp();
                total += w * f * dx / 3.0;
            }
        }
        total
    }

    #[test]
    fn analytic_psi_matches_quadrature_and_paper_values() {
        let p = DoubleSlit::default();
        let psi = p.log_psi(1.0, 0.0).exp();
        let q = psi_quadrature(&p, 1.0, 0.0);
        assert!((psi - q).abs() < 1e-7 * q, "{psi} vs {q}");
        assert!((psi - 3.5177e-11).abs() < 1e-4 * 3.5177e-11, "{psi}");
        for &(x, t) in &[(0.3, 0.5), (-5.0, 0.9), (7.0, 0.2), (2.0, 0.96)] {
            let a = p.log_psi(x, t).exp();
            let q = psi_quadrature(&p, x, t);
            assert!((a - q).abs() < 1e-6 * q, "x={x} t={t}: {a} vs {q}");
        }
        // After the wall (notes Appendix A check 4): ψ(1, t₁) = 0.191380.
        assert!((p.log_psi(1.0, 1.0).exp() - 0.191380).abs() < 1e-6);
    }

    #[test]
    fn analytic_control_is_sigma_times_the_log_derivative() {
        let p = DoubleSlit::default();
        // The notes quote u(1, 0) ≈ −5.09; the exact value is −5.10955 (also
        // by central differences of the erfc form in double precision).
        assert!(
            (p.control(1.0, 0.0) + 5.109_547_6).abs() < 1e-6,
            "{}",
            p.control(1.0, 0.0)
        );
        for &(x, t) in &[
            (1.0, 0.0),
            (0.3, 0.5),
            (-5.0, 0.9),
            (7.0, 0.2),
            (-3.0, 0.99),
            (1.0, 1.4),
        ] {
            let h = 1e-5;
            let fd = p.sigma * (p.log_psi(x + h, t) - p.log_psi(x - h, t)) / (2.0 * h);
            let u = p.control(x, t);
            assert!(
                (u - fd).abs() < 1e-5 * (1.0 + u.abs()),
                "x={x} t={t}: {u} vs {fd}"
            );
        }
    }

    #[test]
    fn erf_differences_survive_the_tails() {
        // erf(−4.42) − erf(−6.37) ≈ erfc(4.42): no cancellation to zero.
        let v = ln_erf_diff(-6.37, -4.42).exp();
        assert!((v - libm::erfc(4.42)).abs() < 1e-6 * v);
        assert!(ln_erf_diff(30.0, 31.0).is_finite());
        assert!((ln_erfc(20.5) - libm::erfc(20.5).ln()).abs() < 1e-6);
    }
}
