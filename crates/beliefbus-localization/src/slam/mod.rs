//! Online SLAM on the Ute vehicle (paper 003 §4.2): implicit SLAM and its
//! three baselines behind one interface, [`SlamFilter`]:
//!
//! - [`implicit::ImplicitSlam`]: per-particle pose and sampled landmark
//!   positions; a new feature is sampled jointly with the pose from the 5-D
//!   F^j(x_n, θ_n) ([`joint`]), a re-observed one gives the implicit MCL
//!   step with the particle's landmark fixed (the notes' §1.7 reading (i));
//! - [`implicit_refine::ImplicitRefineSlam`]: the same, but a re-observed
//!   feature is drawn again jointly with the pose from F^j(x_n, θ_n) with
//!   the particle's earlier sightings as exact terms ([`refine`]);
//! - [`fastslam::FastSlam`]: FastSLAM 1.0 (motion-model proposal) and 2.0
//!   (proposal including the observation), per-landmark EKFs;
//! - [`ekf::EkfSlam`]: the joint-state EKF, augmented on a new landmark.
//!
//! [`implicit::ImplicitSlam`] can renew its particles' recent paths after
//! each resampling by Metropolis–Hastings moves ([`path_move`], off by
//! default).
//!
//! Every filter associates each return by the one maximum-likelihood rule
//! with the same gates ([`assoc`]), predicts with the same kinematics (E10)
//! and noise Σ₁ = T(β) Σ₀(u) T(β)ᵀ every odometry step (the particle
//! filters optionally deferring the noise of steps without returns to the
//! next step with returns, [`step_setup::StepPrior`]), and weighs returns
//! with the same Σ₂. A return associated with no landmark starts one; the
//! flat prior on its position is taken uniform over the laser's forward
//! half circle (area A = π r_max²/2), which fixes the weight of a new
//! landmark against a re-observed one: r/A after θ is integrated out.

/// The fields [`step_setup::begin_step`] takes from a particle SLAM
/// filter, borrowed from `$f` (the same field names in the four of them).
macro_rules! particle_filter_parts {
    ($f:ident) => {
        $crate::slam::step_setup::FilterParts {
            model: &$f.model,
            set: &mut $f.set,
            step: &mut $f.step,
            stats: &mut $f.stats,
            forced: &mut $f.forced,
            shared: $f.shared,
            scan: &mut $f.scan,
        }
    };
}

/// The diagnostics every particle SLAM filter answers from its particle
/// set and association settings (fields `set`, `shared`, `scan`, `forced`,
/// `stats`), written once for the four of them.
macro_rules! particle_set_diagnostics {
    () => {
        fn set_shared_association(&mut self, on: bool) {
            self.shared = on;
        }

        fn set_interval_prior(&mut self, on: bool) -> bool {
            self.set.deferred = on;
            self.set.acc.fill(nalgebra::Matrix3::zeros());
            true
        }

        fn set_existence(
            &mut self,
            cfg: Option<$crate::slam::existence::ExistenceConfig>,
        ) -> Result<bool, $crate::error::LocalizationError> {
            if let Some(c) = &cfg {
                c.validate()?;
                if self.shared {
                    return Err($crate::error::LocalizationError::Param {
                        key: "existence".into(),
                        msg: "removing landmarks renumbers a particle's map; \
                              it needs per-particle association"
                            .into(),
                    });
                }
            }
            self.existence = cfg;
            Ok(true)
        }

        fn set_exclusion(&mut self, e: $crate::slam::scan_assoc::Exclusion) {
            self.scan.exclusive = e;
        }

        fn force_association(&mut self, a: &[$crate::slam::assoc::Association]) {
            self.forced.set(a);
        }

        fn position_spread(&self) -> f64 {
            self.set.position_spread()
        }

        fn set_true_landmarks(&mut self, ids: &[usize]) {
            self.set.audit.set_truth(ids);
        }

        fn mark_ancestors(&mut self, slot: usize) {
            self.set.mark_ancestors(slot);
        }

        fn distinct_ancestors(&self, slot: usize) -> Option<usize> {
            Some(self.set.distinct_ancestors(slot))
        }

        fn stats(&self) -> $crate::slam::SlamStats {
            self.set.stats_with(self.stats)
        }
    };
}

