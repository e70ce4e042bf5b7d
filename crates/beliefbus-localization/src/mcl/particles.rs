//! The weighted particle set both MCL filters share: log weights, the
//! normalisation and ESS of `beliefbus_core::math::weights`, systematic
//! resampling (`beliefbus_core::filter::resample`, Algorithm 2 of
//! Arulampalam et al. 2002, the paper's choice) when the weights are uneven
//! (ESS < threshold · M), and the weighted-mean estimate. Buffers are sized
//! once; a step allocates nothing.

use super::interval_prior::MotionStep;
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::geometry::Pose;
use crate::vehicle::{Control, StepNoise, Ute};
use beliefbus_core::filter::resample::systematic;
use beliefbus_core::math::weights::normalise;
use beliefbus_core::rng::SimRng;
use nalgebra::Matrix3;

/// M particles with their weights and resampling bookkeeping.
#[derive(Clone, Debug)]
pub struct ParticleSet {
    pub x: Vec<Pose>,
    /// Log weights (any shift).
    pub logw: Vec<f64>,
    /// Normalised weights of the last reweighting.
    pub w: Vec<f64>,
    /// Per particle, the covariance (world frame) of its pose given its
    /// pose at the last scan, linearised along the mean prediction
    /// ([`super::interval_prior::MotionStep::accumulate`]); zero while
    /// `deferred` is off.
    pub acc: Vec<Matrix3<f64>>,
    /// The interval prior: steps without a scan move each particle by the
    /// mean model and accumulate its noise in `acc`, for the next scan's
    /// proposal to draw the whole interval's noise.
    pub deferred: bool,
    anc: Vec<usize>,
    tmp: Vec<Pose>,
    tmp_acc: Vec<Matrix3<f64>>,
    /// Resample when ESS < ess_threshold · M.
    pub ess_threshold: f64,
    /// Reweightings so far, resamplings so far, and the sum of ESS/M.
    pub updates: usize,
    pub resamplings: usize,
    pub ess_fraction_sum: f64,
}

impl ParticleSet {
    /// `m` particles at the origin with equal weights.
    pub fn new(m: usize, ess_threshold: f64) -> Result<Self, LocalizationError> {
        if m == 0 {
            return Err(LocalizationError::Invalid {
                name: "particles",
                value: 0.0,
                need: "must be at least 1",
            });
        }
        if !(0.0..=1.0).contains(&ess_threshold) {
            return Err(LocalizationError::Invalid {
                name: "ess_threshold",
                value: ess_threshold,
                need: "must lie in [0, 1]",
            });
        }
        Ok(Self {
            x: vec![Pose::zeros(); m],
            logw: vec![0.0; m],
            w: vec![1.0 / m as f64; m],
            acc: vec![Matrix3::zeros(); m],
            deferred: false,
            anc: vec![0; m],
            tmp: vec![Pose::zeros(); m],
            tmp_acc: vec![Matrix3::zeros(); m],
            ess_threshold,
            updates: 0,
            resamplings: 0,
            ess_fraction_sum: 0.0,
        })
    }

