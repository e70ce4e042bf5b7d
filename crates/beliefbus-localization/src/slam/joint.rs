//! The joint objective of implicit SLAM for a newly seen feature (paper 003
//! §4.2, the notes' §1.7 with the ½ of erratum E9):
//!
//! ```text
//! F^j(x, θ) = ½ (x − f^j)ᵀ Σ₁⁻¹ (x − f^j) + ½ ‖z − h(x, θ)‖²_{Σ₂⁻¹},   v = (x₁, x₂, β, θ₁, θ₂)
//! ```
//!
//! The landmark term depends on the position only through d = x₁₂ − θ, so
//! with g₃, H₃ its gradient and Hessian in (x₁, x₂, β) (the corrected E12 of
//! [`crate::laser::add_term`]):
//!
//! ```text
//! ∇_θ = −g₃[0..2],  ∇²_θθ = H₃[0..2, 0..2],  ∇²_{x₁₂ θ} = −H₃[0..2, 0..2],  ∇²_{β θ} = −H₃[2, 0..2]
//! ```
//!
//! Newton (5×5 Cholesky, backtracking, Gauss–Newton where the exact Hessian
//! is not positive definite) starts at (f^j, g(f^j, z)), the prediction and
//! the inverse observation from it. With a flat prior on θ that point is the
//! minimiser (F = 0 there), so Newton confirms it in zero steps; the
//! iteration is kept so the objective can carry other terms.

use super::assoc::{inverse, RangeBearing};
use crate::error::LocalizationError;
use crate::geometry::{wrap_angle, Pose};
use crate::laser::{add_term, term_cost, Curvature, LaserNoise, Observation};
use nalgebra::{Matrix3, Matrix5, Vector3, Vector5};

/// F^j(x, θ) for one particle and one new feature.
#[derive(Clone, Copy, Debug)]
pub struct JointObjective {
    pub f: Pose,
    /// Σ₁⁻¹ at the particle's heading.
    pub prec: Matrix3<f64>,
    pub z: RangeBearing,
    pub laser: LaserNoise,
}

fn obs(z: &RangeBearing) -> Observation {
    Observation {
        range: z.range,
        bearing: z.bearing,
        landmark: 0,
    }
}

impl JointObjective {
    fn prior_diff(&self, v: &Vector5<f64>) -> Vector3<f64> {
        let mut d = Vector3::new(v[0] - self.f[0], v[1] - self.f[1], v[2] - self.f[2]);
        d[2] = wrap_angle(d[2]);
        d
    }

    /// F(v).
    pub fn value(&self, v: &Vector5<f64>) -> f64 {
        let d = self.prior_diff(v);
        let x = Pose::new(v[0], v[1], v[2]);
        0.5 * d.dot(&(self.prec * d)) + term_cost(&x, [v[3], v[4]], &obs(&self.z), &self.laser)
    }

    /// F(v) with its gradient and Hessian (exact or Gauss–Newton).
    pub fn eval(
        &self,
        v: &Vector5<f64>,
        curv: Curvature,
        g: &mut Vector5<f64>,
        h: &mut Matrix5<f64>,
    ) -> f64 {
        let d = self.prior_diff(v);
        let pd = self.prec * d;
        let x = Pose::new(v[0], v[1], v[2]);
        let (mut g3, mut h3) = (Vector3::zeros(), Matrix3::zeros());
        let t = add_term(
            &x,
            [v[3], v[4]],
            &obs(&self.z),
            &self.laser,
            curv,
            &mut g3,
            &mut h3,
        );
        *h = Matrix5::zeros();
        for i in 0..3 {
            g[i] = pd[i] + g3[i];
            for j in 0..3 {
                h[(i, j)] = self.prec[(i, j)] + h3[(i, j)];
            }
        }
        for a in 0..2 {
            g[3 + a] = -g3[a];
            for b in 0..2 {
                h[(3 + a, 3 + b)] = h3[(a, b)];
            }
            for i in 0..3 {
                h[(i, 3 + a)] = -h3[(i, a)];
                h[(3 + a, i)] = -h3[(i, a)];
            }
        }
        0.5 * d.dot(&pd) + t
    }
}

/// The minimum of a joint objective.
#[derive(Clone, Copy, Debug)]
pub struct JointMinimum {
    pub mu: Vector5<f64>,
    pub phi: f64,
    /// Lower Cholesky factor of the Hessian at μ.
    pub l: Matrix5<f64>,
    pub log_det_l: f64,
    pub iters: usize,
}

fn factor(
    obj: &JointObjective,
    v: &Vector5<f64>,
    g: &mut Vector5<f64>,
    h: &mut Matrix5<f64>,
) -> Option<(f64, Matrix5<f64>)> {
    let val = obj.eval(v, Curvature::Exact, g, h);
    if let Some(c) = h.cholesky() {
        return Some((val, c.l()));
    }
    let val = obj.eval(v, Curvature::GaussNewton, g, h);
    h.cholesky().map(|c| (val, c.l()))
}

