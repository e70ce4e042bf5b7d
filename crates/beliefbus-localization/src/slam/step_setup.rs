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
use crate::geometry::{Point, Pose};
use crate::mcl::interval_prior::MotionStep;
pub use crate::mcl::interval_prior::StepPrior;
use crate::vehicle::{Control, StepNoise, Ute};
use beliefbus_core::rng::SimRng;
use nalgebra::{Matrix2, Matrix3};

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

impl StepSetup {
    /// The prior of a particle at pose `x` with accumulated noise `acc`
    /// ([`MotionStep::prior`], shared with MCL): with `acc` = 0 the one
    /// step's N(f, Σ₁), computed exactly as the motion model draws it.
    ///
    /// Why the interval prior: returns arrive at a fraction of the
    /// odometry rate (Victoria Park: one scan per 8.6 odometry steps; the
    /// synthetic car park: none for 80 steps in a laser gap), and with it
    /// the whole interval's noise is drawn from the proposal and gated with
    /// (EKF-SLAM's gate sees the whole interval's P_xx too).
    pub fn prior(&self, x: &Pose, acc: &Matrix3<f64>, u: Control) -> StepPrior {
        self.motion().prior(x, acc, u)
    }

    /// The step's motion constants.
    pub fn motion(&self) -> MotionStep<'_> {
        MotionStep {
            ute: &self.ute,
            noise: &self.noise,
            s0: self.s0,
            motion_norm: self.motion_norm,
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
    let MotionStep {
        s0, motion_norm, ..
    } = MotionStep::new(&ute, &noise);
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
