//! The interval prior both the MCL filters and the particle SLAM filters
//! use: between steps with measurements a particle follows the mean model
//! and accumulates its noise, linearised (as EKF prediction),
//!
//! ```text
//! x ← f(x, u),  C ← F C Fᵀ + Σ₁(β),  F = ∂f/∂x at x,  Σ₁(β) = T(β) Σ₀ T(β)ᵀ
//! ```
//!
//! and at the next step with measurements its pose has the prior
//! N(f, F C Fᵀ + Σ₁(β)) ([`StepPrior`]), from which the proposal draws the
//! whole interval's noise at once.
//!
//! Why: measurements arrive at a fraction of the odometry rate (Victoria
//! Park and the car park: one scan per ≈ 9 odometry steps; the car park has
//! 2 s laser gaps too). Drawing every step's noise from the motion model as
//! it comes leaves only the last step's noise to the proposal (implicit
//! sampling's Newton and linear map, FastSLAM 2.0's Gaussian), so the
//! measurements steer 1/k of the interval's spread and the rest is left to
//! the weights. The linearised interval transition
//! x_k | x_0 ~ N(f∘…∘f(x_0), C) is the one approximation, second order in
//! the interval's heading spread.

use crate::geometry::{frame_rotation, Pose};
use crate::slam::ekf::motion_jacobian;
use crate::vehicle::{Control, StepNoise, Ute};
use nalgebra::{Matrix3, Vector3};

/// One step's motion constants: the vehicle, Σ₀'s factor and inverse, Σ₀
/// (body frame) and the one-step density's normaliser −½ log det Σ₁
/// (= −½ log det Σ₀, the same at every heading).
#[derive(Clone, Copy, Debug)]
pub struct MotionStep<'a> {
    pub ute: &'a Ute,
    pub noise: &'a StepNoise,
    /// Σ₀ = C₀ C₀ᵀ.
    pub s0: Matrix3<f64>,
    /// −½ log det Σ₁.
    pub motion_norm: f64,
}

impl<'a> MotionStep<'a> {
    pub fn new(ute: &'a Ute, noise: &'a StepNoise) -> Self {
        Self {
            ute,
            noise,
            s0: noise.chol * noise.chol.transpose(),
            motion_norm: -(0..3).map(|i| noise.chol[(i, i)].ln()).sum::<f64>(),
        }
    }

    /// A step without measurements under the interval prior: `x` follows
    /// the mean model and `c` accumulates the step's noise,
    /// C ← F C Fᵀ + Σ₁(β) with F and β at the pose before the step.
    pub fn accumulate(&self, x: &mut Pose, c: &mut Matrix3<f64>, u: Control) {
        let fx = motion_jacobian(self.ute, x[2], u);
        let t = frame_rotation(x[2]);
        *c = fx * *c * fx.transpose() + t * self.s0 * t.transpose();
        *x = self.ute.predict_mean(x, u);
    }

    /// The prior of a particle at pose `x` with accumulated noise `acc`.
    /// With `acc` = 0 it is the one step's N(f, Σ₁), computed exactly as
    /// the motion model draws it ([`StepNoise::draw`], same rounding).
    pub fn prior(&self, x: &Pose, acc: &Matrix3<f64>, u: Control) -> StepPrior {
        let f = self.ute.predict_mean(x, u);
        let t = frame_rotation(x[2]);
        let step = StepPrior {
            f,
            cov: t * self.s0 * t.transpose(),
            prec: self.noise.precision(x[2]),
            norm: self.motion_norm,
            factor: None,
            beta: x[2],
            chol0: self.noise.chol,
        };
        if *acc == Matrix3::zeros() {
            return step;
        }
        let fx = motion_jacobian(self.ute, x[2], u);
        let cov = fx * acc * fx.transpose() + step.cov;
        let cov = 0.5 * (cov + cov.transpose());
        match cov.cholesky() {
            Some(ch) => {
                let l = ch.l();
                StepPrior {
                    cov,
                    prec: ch.inverse(),
                    norm: -(0..3).map(|i| l[(i, i)].ln()).sum::<f64>(),
                    factor: Some(l),
                    ..step
                }
            }
            None => step,
        }
    }
}

/// One particle's prior for its pose at a step with measurements: N(f, Σ)
/// with Σ = F C Fᵀ + Σ₁(β), C the noise accumulated since its last step
/// with measurements ([`MotionStep::accumulate`]); Σ = Σ₁(β) when C = 0.
#[derive(Clone, Copy, Debug)]
pub struct StepPrior {
    /// The mean prediction f(x, u).
    pub f: Pose,
    /// Σ (world frame).
    pub cov: Matrix3<f64>,
    /// Σ⁻¹.
    pub prec: Matrix3<f64>,
    /// −½ log det Σ: the prior density's normaliser. It differs between
    /// particles once C ≠ 0, so a weight with the prior's density in it
    /// (implicit sampling's) must keep it.
    pub norm: f64,
    /// A factor of Σ for draws; `None`: the step's own T(β) C₀.
    factor: Option<Matrix3<f64>>,
    beta: f64,
    chol0: Matrix3<f64>,
}

impl StepPrior {
    /// A draw f + Σ^{1/2} ξ.
    pub fn draw(&self, xi: &Vector3<f64>) -> Pose {
        match &self.factor {
            Some(c) => self.f + c * xi,
            None => self.f + frame_rotation(self.beta) * (self.chol0 * xi),
        }
    }
}
