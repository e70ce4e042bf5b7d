//! Standard MCL (Dellaert et al. 1999; paper 003 §4.1): the motion model is
//! the proposal and the laser likelihood the weight,
//!
//! ```text
//! X_n^j = f_n^j + ΔB^j,   W_n^j ∝ W_{n−1}^j p(z_n | X_n^j)
//! log p(z_n | x) = −Σ_i ½ ‖z^i − h(x, m^i)‖²_{Σ₂⁻¹} + const.
//! ```
//!
//! With the interval prior ([`super::interval_prior`]) the motion model is
//! the prior N(f_n^j, F C Fᵀ + Σ₁) of the whole interval since the last
//! scan: the proposal is still the prior, so the weight is still the
//! likelihood alone. The filter then targets the same (linearised)
//! transition as implicit MCL with the prior, so the two differ only in
//! their proposals.

use super::interval_prior::MotionStep;
use super::particles::ParticleSet;
use super::{LaserStep, Localizer};
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::laser::term_cost;
use beliefbus_core::rng::SimRng;
use nalgebra::Matrix3;

/// Standard MCL with M particles.
#[derive(Clone, Debug)]
pub struct StandardMcl {
    pub set: ParticleSet,
}

impl StandardMcl {
    /// M particles, resampling when ESS < `ess_threshold` · M.
    pub fn new(m: usize, ess_threshold: f64) -> Result<Self, LocalizationError> {
        Ok(Self {
            set: ParticleSet::new(m, ess_threshold)?,
        })
    }
}

impl Localizer for StandardMcl {
    fn name(&self) -> &'static str {
        "standard"
    }
    fn particles(&self) -> &ParticleSet {
        &self.set
    }
    fn particles_mut(&mut self) -> &mut ParticleSet {
        &mut self.set
    }

    fn update(&mut self, s: &LaserStep, rng: &mut SimRng) -> Result<(), LocalizationError> {
        let LaserStep {
            ute,
            u,
            noise,
            obs,
            map,
            laser,
            step,
        } = *s;
        let ms = MotionStep::new(ute, noise);
        for (x, lw, c) in self.set.scan_mut() {
            let xi = normal3(rng);
            *x = ms.prior(x, c, u).draw(&xi);
            *c = Matrix3::zeros();
            for o in obs {
                *lw -= term_cost(x, map[o.landmark], o, laser);
            }
        }
        self.set.reweight(step, rng)?;
        Ok(())
    }
}
