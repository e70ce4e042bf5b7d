//! The laser: range and bearing to a landmark m from the laser pose
//! x = (x₁, x₂, β) (paper 003 appendix, with errata E9, E11, E12 of the notes):
//!
//! ```text
//! h(x, m) = ( ‖(x₁, x₂) − m‖,  atan2(m₂ − x₂, m₁ − x₁) − β + π/2 )
//! term(x) = ½ ε²/σ₁ + ½ e²/σ₂,   ε = r − z₁,   e = wrap(z₂ − θ̂)
//! ∇term = ( d₁ε/(σ₁r) + d₂e/(σ₂r²),  d₂ε/(σ₁r) − d₁e/(σ₂r²),  e/σ₂ )
//! ```
//!
//! with d = (x₁, x₂) − m, r = ‖d‖, θ̂ the predicted bearing, and the
//! corrected Hessian of E12. The bearing is in the laser frame, 0 to the
//! right, π/2 straight ahead, π to the left; the forward half circle is
//! bearings in [0, π].
//!
//! σ₁ = 0.05, σ₂ = 0.05π/180 are read as the diagonal *entries* of Σ₂, i.e.
//! variances (0.05 m² and 8.7·10⁻⁴ rad²: standard deviations 0.22 m and
//! 1.7°), because the paper's gradient divides the innovations by σ, not σ²
//! (notes §3.4). The other reading (0.05 m, 0.05°) is a parameter away.

use crate::geometry::{wrap_angle, Point, Pose};
use nalgebra::{Matrix3, Vector3};
use std::f64::consts::FRAC_PI_2;

/// Σ₂ = diag(σ₁, σ₂): variances of range (m²) and bearing (rad²).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LaserNoise {
    pub var_range: f64,
    pub var_bearing: f64,
}

impl Default for LaserNoise {
    fn default() -> Self {
        Self {
            var_range: 0.05,
            var_bearing: 0.05 * std::f64::consts::PI / 180.0,
        }
    }
}

/// One laser return: range (m), bearing (rad, laser frame), and the index of
/// the landmark it belongs to (the association, given in MCL).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    pub range: f64,
    pub bearing: f64,
    pub landmark: usize,
}

/// h(x, m): the predicted range and bearing (bearing wrapped to (−π, π]).
pub fn predict(x: &Pose, m: Point) -> (f64, f64) {
    let d1 = m[0] - x[0];
    let d2 = m[1] - x[1];
    (
        (d1 * d1 + d2 * d2).sqrt(),
        wrap_angle(d2.atan2(d1) - x[2] + FRAC_PI_2),
    )
}

/// Whether m is in the forward half circle of radius `max_range`.
pub fn in_view(x: &Pose, m: Point, max_range: f64) -> bool {
    let (r, b) = predict(x, m);
    r <= max_range && (0.0..=std::f64::consts::PI).contains(&b)
}

/// Which Hessian of a term to form.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Curvature {
    /// The exact Hessian (E12).
    Exact,
    /// Gauss–Newton: Jᵀ Σ₂⁻¹ J, always positive semi-definite.
    GaussNewton,
}

/// The value of one landmark term ½ε²/σ₁ + ½e²/σ₂.
pub fn term_cost(x: &Pose, m: Point, z: &Observation, n: &LaserNoise) -> f64 {
    let (r, b) = predict(x, m);
    let eps = r - z.range;
    let e = wrap_angle(z.bearing - b);
    0.5 * (eps * eps / n.var_range + e * e / n.var_bearing)
}

