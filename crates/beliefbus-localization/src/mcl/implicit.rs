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
//! With the interval prior ([`super::interval_prior`]) the prior term of
//! F^j is N(f_n^j, Σ^j), Σ^j = F C^j Fᵀ + Σ₁ with C^j the noise particle j
//! accumulated since the last scan, so the Newton step and the linear map
//! steer the whole interval's noise by the scan. Σ^j differs by particle,
//! so its normaliser enters the weight:
//!
//! ```text
//! W_n^j ∝ W_{n−1}^j e^{½ ξᵀξ − F^j(X_n^j)} |Σ^j|^{−½} / (det L^j |Σ₁|^{−½})
//! ```
//!
//! (the common |Σ₁|^{−½} divided out, so with C^j = 0 nothing changes).
//!
//! Should Newton fail for a particle (a non-finite iterate: for a particle
//! far from the data, F^j can have a second basin at a landmark, where the
//! bearing is undefined and the Hessian blows up, and Newton may walk into
//! it), that particle falls back to the motion-model
//! proposal with the likelihood weight of standard MCL (times |Σ₁|^{½}, the
//! constant the implicit weights leave out): the proposal is still
//! a function of the particle's own past, so the weights stay exact. The
//! fallbacks are counted.

use super::interval_prior::MotionStep;
use super::newton::{minimise, NewtonSettings, Objective};
use super::particles::ParticleSet;
use super::{LaserStep, Localizer};
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::laser::term_cost;
use beliefbus_core::rng::SimRng;
use nalgebra::Matrix3;

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
        let ms = MotionStep::new(ute, noise);
        for (x, lw, c) in self.set.scan_mut() {
            let prior = ms.prior(x, c, u);
            let beta = x[2];
            *c = Matrix3::zeros();
            let obj = Objective {
                f: prior.f,
                prec: prior.prec,
                obs,
                map,
                laser: *laser,
            };
            // The prior's normaliser relative to the one step's, common to
            // all particles when no noise was accumulated (exactly 0 then).
            let rel_norm = prior.norm - ms.motion_norm;
            let xi = normal3(rng);
            let sample = minimise(&obj, &self.newton, step).ok().and_then(|m| {
                self.newton_iters += m.iters;
                let y = m.l.tr_solve_lower_triangular(&xi)?;
                let xn = m.mu + y;
                let inc = 0.5 * xi.dot(&xi) - obj.value(&xn) - m.log_det_l + rel_norm;
                inc.is_finite().then_some((xn, inc))
            });
            match sample {
                Some((xn, inc)) => {
                    *x = xn;
                    *lw += inc;
                }
                None => {
                    self.fallbacks += 1;
                    // The implicit weights above leave out the one step's
                    // |Σ₁|^{−½}, common to the implicit particles; a
                    // fallback draws from the prior, so its likelihood
                    // weight carries no prior term and takes the same
                    // omission, +½ log det Σ₁, to stay on their scale.
                    let log_det_prec = noise.precision(beta).determinant().ln();
                    if log_det_prec.is_finite() {
                        *lw -= 0.5 * log_det_prec;
                    }
                    *x = prior.draw(&xi);
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
