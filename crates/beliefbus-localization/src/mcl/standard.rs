//! Standard MCL (Dellaert et al. 1999; paper 003 §4.1): the motion model is
//! the proposal and the laser likelihood the weight,
//!
//! ```text
//! X_n^j = f_n^j + ΔB^j,   W_n^j ∝ W_{n−1}^j p(z_n | X_n^j)
//! log p(z_n | x) = −Σ_i ½ ‖z^i − h(x, m^i)‖²_{Σ₂⁻¹} + const.
//! ```

use super::particles::ParticleSet;
use super::{LaserStep, Localizer};
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::laser::term_cost;
use beliefbus_core::rng::SimRng;

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
        for (x, lw) in self.set.x.iter_mut().zip(self.set.logw.iter_mut()) {
            let xi = normal3(rng);
            *x = ute.predict_mean(x, u) + noise.draw(x[2], &xi);
            for o in obs {
                *lw -= term_cost(x, map[o.landmark], o, laser);
            }
        }
        self.set.reweight(step, rng)?;
        Ok(())
    }
}
