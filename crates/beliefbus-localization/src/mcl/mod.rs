//! Monte Carlo localization on a known map (paper 003 §4.1): implicit MCL
//! ([`implicit::ImplicitMcl`]) and standard MCL ([`standard::StandardMcl`])
//! share the particle set, the prediction between scans and the driver
//! [`run`]:
//!
//! ```text
//! no laser at step n:  X_n^j = f_n^j + ΔB^j,  f_n^j = X_{n−1}^j + R(X_{n−1}^j, u_n) δ,
//!                      weights unchanged (eq. 19)
//! laser at step n:     the filter's own update (proposal and weights),
//!                      then normalise, resample if ESS < threshold · M
//! estimate:            Σ_j W_n^j X_n^j
//! ```
//!
//! With the interval prior ([`interval_prior`], [`Localizer::set_interval_prior`])
//! a step without laser data moves each particle by the mean model and
//! accumulates its noise, C ← F C Fᵀ + Σ₁, and the next laser step's
//! proposal draws the whole interval's noise from N(f, F C Fᵀ + Σ₁).
//!
//! Both filters draw exactly three standard normals per particle per step
//! (with the interval prior: per laser step) from the generator they are
//! given (the motion noise, or ξ of the linear map) and one uniform per
//! resampling, so with the same seed they use the same random numbers
//! wherever the algorithms allow.

pub mod implicit;
pub mod interval_prior;
pub mod newton;
pub mod particles;
pub mod standard;

use crate::carpark::CarPark;
use crate::error::LocalizationError;
use crate::geometry::{Point, Pose};
use crate::laser::{LaserNoise, Observation};
use crate::vehicle::{Control, StepNoise, Ute};
use beliefbus_core::rng::SimRng;
use particles::ParticleSet;

/// What a laser step n gives a localizer: the vehicle, the control u_n and
/// its step noise, the scan's returns, the map they refer to and the
/// laser's noise.
#[derive(Clone, Copy, Debug)]
pub struct LaserStep<'a> {
    pub ute: &'a Ute,
    pub u: Control,
    pub noise: &'a StepNoise,
    pub obs: &'a [Observation],
    pub map: &'a [Point],
    pub laser: &'a LaserNoise,
    /// The step index n (for error messages).
    pub step: usize,
}

/// A particle localizer on a known map.
pub trait Localizer {
    /// The method's name in reports.
    fn name(&self) -> &'static str;
    fn particles(&self) -> &ParticleSet;
    fn particles_mut(&mut self) -> &mut ParticleSet;

    /// A laser step n: move each particle from X_{n−1} with control u and
    /// weight it by the scan `obs`, then reweight (and maybe resample).
    fn update(&mut self, s: &LaserStep, rng: &mut SimRng) -> Result<(), LocalizationError>;

    /// Newton steps and motion-model fallbacks so far (implicit MCL only).
    fn newton_stats(&self) -> Option<(usize, usize)> {
        None
    }

    /// A step without laser data ([`ParticleSet::predict`]): every
    /// particle moves by the motion model, or with the interval prior
    /// follows the mean model and accumulates its noise.
    fn predict(&mut self, ute: &Ute, u: Control, noise: &StepNoise, rng: &mut SimRng) {
        self.particles_mut().predict(ute, u, noise, rng);
    }

    /// Turn the interval prior on or off (off at construction).
    fn set_interval_prior(&mut self, on: bool) {
        self.particles_mut().deferred = on;
    }
}

/// The prior on the start pose: N(truth₀, diag(std²)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prior {
    pub std: Pose,
}

/// Run a localizer over a data set from the true start pose spread by
/// `prior`, calling `each(n, estimate)` after every step n = 1..=N.
pub fn run(
    filter: &mut dyn Localizer,
    cp: &CarPark,
    prior: &Prior,
    rng: &mut SimRng,
    mut each: impl FnMut(usize, &Pose),
) -> Result<(), LocalizationError> {
    filter.particles_mut().init(&cp.truth[0], &prior.std, rng);
    let mut scans = cp.scans.iter().peekable();
    for n in 1..=cp.steps() {
        let u = cp.controls[n - 1];
        let noise = StepNoise::new(&cp.ute, u, &cp.motion)?;
        match scans.next_if(|s| s.step == n) {
            Some(s) => filter.update(
                &LaserStep {
                    ute: &cp.ute,
                    u,
                    noise: &noise,
                    obs: cp.scan_obs(s),
                    map: &cp.landmarks,
                    laser: &cp.laser,
                    step: n,
                },
                rng,
            )?,
            None => filter.predict(&cp.ute, u, &noise, rng),
        }
        each(n, &filter.particles().estimate());
    }
    Ok(())
}

#[cfg(test)]
mod interval_prior_tests;
