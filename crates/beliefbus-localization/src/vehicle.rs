//! The Ute vehicle of paper 003 (appendix, Table 7) with the corrected
//! laser-point kinematics (erratum E10 of the notes):
//!
//! ```text
//! v_c = L v_l / (L − H tan α)                      (wheel speed → rear-axle centre)
//! R(x, u) = ( v_c (cos β − tan α / L · (a sin β + b cos β)),
//!             v_c (sin β + tan α / L · (a cos β − b sin β)),
//!             v_c tan α / L )
//! x_n = x_{n−1} + R(x_{n−1}, u_n) δ + ΔB_n,   ΔB_n ~ N(0, Σ₁)
//! Σ₁ = δ (∂R/∂u P ∂R/∂uᵀ + Q)
//! ```
//!
//! ∂R/∂u is the world-frame rotation T(β) of a heading-free matrix G(u), so
//! with an isotropic position part of Q, Σ₁ = T(β) Σ₀(u) T(β)ᵀ with
//! Σ₀ = δ(G P Gᵀ + Q): one Cholesky factor per step serves every particle,
//! and det Σ₁ does not depend on the particle (it cancels from the weights).
//!
//! P and Q are read as covariances (intensities of the white noises dW_u and
//! dW), as Table 7 labels them; σ₁, σ₂ of the laser likewise (see
//! [`crate::laser`]).

use crate::error::LocalizationError;
use crate::geometry::{frame_rotation, Pose};
use nalgebra::{Matrix3, Matrix3x2, Vector3};

/// Vehicle geometry and time step (Table 7).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ute {
    /// Wheel base L (m).
    pub l: f64,
    /// Lateral offset H of the speed-encoder wheel from the centreline (m).
    pub h: f64,
    /// Rear axle to laser, forward (m).
    pub a: f64,
    /// Lateral offset b of the laser (m).
    pub b: f64,
    /// Time step δ (s).
    pub dt: f64,
}

impl Default for Ute {
    fn default() -> Self {
        Self {
            l: 2.83,
            h: 0.76,
            a: 3.78,
            b: 0.5,
            dt: 0.025,
        }
    }
}

/// A control u = (v_c, α): rear-axle-centre speed (m/s) and steering (rad).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Control {
    pub v: f64,
    pub alpha: f64,
}

/// Noise intensities of Table 7: P of the controls (v_c, α), Q of the model
/// (x, y, β), each a diagonal covariance per unit time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionNoise {
    pub p: [f64; 2],
    pub q: [f64; 3],
}

impl Default for MotionNoise {
    fn default() -> Self {
        Self {
            p: [0.5, 0.5],
            q: [0.1, 0.1, 0.1 * std::f64::consts::PI / 180.0],
        }
    }
}

impl MotionNoise {
    /// Every entry finite and > 0, and Q₁₁ = Q₂₂ (so Σ₁ rotates with β).
    pub fn validate(&self) -> Result<(), LocalizationError> {
        for (name, v) in [
            ("P11", self.p[0]),
            ("P22", self.p[1]),
            ("Q11", self.q[0]),
            ("Q22", self.q[1]),
            ("Q33", self.q[2]),
        ] {
            LocalizationError::positive(name, v)?;
        }
        if self.q[0] != self.q[1] {
            return Err(LocalizationError::Invalid {
                name: "Q22",
                value: self.q[1],
                need: "must equal Q11 (an isotropic position noise)",
            });
        }
        Ok(())
    }
}

impl Ute {
    /// v_c = L v_l / (L − H tan α); an error where the denominator is not
    /// positive (|α| near π/2) or an input is not finite.
    pub fn centre_speed(&self, v_wheel: f64, alpha: f64) -> Result<f64, LocalizationError> {
        let den = self.l - alpha.tan() * self.h;
        if !(den > 0.0) || !v_wheel.is_finite() {
            return Err(LocalizationError::Invalid {
                name: "steering",
                value: alpha,
                need: "gives L − H tan α ≤ 0 or a non-finite speed",
            });
        }
        Ok(self.l * v_wheel / den)
    }

    /// The corrected kinematics R(x, u) (E10).
    pub fn drift(&self, x: &Pose, u: Control) -> Vector3<f64> {
        let (s, c) = x[2].sin_cos();
        let k = u.alpha.tan() / self.l;
        Vector3::new(
            u.v * (c - k * (self.a * s + self.b * c)),
            u.v * (s + k * (self.a * c - self.b * s)),
            u.v * k,
        )
    }

    /// The predicted mean f = x + R(x, u) δ.
    pub fn predict_mean(&self, x: &Pose, u: Control) -> Pose {
        x + self.drift(x, u) * self.dt
    }

    /// G(u) = ∂R/∂u at β = 0; ∂R/∂u(β) = T(β) G(u).
    pub fn control_jacobian_body(&self, u: Control) -> Matrix3x2<f64> {
        let t = u.alpha.tan();
        let (l, a, b) = (self.l, self.a, self.b);
        let ca = u.alpha.cos();
        let g = u.v / (l * ca * ca);
        Matrix3x2::new(1.0 - t * b / l, -g * b, t * a / l, g * a, t / l, g)
    }

    /// ∂R/∂u at heading β (columns ∂R/∂v_c, ∂R/∂α).
    pub fn control_jacobian(&self, beta: f64, u: Control) -> Matrix3x2<f64> {
        frame_rotation(beta) * self.control_jacobian_body(u)
    }