    /// Each particle's pose, log weight and accumulated interval
    /// covariance, for a scan step to update in place.
    pub fn scan_mut(
        &mut self,
    ) -> impl Iterator<Item = (&mut Pose, &mut f64, &mut Matrix3<f64>)> + '_ {
        self.x
            .iter_mut()
            .zip(self.logw.iter_mut())
            .zip(self.acc.iter_mut())
            .map(|((x, lw), c)| (x, lw, c))
    }

    /// Number of particles M.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there are no particles (never: M ≥ 1).
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Draw the particles from N(mean, diag(std²)), equal weights, counters reset.
    pub fn init(&mut self, mean: &Pose, std: &Pose, rng: &mut SimRng) {
        let m = self.len();
        for p in self.x.iter_mut() {
            *p = mean + std.component_mul(&normal3(rng));
        }
        self.acc.fill(Matrix3::zeros());
        self.logw.fill(0.0);
        self.w.fill(1.0 / m as f64);
        self.updates = 0;
        self.resamplings = 0;
        self.ess_fraction_sum = 0.0;
    }

    /// Normalise the log weights, record the ESS, and resample
    /// systematically if ESS < threshold · M. Returns the ESS.
    pub fn reweight(&mut self, step: usize, rng: &mut SimRng) -> Result<f64, LocalizationError> {
        let m = self.len();
        let s = normalise(&self.logw, &mut self.w).ok_or(LocalizationError::Degenerate { step })?;
        self.updates += 1;
        self.ess_fraction_sum += s.ess / m as f64;
        if s.ess < self.ess_threshold * m as f64 {
            systematic(&self.w, rng, &mut self.anc)
                .map_err(|_| LocalizationError::Degenerate { step })?;
            for (k, &a) in self.anc.iter().enumerate() {
                self.tmp[k] = self.x[a];
                self.tmp_acc[k] = self.acc[a];
            }
            std::mem::swap(&mut self.x, &mut self.tmp);
            std::mem::swap(&mut self.acc, &mut self.tmp_acc);
            self.logw.fill(0.0);
            self.w.fill(1.0 / m as f64);
            self.resamplings += 1;
        } else {
            // Keep the log weights normalised so they never drift.
            for (l, &w) in self.logw.iter_mut().zip(&self.w) {
                *l = w.ln();
            }
        }
        Ok(s.ess)
    }

    /// A step without a scan; the weights do not change. Without
    /// `deferred` each pose moves by the motion model,
    /// X^j ← f(X^j, u) + ΔB^j (three standard normals per particle); with
    /// it each follows the mean model and accumulates its noise
    /// ([`MotionStep::accumulate`], no random numbers).
    pub fn predict(&mut self, ute: &Ute, u: Control, noise: &StepNoise, rng: &mut SimRng) {
        if self.deferred {
            let ms = MotionStep::new(ute, noise);
            for (x, c) in self.x.iter_mut().zip(self.acc.iter_mut()) {
                ms.accumulate(x, c, u);
            }
        } else {
            for x in self.x.iter_mut() {
                let xi = normal3(rng);
                *x = ute.predict_mean(x, u) + noise.draw(x[2], &xi);
            }
        }
    }

    /// The weighted mean: positions averaged, heading by the mean of
    /// (cos β, sin β).
    pub fn estimate(&self) -> Pose {
        crate::geometry::mean_pose(&self.x, &self.w)
    }

    /// Mean ESS/M over the reweightings so far (NaN before the first).
    pub fn mean_ess_fraction(&self) -> f64 {
        self.ess_fraction_sum / self.updates as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn even_weights_are_kept_and_uneven_ones_resampled() {
        let mut rng = beliefbus_core::rng::stream(1, 2);
        let mut ps = ParticleSet::new(4, 0.5).unwrap();
        for (i, p) in ps.x.iter_mut().enumerate() {
            *p = Pose::new(i as f64, 0.0, 0.0);
        }
        ps.logw.copy_from_slice(&[0.0, 0.0, 0.0, 0.1]);
        let ess = ps.reweight(1, &mut rng).unwrap();
        assert!(ess > 3.9 && ps.resamplings == 0);
        // One dominant particle: ESS ≈ 1 < 2, all copies of it.
        ps.logw.copy_from_slice(&[-50.0, -50.0, 0.0, -50.0]);
        let ess = ps.reweight(2, &mut rng).unwrap();
        assert!(ess < 1.01 && ps.resamplings == 1);
        assert!(ps.x.iter().all(|p| p[0] == 2.0));
        assert!((ps.estimate()[0] - 2.0).abs() < 1e-12);
        ps.logw.fill(f64::NAN);
        assert!(matches!(
            ps.reweight(3, &mut rng),
            Err(LocalizationError::Degenerate { step: 3 })
        ));
        assert!(ParticleSet::new(0, 0.5).is_err());
        assert!(ParticleSet::new(3, 1.5).is_err());
    }

    #[test]
    fn heading_estimate_is_circular() {
        let mut ps = ParticleSet::new(2, 0.5).unwrap();
        ps.x[0] = Pose::new(0.0, 0.0, 3.1);
        ps.x[1] = Pose::new(0.0, 0.0, -3.1);
        let b = ps.estimate()[2];
        assert!((b.abs() - std::f64::consts::PI).abs() < 1e-9, "{b}");
    }
}
