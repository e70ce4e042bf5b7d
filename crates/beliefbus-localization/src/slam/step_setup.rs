//! What every particle SLAM filter's step does before its per-particle
//! loop: count the step, build the vehicle and Σ₁ for its length, move the
//! particles by the motion model alone when no return arrived, otherwise
//! the constants of the weights (Σ₂, ½ log det Σ₂, log 2π, the
//! new-landmark density log(1/A), Σ₁ in the body frame and −½ log det Σ₁)
//! and, with shared association, one association per return for the whole
//! set ([`super::shared_assoc`]).

use super::assoc::{Forced, RangeBearing};
use super::particles::SlamParticles;
use super::scan_assoc::ScanAssoc;
use super::shared_assoc::shared_offers;
use super::{SlamModel, SlamStats};
use crate::error::LocalizationError;
use crate::geometry::{frame_rotation, Point, Pose};
use crate::vehicle::{Control, StepNoise, Ute};
use beliefbus_core::rng::SimRng;
use nalgebra::{Matrix2, Matrix3, Vector3};

/// The step's constants.
pub struct StepSetup {
    /// The step's number (from 1).
    pub step: usize,
    pub ute: Ute,
    pub noise: StepNoise,
    pub model: SlamModel,
    /// Σ₂.
    pub r: Matrix2<f64>,
    /// ½ log det Σ₂.
    pub half_logdet_r: f64,
    pub ln2pi: f64,
    /// log(1/A), the new-landmark prior density.
    pub log_new: f64,
    /// Σ₁ in the body frame.
    pub s0: Matrix3<f64>,
    /// −½ log det Σ₁: the motion density's normaliser, which the linear
    /// map's weight keeps and a motion-model proposal cancels.
    pub motion_norm: f64,
}

/// One particle's prior for its pose at this step: N(f, Σ) with
/// Σ = F C Fᵀ + Σ₁(β), C the noise accumulated since its last step with
/// returns ([`SlamParticles::predict_only`]); Σ = Σ₁(β) when C = 0.
///
/// Why: returns arrive at a fraction of the odometry rate (Victoria Park:
/// one scan per 8.6 odometry steps; the synthetic car park: none for 80
/// steps in a laser gap). Drawing every step's noise from the motion model
/// as it comes leaves only the last step's noise to the proposal (FastSLAM
/// 2.0's Gaussian, implicit sampling's Newton), so the returns correct
/// 1/k of the interval's spread and the rest is left to the weights; the
/// association gate sees one step's Σ₁ where EKF-SLAM's sees the whole
/// interval's P_xx. With C the whole interval's noise is drawn from the
/// proposal and gated with. The interval's transition is the linearised
/// Gaussian of EKF-SLAM's prediction, x_k | x_0 ~ N(f∘…∘f(x_0), C): the
/// one approximation, second order in the interval's heading spread.
#[derive(Clone, Copy, Debug)]
pub struct StepPrior {
    /// The mean prediction f(x, u).
    pub f: Pose,
    /// Σ (world frame).
    pub cov: Matrix3<f64>,
    /// Σ⁻¹.
    pub prec: Matrix3<f64>,
    /// −½ log det Σ: the prior density's normaliser.
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

impl StepSetup {
    /// The prior of a particle at pose `x` with accumulated noise `acc`.
    /// With `acc` = 0 it is the one step's N(f, Σ₁), computed exactly as
    /// before the accumulation existed (same draws, same rounding).
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
        let fx = super::ekf::motion_jacobian(&self.ute, x[2], u);
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

/// How a step goes on. Returned by value once per step: boxing the large
/// variant would allocate on the hot path.
#[allow(clippy::large_enum_variant)]
pub enum Begin {
    /// No return: the particles moved by the motion model; the estimate.
    Predicted(Pose),
    /// Returns to take in, with the step's constants.
    Update(StepSetup),
}

/// A particle filter's own state that the set-up touches.
pub struct FilterParts<'a, L: Clone> {
    pub model: &'a SlamModel,
    pub set: &'a mut SlamParticles<L>,
    pub step: &'a mut usize,
    pub stats: &'a mut SlamStats,
    pub forced: &'a mut Forced,
    pub shared: bool,
    /// The scan's association buffers (and whether returns exclude each other).
    pub scan: &'a mut ScanAssoc,
}

/// Start a step of a particle filter; `lm` gives a landmark's position and
/// covariance for the shared association.
pub fn begin_step<L: Clone>(
    p: FilterParts<'_, L>,
    u: Control,
    dt: f64,
    obs: &[RangeBearing],
    rng: &mut SimRng,
    lm: impl Fn(&L) -> (Point, Matrix2<f64>),
) -> Result<Begin, LocalizationError> {
    *p.step += 1;
    let step = *p.step;
    let (ute, noise) = p.model.step_noise(u, dt)?;
    if obs.is_empty() {
        return Ok(Begin::Predicted(p.set.predict_only(&ute, &noise, u, rng)));
    }
    p.stats.updates += 1;
    let model = *p.model;
    let r = model.r();
    let s0 = noise.chol * noise.chol.transpose();
    if p.shared && p.forced.is_empty() {
        p.scan.begin(obs.len());
        let aligned = obs.iter().enumerate().all(|(i, z)| {
            shared_offers(p.set, &ute, u, &s0, &r, z, i, &model.assoc, &lm, p.scan).is_some()
        });
        if aligned {
            for &a in p.scan.decide(&model.assoc) {
                p.forced.push(a);
            }
        }
    }
    let motion_norm = -(0..3).map(|i| noise.chol[(i, i)].ln()).sum::<f64>();
    Ok(Begin::Update(StepSetup {
        step,
        ute,
        noise,
        model,
        r,
        half_logdet_r: 0.5 * (r[(0, 0)] * r[(1, 1)]).ln(),
        ln2pi: (2.0 * std::f64::consts::PI).ln(),
        log_new: model.log_new_density(),
        s0,
        motion_norm,
    }))
}
