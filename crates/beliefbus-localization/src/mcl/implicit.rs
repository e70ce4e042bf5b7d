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
//!
//! Should Newton fail for a particle (a non-finite iterate: for a particle
//! far from the data, F^j can have a second basin at a landmark, where the
//! bearing is undefined and the Hessian blows up, and Newton may walk into
//! it), that particle falls back to the motion-model
//! proposal with the likelihood weight of standard MCL (times |Σ₁|^{½}, the
//! constant the implicit weights leave out): the proposal is still
//! a function of the particle's own past, so the weights stay exact. The
//! fallbacks are counted.

use super::newton::{minimise, NewtonSettings, Objective};
use super::particles::ParticleSet;
use super::{LaserStep, Localizer};
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::laser::term_cost;
use beliefbus_core::rng::SimRng;

/// Implicit MCL with M particles.
#[derive(Clone, Debug)]
pub struct ImplicitMcl {
    pub set: ParticleSet,
    pub newton: NewtonSettings,
    /// Newton steps taken so far (all particles, all scans).
    pub newton_iters: usize,
    /// Particle updates that fell back to the motion-model proposal.
    pub fallbacks: usize,
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
            fallbacks: 0,
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
    fn newton_stats(&self) -> Option<(usize, usize)> {
        Some((self.newton_iters, self.fallbacks))
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
            let obj = Objective {
                f: ute.predict_mean(x, u),
                prec: noise.precision(x[2]),
                obs,
                map,
                laser: *laser,
            };
            let xi = normal3(rng);
            let sample = minimise(&obj, &self.newton, step).ok().and_then(|m| {
                self.newton_iters += m.iters;
                let y = m.l.tr_solve_lower_triangular(&xi)?;
                let xn = m.mu + y;
                let inc = 0.5 * xi.dot(&xi) - obj.value(&xn) - m.log_det_l;
                inc.is_finite().then_some((xn, inc))
            });
            match sample {
                Some((xn, inc)) => {
                    *x = xn;
                    *lw += inc;
                }
                None => {
                    self.fallbacks += 1;
                    // The implicit weights above leave out the motion
                    // prior's |Σ₁|^{−½}, common to the implicit particles;
                    // a fallback's likelihood weight carries no prior term,
                    // so it takes the same omission, +½ log det Σ₁, to stay
                    // on their scale.
                    let log_det_prec = obj.prec.determinant().ln();
                    if log_det_prec.is_finite() {
                        *lw -= 0.5 * log_det_prec;
                    }
                    *x = obj.f + noise.draw(x[2], &xi);
                    for o in obs {
                        *lw -= term_cost(x, map[o.landmark], o, laser);
                    }
                }
            }
        }
        self.set.reweight(step, rng)?;
        Ok(())
    }
}