/// Newton from (f, g(f, z)).
pub fn minimise_joint(
    obj: &JointObjective,
    max_iter: usize,
    tol: f64,
    step: usize,
) -> Result<JointMinimum, LocalizationError> {
    let bad = || LocalizationError::NonFinite {
        what: "joint Newton iterate",
        step,
    };
    let (m0, _, _) = inverse(&obj.f, &obj.z);
    let mut v = Vector5::new(obj.f[0], obj.f[1], obj.f[2], m0[0], m0[1]);
    let (mut g, mut h) = (Vector5::zeros(), Matrix5::zeros());
    let (mut gn, mut hn) = (Vector5::zeros(), Matrix5::zeros());
    let (mut val, mut l) = factor(obj, &v, &mut g, &mut h).ok_or_else(bad)?;
    let mut iters = 0;
    while iters < max_iter {
        let y = l.solve_lower_triangular(&g).ok_or_else(bad)?;
        let dir = -l.tr_solve_lower_triangular(&y).ok_or_else(bad)?;
        let dec = -g.dot(&dir);
        if !dec.is_finite() {
            return Err(bad());
        }
        if dec < tol {
            break;
        }
        let mut t = 1.0;
        let mut accepted = false;
        for _ in 0..30 {
            let vn = v + dir * t;
            let fv = obj.eval(&vn, Curvature::Exact, &mut gn, &mut hn);
            if fv <= val - 1e-4 * t * dec {
                v = vn;
                val = fv;
                g = gn;
                l = match hn.cholesky() {
                    Some(c) => c.l(),
                    None => {
                        obj.eval(&v, Curvature::GaussNewton, &mut g, &mut h);
                        h.cholesky().ok_or_else(bad)?.l()
                    }
                };
                accepted = true;
                break;
            }
            t *= 0.5;
        }
        iters += 1;
        if !accepted {
            break;
        }
    }
    if !val.is_finite() || !v.iter().all(|c| c.is_finite()) {
        return Err(bad());
    }
    let log_det_l = (0..5).map(|i| l[(i, i)].ln()).sum();
    Ok(JointMinimum {
        mu: v,
        phi: val,
        l,
        log_det_l,
        iters,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn check_fd(obj: &JointObjective, v: Vector5<f64>) {
        let (mut g, mut h) = (Vector5::zeros(), Matrix5::zeros());
        let val = obj.eval(&v, Curvature::Exact, &mut g, &mut h);
        assert!((val - obj.value(&v)).abs() < 1e-9 * val.abs().max(1.0));
        let e = 1e-6;
        let sg = g.norm().max(1.0);
        let sh = h.norm().max(1.0);
        for k in 0..5 {
            let (mut vp, mut vm) = (v, v);
            vp[k] += e;
            vm[k] -= e;
            let fd = (obj.value(&vp) - obj.value(&vm)) / (2.0 * e);
            assert!((fd - g[k]).abs() < 1e-5 * sg, "grad {k}: {fd} vs {}", g[k]);
            let (mut gp, mut gm) = (Vector5::zeros(), Vector5::zeros());
            let mut dummy = Matrix5::zeros();
            obj.eval(&vp, Curvature::Exact, &mut gp, &mut dummy);
            obj.eval(&vm, Curvature::Exact, &mut gm, &mut dummy);
            let col = (gp - gm) / (2.0 * e);
            for i in 0..5 {
                assert!(
                    (col[i] - h[(i, k)]).abs() < 1e-5 * sh,
                    "hess ({i},{k}): {} vs {}",
                    col[i],
                    h[(i, k)]
                );
            }
        }
    }

    fn prec() -> Matrix3<f64> {
        Matrix3::new(40.0, 3.0, -1.0, 3.0, 30.0, 2.0, -1.0, 2.0, 500.0)
    }

    #[test]
    fn joint_gradient_and_hessian_match_finite_differences() {
        let laser = LaserNoise::default();
        let obj = JointObjective {
            f: Pose::new(0.2, -0.1, 0.4),
            prec: prec(),
            z: RangeBearing {
                range: 9.0,
                bearing: 1.2,
            },
            laser,
        };
        // Away from the minimum in every coordinate.
        check_fd(&obj, Vector5::new(0.5, 0.3, 0.3, 6.0, 4.0));
        check_fd(&obj, Vector5::new(-1.0, 2.0, -2.0, -5.0, 1.0));
    }

    /// The predicted bearing and the prior's heading difference straddle ±π.
    #[test]
    fn joint_derivatives_hold_across_the_angle_wrap() {
        let laser = LaserNoise::default();
        let obj = JointObjective {
            f: Pose::new(0.0, 0.0, PI - 0.02),
            prec: prec(),
            z: RangeBearing {
                range: 5.0,
                bearing: 3.1,
            },
            laser,
        };
        // β = −π + 0.03: the raw difference to f's heading is ≈ −2π + 0.05.
        let v = Vector5::new(0.1, 0.05, -PI + 0.03, 0.3, -4.95);
        let x = Pose::new(v[0], v[1], v[2]);
        let (_, b) = crate::laser::predict(&x, [v[3], v[4]]);
        assert!(b.abs() > 3.0, "{b}");
        check_fd(&obj, v);
    }

    #[test]
    fn newton_from_the_inverse_observation_is_at_the_minimum() {
        let obj = JointObjective {
            f: Pose::new(1.0, 2.0, 0.7),
            prec: prec(),
            z: RangeBearing {
                range: 12.0,
                bearing: 0.4,
            },
            laser: LaserNoise::default(),
        };
        let m = minimise_joint(&obj, 20, 1e-10, 0).unwrap();
        assert!(m.phi.abs() < 1e-20 && m.iters == 0);
        let (mut g, mut h) = (Vector5::zeros(), Matrix5::zeros());
        obj.eval(&m.mu, Curvature::Exact, &mut g, &mut h);
        assert!(g.norm() < 1e-9);
        assert!((m.l * m.l.transpose() - h).norm() < 1e-8 * h.norm());
        // A perturbed start still converges there: minimise from a shifted f
        // through an objective whose z is off the start point.
        for k in 0..5 {
            for s in [-1e-3, 1e-3] {
                let mut v = m.mu;
                v[k] += s;
                assert!(obj.value(&v) > m.phi);
            }
        }
    }
}