    /// The body-frame step covariance Σ₀(u) = δ (G P Gᵀ + Q).
    pub fn step_covariance_body(&self, u: Control, noise: &MotionNoise) -> Matrix3<f64> {
        let g = self.control_jacobian_body(u);
        let p = nalgebra::Matrix2::new(noise.p[0], 0.0, 0.0, noise.p[1]);
        let q = Matrix3::from_diagonal(&Vector3::new(noise.q[0], noise.q[1], noise.q[2]));
        (g * p * g.transpose() + q) * self.dt
    }
}

/// The per-step motion noise shared by all particles: the Cholesky factor C₀
/// of Σ₀(u) and Σ₀⁻¹; particle j uses T(β_j) C₀ and T(β_j) Σ₀⁻¹ T(β_j)ᵀ.
#[derive(Clone, Copy, Debug)]
pub struct StepNoise {
    pub chol: Matrix3<f64>,
    pub inv: Matrix3<f64>,
}

impl StepNoise {
    /// Factor Σ₀(u).
    pub fn new(ute: &Ute, u: Control, noise: &MotionNoise) -> Result<Self, LocalizationError> {
        let s = ute.step_covariance_body(u, noise);
        let ch = s
            .cholesky()
            .ok_or(LocalizationError::NotPositiveDefinite("Σ₀"))?;
        Ok(Self {
            chol: ch.l(),
            inv: ch.inverse(),
        })
    }

    /// A world-frame draw T(β) C₀ ξ of the step noise.
    pub fn draw(&self, beta: f64, xi: &Vector3<f64>) -> Vector3<f64> {
        frame_rotation(beta) * (self.chol * xi)
    }

    /// Σ₁⁻¹ = T(β) Σ₀⁻¹ T(β)ᵀ.
    pub fn precision(&self, beta: f64) -> Matrix3<f64> {
        let t = frame_rotation(beta);
        t * self.inv * t.transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::laser_point;

    /// R(x, u) is the time derivative of the laser point of a rear axle
    /// moving by ẋc = v cos β, ẏc = v sin β, β̇ = v tan α / L (the check that
    /// found E10): central differences of the laser-position relation.
    #[test]
    fn kinematics_match_the_derivative_of_the_laser_position() {
        let ute = Ute::default();
        let u = Control {
            v: 3.2,
            alpha: 0.31,
        };
        let (xc, yc, beta) = (1.0, -2.0, 0.9);
        let h = 1e-6;
        let rear = |t: f64| {
            let b = beta + u.v * u.alpha.tan() / ute.l * t;
            let p = laser_point(
                xc + u.v * beta.cos() * t,
                yc + u.v * beta.sin() * t,
                b,
                ute.a,
                ute.b,
            );
            // Only the first-order motion matters at t → 0.
            (p, b)
        };
        let (p1, b1) = rear(h);
        let (p0, b0) = rear(-h);
        let fd = Vector3::new(
            (p1[0] - p0[0]) / (2.0 * h),
            (p1[1] - p0[1]) / (2.0 * h),
            (b1 - b0) / (2.0 * h),
        );
        let x0 = laser_point(xc, yc, beta, ute.a, ute.b);
        let r = ute.drift(&Pose::new(x0[0], x0[1], beta), u);
        assert!((r - fd).norm() < 1e-6, "{r} vs {fd}");
    }

    #[test]
    fn control_jacobian_matches_finite_differences() {
        let ute = Ute::default();
        let x = Pose::new(0.3, 0.4, -2.2);
        let u = Control {
            v: 2.0,
            alpha: -0.2,
        };
        let j = ute.control_jacobian(x[2], u);
        let h = 1e-6;
        let dv = (ute.drift(&x, Control { v: u.v + h, ..u })
            - ute.drift(&x, Control { v: u.v - h, ..u }))
            / (2.0 * h);
        let da = (ute.drift(
            &x,
            Control {
                alpha: u.alpha + h,
                ..u
            },
        ) - ute.drift(
            &x,
            Control {
                alpha: u.alpha - h,
                ..u
            },
        )) / (2.0 * h);
        assert!((j.column(0) - dv).norm() < 1e-7);
        assert!((j.column(1) - da).norm() < 1e-7);
    }

    #[test]
    fn rotated_step_noise_has_the_world_covariance() {
        let ute = Ute::default();
        let u = Control { v: 4.0, alpha: 0.1 };
        let n = MotionNoise::default();
        let sn = StepNoise::new(&ute, u, &n).unwrap();
        let beta = 1.3;
        let g = ute.control_jacobian(beta, u);
        let p = nalgebra::Matrix2::new(n.p[0], 0.0, 0.0, n.p[1]);
        let q = Matrix3::from_diagonal(&Vector3::new(n.q[0], n.q[1], n.q[2]));
        let want = (g * p * g.transpose() + q) * ute.dt;
        let t = frame_rotation(beta);
        let c = t * sn.chol;
        assert!((c * c.transpose() - want).norm() < 1e-12);
        assert!((sn.precision(beta) * want - Matrix3::identity()).norm() < 1e-9);
    }

    #[test]
    fn centre_speed_refuses_a_vertical_steering() {
        let ute = Ute::default();
        assert!((ute.centre_speed(2.0, 0.0).unwrap() - 2.0).abs() < 1e-15);
        assert!(ute.centre_speed(2.0, 1.5).is_err());
        let mut bad = MotionNoise::default();
        bad.q[1] = 0.2;
        assert!(bad.validate().is_err());
    }
}