pub mod arrow;
#[cfg(test)]
mod arrow_tests;
pub mod assoc;
pub mod assoc_audit;
#[cfg(test)]
mod assoc_audit_tests;
#[cfg(test)]
mod diag_tests;
pub mod driver;
pub mod ekf;
pub mod existence;
#[cfg(test)]
mod existence_tests;
pub mod fastslam;
pub mod implicit;
pub mod implicit_rb;
pub mod implicit_refine;
#[cfg(test)]
mod interval_prior_tests;
pub mod joint;
pub mod map;
pub mod particles;
pub mod path_move;
#[cfg(test)]
mod path_move_tests;
pub mod refine;
#[cfg(test)]
mod refine_tests;
pub mod refined_map;
pub mod scan_assoc;
pub mod shared_assoc;
pub mod step_setup;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod weight_tests;

use crate::error::LocalizationError;
use crate::geometry::{Point, Pose};
use crate::laser::LaserNoise;
use crate::vehicle::{Control, MotionNoise, StepNoise, Ute};
use assoc::{AssocConfig, RangeBearing};
use beliefbus_core::rng::SimRng;
use nalgebra::Matrix2;

/// The models every SLAM filter shares.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlamModel {
    /// Vehicle geometry; its `dt` is replaced by each step's own.
    pub ute: Ute,
    pub motion: MotionNoise,
    pub laser: LaserNoise,
    pub assoc: AssocConfig,
    /// Laser radius (m), for the new-landmark prior.
    pub max_range: f64,
}

impl SlamModel {
    /// Check the noise settings.
    pub fn validate(&self) -> Result<(), LocalizationError> {
        self.motion.validate()?;
        LocalizationError::positive("laser variance of range", self.laser.var_range)?;
        LocalizationError::positive("laser variance of bearing", self.laser.var_bearing)?;
        LocalizationError::positive("max_range", self.max_range)?;
        LocalizationError::positive("association gate", self.assoc.gate)?;
        LocalizationError::positive("association radius", self.assoc.radius)?;
        if !(self.assoc.new_threshold >= self.assoc.gate) {
            return Err(LocalizationError::Invalid {
                name: "new-landmark threshold",
                value: self.assoc.new_threshold,
                need: "must be ≥ the association gate",
            });
        }
        Ok(())
    }

    /// Σ₂.
    pub fn r(&self) -> Matrix2<f64> {
        Matrix2::new(self.laser.var_range, 0.0, 0.0, self.laser.var_bearing)
    }

    /// log of the new-landmark prior density 1/A.
    pub fn log_new_density(&self) -> f64 {
        -(std::f64::consts::PI * self.max_range * self.max_range / 2.0).ln()
    }

    /// The vehicle and the shared step noise for a step of length dt.
    pub fn step_noise(&self, u: Control, dt: f64) -> Result<(Ute, StepNoise), LocalizationError> {
        LocalizationError::positive("dt", dt)?;
        let ute = Ute { dt, ..self.ute };
        Ok((ute, StepNoise::new(&ute, u, &self.motion)?))
    }
}

/// Counters over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SlamStats {
    /// Steps with at least one return.
    pub updates: usize,
    pub resamplings: usize,
    /// Sum of ESS/M over the updates (particle filters).
    pub ess_fraction_sum: f64,
    /// Newton steps (implicit SLAM).
    pub newton_iters: usize,
    /// Particle updates that fell back to the motion-model proposal.
    pub fallbacks: usize,
    /// Returns associated with a known landmark / starting one / discarded
    /// (summed over particles for the particle filters).
    pub known: usize,
    pub new: usize,
    pub discarded: usize,
    /// Landmarks removed by the existence rule (summed over particles).
    pub removed: usize,
    /// Associations scored against the truth, wrong and missed ones
    /// (summed over particles; [`assoc_audit`]).
    pub audit: assoc_audit::AuditCounts,
}

