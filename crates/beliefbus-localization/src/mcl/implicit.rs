//! MCL with implicit sampling (paper 003 §4.1, the notes' §1.6 with errata
//! E8, E9, E12): per particle j at a laser step,
//!
//! ```text
//! F^j(x) = ½ ‖x − f_n^j‖²_{Σ₁⁻¹} + Σ_i ½ ‖z_n^i − h(x, m^i)‖²_{Σ₂⁻¹}
//! μ^j = argmin F^j (Newton from f_n^j),  φ^j = F^j(μ^j),  H^j = L^j L^jᵀ
//! X_n^j = μ^j + (L^j)⁻ᵀ ξ^j,  ξ^j ~ N(0, I₃)                  (linear map)
//! W_n^j ∝ W_{n−1}^j e^{−φ^j} e^{F̂^j(X_n^j) − F^j(X_n^j)} / det L^j
//!       = W_{n−1}^j e^{½ ξᵀξ − F^j(X_n^j)} / det L^j
//! ```
//!
//! with F̂^j = φ^j + ½ (x − μ^j)ᵀ H^j (x − μ^j). The normalising constants
//! of F^j are the same for every particle (det Σ₁ does not depend on the
//! heading, see [`crate::vehicle`]), so they cancel.

use super::newton::{minimise, NewtonSettings, Objective};
use super::particles::ParticleSet;
use super::Localizer;
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::geometry::Point;
use crate::laser::{LaserNoise, Observation};
use crate::vehicle::{Control, StepNoise, Ute};
use beliefbus_core::rng::SimRng;

/// Implicit MCL with M particles.
#[derive(Clone, Debug)]
pub struct ImplicitMcl {
    pub set: ParticleSet,
    pub newton: NewtonSettings,
    /// Newton steps taken so far (all particles, all scans).
    pub newton_iters: usize,
}

impl ImplicitMcl {
    /// M particles, resampling when ESS < `ess_threshold` · M.
    pub fn new(
        m: usize,
        ess_threshold: f64,
        newton: NewtonSettings,
    ) -> Result<Self, LocalizationError> {
        Ok(Self {
            set: ParticleSet::new(m, ess_threshold)?,
            newton,
            newton_iters: 0,
        })
    }
}

impl Localizer for ImplicitMcl {
    fn name(&self) -> &'static str {
        "implicit"
    }
    fn particles(&self) -> &ParticleSet {
        &self.set
    }
    fn particles_mut(&mut self) -> &mut ParticleSet {
        &mut self.set
    }

    fn update(
        &mut self,
        ute: &Ute,
        u: Control,
        noise: &StepNoise,
        obs: &[Observation],
        map: &[Point],
        laser: &LaserNoise,
        step: usize,
        rng: &mut SimRng,
    ) -> Result<(), LocalizationError> {
        for (x, lw) in self.set.x.iter_mut().zip(self.set.logw.iter_mut()) {
            let obj = Objective {
                f: ute.predict_mean(x, u),
                prec: noise.precision(x[2]),
                obs,
                map,
                laser: *laser,
            };
            let m = minimise(&obj, &self.newton, step)?;
            self.newton_iters += m.iters;
            let xi = normal3(rng);
            let y =
                m.l.tr_solve_lower_triangular(&xi)
                    .ok_or(LocalizationError::NonFinite {
                        what: "linear map",
                        step,
                    })?;
            *x = m.mu + y;
            *lw += 0.5 * xi.dot(&xi) - obj.value(x) - m.log_det_l;
        }
        self.set.reweight(step, rng)?;
        Ok(())
    }
}