/// Add one landmark term's gradient and Hessian to `g`, `h`; returns its
/// value. Undefined at r = 0 (the laser on the landmark), where the returned
/// value is NaN.
pub fn add_term(
    x: &Pose,
    m: Point,
    z: &Observation,
    n: &LaserNoise,
    curv: Curvature,
    g: &mut Vector3<f64>,
    h: &mut Matrix3<f64>,
) -> f64 {
    let d1 = x[0] - m[0];
    let d2 = x[1] - m[1];
    let r2 = d1 * d1 + d2 * d2;
    let r = r2.sqrt();
    let eps = r - z.range;
    let theta = wrap_angle((-d2).atan2(-d1) - x[2] + FRAC_PI_2);
    let e = wrap_angle(z.bearing - theta);
    let (s1, s2) = (n.var_range, n.var_bearing);
    let r4 = r2 * r2;
    g[0] += d1 * eps / (s1 * r) + d2 * e / (s2 * r2);
    g[1] += d2 * eps / (s1 * r) - d1 * e / (s2 * r2);
    g[2] += e / s2;
    // Gauss–Newton part: Jᵀ Σ₂⁻¹ J with J rows (d/r, 0) and (−d₂/r², d₁/r², −1).
    let mut h11 = d1 * d1 / (s1 * r2) + d2 * d2 / (s2 * r4);
    let mut h12 = d1 * d2 / (s1 * r2) - d1 * d2 / (s2 * r4);
    let mut h22 = d2 * d2 / (s1 * r2) + d1 * d1 / (s2 * r4);
    if curv == Curvature::Exact {
        // Second-derivative terms ε ∇²r/σ₁ + e ∇²e/σ₂ (E12).
        h11 += eps * (1.0 / r - d1 * d1 / (r2 * r)) / s1 - 2.0 * e * d1 * d2 / (s2 * r4);
        h12 += -eps * d1 * d2 / (r2 * r) / s1 + e * (d1 * d1 - d2 * d2) / (s2 * r4);
        h22 += eps * (1.0 / r - d2 * d2 / (r2 * r)) / s1 + 2.0 * e * d1 * d2 / (s2 * r4);
    }
    let h13 = d2 / (s2 * r2);
    let h23 = -d1 / (s2 * r2);
    let h33 = 1.0 / s2;
    h[(0, 0)] += h11;
    h[(0, 1)] += h12;
    h[(1, 0)] += h12;
    h[(1, 1)] += h22;
    h[(0, 2)] += h13;
    h[(2, 0)] += h13;
    h[(1, 2)] += h23;
    h[(2, 1)] += h23;
    h[(2, 2)] += h33;
    0.5 * (eps * eps / s1 + e * e / s2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// Central differences of the term's value and of its analytic gradient.
    fn check(x: Pose, m: Point, z: Observation, n: LaserNoise) {
        let h = 1e-6;
        let mut g = Vector3::zeros();
        let mut hs = Matrix3::zeros();
        let v = add_term(&x, m, &z, &n, Curvature::Exact, &mut g, &mut hs);
        assert!((v - term_cost(&x, m, &z, &n)).abs() < 1e-9 * v.abs().max(1.0));
        let scale_g = g.norm().max(1.0);
        for k in 0..3 {
            let mut xp = x;
            let mut xm = x;
            xp[k] += h;
            xm[k] -= h;
            let fd = (term_cost(&xp, m, &z, &n) - term_cost(&xm, m, &z, &n)) / (2.0 * h);
            assert!(
                (fd - g[k]).abs() < 1e-5 * scale_g,
                "grad {k}: fd {fd} vs {}",
                g[k]
            );
            let (mut gp, mut gm) = (Vector3::zeros(), Vector3::zeros());
            let mut dummy = Matrix3::zeros();
            add_term(&xp, m, &z, &n, Curvature::Exact, &mut gp, &mut dummy);
            add_term(&xm, m, &z, &n, Curvature::Exact, &mut gm, &mut dummy);
            let col = (gp - gm) / (2.0 * h);
            let scale_h = hs.norm().max(1.0);
            for i in 0..3 {
                assert!(
                    (col[i] - hs[(i, k)]).abs() < 1e-5 * scale_h,
                    "hess ({i},{k}): fd {} vs {}",
                    col[i],
                    hs[(i, k)]
                );
            }
        }
    }

    #[test]
    fn gradient_and_hessian_match_finite_differences() {
        let n = LaserNoise::default();
        // Several geometries: landmark ahead, left, behind-right; large
        // innovations so the ε and e second-order terms matter.
        let cases = [
            (Pose::new(0.0, 0.0, 0.3), [8.0, 3.0], 9.1, 1.0),
            (Pose::new(2.0, -1.0, 2.5), [-4.0, 5.0], 7.0, 2.2),
            (Pose::new(-3.0, 4.0, -1.2), [1.0, -2.0], 6.5, 0.4),
            (Pose::new(0.5, 0.5, 0.0), [0.9, 14.0], 13.0, -0.7),
        ];
        for (x, m, zr, zb) in cases {
            check(
                x,
                m,
                Observation {
                    range: zr,
                    bearing: zb,
                    landmark: 0,
                },
                n,
            );
        }
        // The other Σ₂ reading (standard deviations squared).
        let n2 = LaserNoise {
            var_range: 0.05 * 0.05,
            var_bearing: (0.05 * PI / 180.0).powi(2),
        };
        check(
            Pose::new(1.0, 2.0, 0.1),
            [6.0, 9.0],
            Observation {
                range: 8.0,
                bearing: 0.6,
                landmark: 0,
            },
            n2,
        );
    }

    /// Angle wrap: the predicted bearing straddles ±π (landmark behind-left
    /// with the heading turned), and an innovation near π; both are wrapped,
    /// so the derivatives stay those of the smooth branch.
    #[test]
    fn derivatives_hold_across_the_angle_wrap() {
        let n = LaserNoise::default();
        // Raw atan2 − β + π/2 = 2.944 − 1.3 + 1.571 ≈ 3.215 > π, wrapped to
        // ≈ −3.068; the observed 3.1 then gives a wrapped innovation ≈ −0.115.
        let x = Pose::new(0.0, 0.0, 1.3);
        let m = [-5.0, 1.0];
        let (_, b) = predict(&x, m);
        assert!(b < -3.0 && b > -PI, "{b}");
        check(
            x,
            m,
            Observation {
                range: 5.0,
                bearing: 3.1,
                landmark: 0,
            },
            n,
        );
        // Innovation z₂ − θ̂ close to +π and close to −π.
        let x = Pose::new(1.0, 1.0, 0.2);
        let m = [6.0, 4.0];
        let (_, b) = predict(&x, m);
        check(
            x,
            m,
            Observation {
                range: 6.0,
                bearing: wrap_angle(b + PI - 0.05),
                landmark: 0,
            },
            n,
        );
        check(
            x,
            m,
            Observation {
                range: 6.0,
                bearing: wrap_angle(b - PI + 0.05),
                landmark: 0,
            },
            n,
        );
    }

    #[test]
    fn gauss_newton_curvature_is_positive_semidefinite_and_exact_at_zero_residual() {
        let n = LaserNoise::default();
        let x = Pose::new(1.0, -1.0, 0.4);
        let m = [7.0, 2.0];
        let (r, b) = predict(&x, m);
        let z = Observation {
            range: r,
            bearing: b,
            landmark: 0,
        };
        let (mut g1, mut h1, mut g2, mut h2) = (
            Vector3::zeros(),
            Matrix3::zeros(),
            Vector3::zeros(),
            Matrix3::zeros(),
        );
        add_term(&x, m, &z, &n, Curvature::Exact, &mut g1, &mut h1);
        add_term(&x, m, &z, &n, Curvature::GaussNewton, &mut g2, &mut h2);
        assert!(g1.norm() < 1e-9);
        assert!((h1 - h2).norm() < 1e-9 * h1.norm());
        let ev = h2.symmetric_eigenvalues();
        assert!(ev.min() > -1e-9 * ev.max());
    }

    #[test]
    fn field_of_view_is_the_forward_half_circle() {
        let x = Pose::new(0.0, 0.0, 0.0); // facing +x
        assert!(in_view(&x, [10.0, 0.0], 15.0));
        assert!(in_view(&x, [0.1, 10.0], 15.0));
        assert!(!in_view(&x, [-0.1, 10.0], 15.0));
        assert!(!in_view(&x, [16.0, 0.0], 15.0));
        let (_, b) = predict(&x, [10.0, 0.0]);
        assert!((b - FRAC_PI_2).abs() < 1e-15);
    }
}