/// An online SLAM filter: one call per odometry sample.
pub trait SlamFilter {
    /// The method's name in reports.
    fn name(&self) -> &'static str;
    /// Start again at a known pose with an empty map.
    fn reset(&mut self, start: &Pose);
    /// Move by control u over dt seconds, then take the returns `obs` seen
    /// at the end of the step (may be empty); the pose estimate.
    fn step(
        &mut self,
        u: Control,
        dt: f64,
        obs: &[RangeBearing],
        rng: &mut SimRng,
    ) -> Result<Pose, LocalizationError>;
    /// The map estimate (the heaviest particle's map for particle filters).
    fn map(&self) -> Vec<Point>;
    fn stats(&self) -> SlamStats;
    /// Impose the association of the next step's returns, one per return,
    /// in place of the ML rule (the known-association ablation).
    fn force_association(&mut self, a: &[assoc::Association]);
    /// Resample-move: after each resampling, move every particle's last
    /// poses by Metropolis–Hastings ([`path_move`]); `None` turns it off.
    /// Whether the filter has such a move (`false`: the setting is ignored).
    fn set_path_move(
        &mut self,
        _cfg: Option<path_move::MoveConfig>,
    ) -> Result<bool, LocalizationError> {
        Ok(false)
    }
    /// Moves proposed and accepted by the resample-move so far.
    fn move_counts(&self) -> (usize, usize) {
        (0, 0)
    }
    /// Particle filters: associate each return once for the whole set
    /// ([`shared_assoc`]) instead of once per particle; from the next reset.
    fn set_shared_association(&mut self, _on: bool) {}
    /// Particle filters: on steps without returns move each particle by
    /// the mean model and accumulate its noise (linearised, as EKF-SLAM's
    /// prediction), so that the next step with returns draws the whole
    /// interval's noise from its proposal and associates with the whole
    /// interval's pose uncertainty ([`particles::SlamParticles::predict_only`],
    /// [`step_setup::StepPrior`]). Whether the filter has the setting
    /// (`false`: EKF-SLAM, whose prediction already does this).
    fn set_interval_prior(&mut self, _on: bool) -> bool {
        false
    }
    /// `implicit-refine` only: associate at each landmark's conditional
    /// mode given the particle's path (`true`) or at its last draw
    /// (`false`, the default) ([`implicit_refine::ImplicitRefineSlam::assoc_at_mode`]).
    /// Whether the filter has the setting.
    fn set_assoc_at_mode(&mut self, _on: bool) -> bool {
        false
    }
    /// Associate a scan's returns jointly, one landmark per return at most
    /// ([`scan_assoc`]), instead of each return on its own.
    fn set_exclusion(&mut self, _e: scan_assoc::Exclusion) {}
    /// Landmark existence from negative information
    /// ([`existence`]); `None` turns it off. Whether the filter has the
    /// rule (`false`: the setting is ignored, as by EKF-SLAM). Refused
    /// together with shared association.
    fn set_existence(
        &mut self,
        _cfg: Option<existence::ExistenceConfig>,
    ) -> Result<bool, LocalizationError> {
        Ok(false)
    }
    /// Synthetic data: the true landmarks of the next step's returns, one
    /// per return (empty: the step is not scored), for scoring the
    /// association ([`assoc_audit`]; reported in [`SlamStats::audit`]).
    /// The filter's estimates do not depend on it.
    fn set_true_landmarks(&mut self, _ids: &[usize]) {}
    /// √(trace of the position covariance) of the current belief (m).
    fn position_spread(&self) -> f64;
    /// Particle filters: label every particle by its index in slot `slot`
    /// ([`particles::SlamParticles::mark_ancestors`]).
    fn mark_ancestors(&mut self, _slot: usize) {}
    /// Particle filters: how many particles labelled in slot `slot` still
    /// have descendants; `None` for a Gaussian filter.
    fn distinct_ancestors(&self, _slot: usize) -> Option<usize> {
        None
    }
}
