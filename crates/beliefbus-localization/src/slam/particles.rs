//! The weighted particle set of the particle SLAM filters: each particle a
//! pose and its own [`SharedMap`], log weights, ESS-triggered systematic
//! resampling (`beliefbus_core::filter::resample::systematic`) that copies
//! maps by sharing their blocks, and the weighted-mean pose estimate.
//! Buffers are sized once; resampling a map copies block pointers into a
//! reused buffer.
//!
//! For diagnosing path and map depletion each particle also carries
//! [`LINEAGE_SLOTS`] ancestor labels: [`SlamParticles::mark_ancestors`]
//! labels every particle by its index at a chosen step, resampling copies
//! the labels with the particle, and [`SlamParticles::distinct_ancestors`]
//! counts how many of the particles alive at that step still have
//! descendants.

use super::assoc_audit::AssocAudit;
use super::map::SharedMap;
use crate::error::LocalizationError;
use crate::geometry::Pose;
use beliefbus_core::filter::resample::systematic;
use beliefbus_core::math::weights::normalise;
use beliefbus_core::rng::SimRng;
use nalgebra::Matrix3;

/// Number of ancestor-label slots per particle.
pub const LINEAGE_SLOTS: usize = 4;

/// M particles, each a pose and a map of landmarks `L`.
#[derive(Clone, Debug)]
pub struct SlamParticles<L: Clone> {
    pub x: Vec<Pose>,
    pub maps: Vec<SharedMap<L>>,
    /// Each landmark's existence evidence ([`super::existence`]); empty
    /// maps while the rule is off.
    pub ev: Vec<SharedMap<f32>>,
    /// Each landmark's true origin, for scoring the association against the
    /// truth ([`super::assoc_audit`]); empty maps unless truth is given.
    tags: Vec<SharedMap<u32>>,
    pub audit: AssocAudit,
    pub logw: Vec<f64>,
    pub w: Vec<f64>,
    /// Per particle, the covariance (world frame) of its pose given its
    /// pose at the last step with returns, linearised along the noise-free
    /// prediction ([`SlamParticles::predict_only`] with `deferred`); zero
    /// while `deferred` is off.
    pub acc: Vec<Matrix3<f64>>,
    /// Steps without returns move each particle by the mean model and
    /// accumulate the noise in `acc`, for the next step with returns to
    /// draw the whole interval's noise from its proposal.
    pub deferred: bool,
    anc: Vec<usize>,
    tmp_x: Vec<Pose>,
    tmp_acc: Vec<Matrix3<f64>>,
    tmp_maps: Vec<SharedMap<L>>,
    tmp_ev: Vec<SharedMap<f32>>,
    tmp_tags: Vec<SharedMap<u32>>,
    lineage: Vec<[u32; LINEAGE_SLOTS]>,
    tmp_lineage: Vec<[u32; LINEAGE_SLOTS]>,
    pub ess_threshold: f64,
    pub updates: usize,
    pub resamplings: usize,
    pub ess_fraction_sum: f64,
}

impl<L: Clone> SlamParticles<L> {
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
            maps: vec![SharedMap::new(); m],
            ev: vec![SharedMap::new(); m],
            tags: vec![SharedMap::new(); m],
            audit: AssocAudit::default(),
            logw: vec![0.0; m],
            w: vec![1.0 / m as f64; m],
            acc: vec![Matrix3::zeros(); m],
            deferred: false,
            anc: vec![0; m],
            tmp_x: vec![Pose::zeros(); m],
            tmp_acc: vec![Matrix3::zeros(); m],
            tmp_maps: vec![SharedMap::new(); m],
            tmp_ev: vec![SharedMap::new(); m],
            tmp_tags: vec![SharedMap::new(); m],
            lineage: vec![[0; LINEAGE_SLOTS]; m],
            tmp_lineage: vec![[0; LINEAGE_SLOTS]; m],
            ess_threshold,
            updates: 0,
            resamplings: 0,
            ess_fraction_sum: 0.0,
        })
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Every particle at `start` with an empty map and equal weights.
    pub fn reset(&mut self, start: &Pose) {
        let m = self.len();
        self.x.fill(*start);
        self.acc.fill(Matrix3::zeros());
        for mp in self.maps.iter_mut() {
            *mp = SharedMap::new();
        }
        for e in self.ev.iter_mut() {
            *e = SharedMap::new();
        }
        for t in self.tags.iter_mut() {
            *t = SharedMap::new();
        }
        self.audit.reset();
        self.logw.fill(0.0);
        self.w.fill(1.0 / m as f64);
        for slot in 0..LINEAGE_SLOTS {
            self.mark_ancestors(slot);
        }
        self.updates = 0;
        self.resamplings = 0;
        self.ess_fraction_sum = 0.0;
    }

    /// Normalise, record the ESS, resample if ESS < threshold · M.
    pub fn reweight(&mut self, step: usize, rng: &mut SimRng) -> Result<f64, LocalizationError> {
        let m = self.len();
        let s = normalise(&self.logw, &mut self.w).ok_or(LocalizationError::Degenerate { step })?;
        self.updates += 1;
        self.ess_fraction_sum += s.ess / m as f64;
        if s.ess < self.ess_threshold * m as f64 {
            systematic(&self.w, rng, &mut self.anc)
                .map_err(|_| LocalizationError::Degenerate { step })?;
            for (k, &a) in self.anc.iter().enumerate() {
                self.tmp_x[k] = self.x[a];
                self.tmp_acc[k] = self.acc[a];
                self.tmp_maps[k].share_from(&self.maps[a]);
                self.tmp_ev[k].share_from(&self.ev[a]);
                self.tmp_tags[k].share_from(&self.tags[a]);
                self.tmp_lineage[k] = self.lineage[a];
            }
            std::mem::swap(&mut self.lineage, &mut self.tmp_lineage);
            std::mem::swap(&mut self.x, &mut self.tmp_x);
            std::mem::swap(&mut self.acc, &mut self.tmp_acc);
            std::mem::swap(&mut self.maps, &mut self.tmp_maps);
            std::mem::swap(&mut self.ev, &mut self.tmp_ev);
            std::mem::swap(&mut self.tags, &mut self.tmp_tags);
            self.logw.fill(0.0);
            self.w.fill(1.0 / m as f64);
            self.resamplings += 1;
        } else {
            for (l, &w) in self.logw.iter_mut().zip(&self.w) {
                *l = w.ln();
            }
        }
        Ok(s.ess)
    }

    /// The existence rule on particle j after its update (`before`: its
    /// map's length before the scan); the number of landmarks removed.
    pub fn apply_existence(
        &mut self,
        cfg: &super::existence::ExistenceConfig,
        j: usize,
        before: usize,
        assoc: &[super::assoc::Association],
        pos: impl Fn(&L) -> crate::geometry::Point,
    ) -> usize {
        let x = self.x[j];
        cfg.apply(&mut self.maps[j], &mut self.ev[j], before, &x, assoc, pos)
    }

    /// Score particle j's associations `assoc` of this step against the
    /// truth and tag the landmarks they started (`before`: its map's length
    /// before the step); nothing unless the step's truth was given.
    pub fn audit_particle(&mut self, j: usize, before: usize, assoc: &[super::assoc::Association]) {
        let after = self.maps[j].len();
        self.audit.score(&mut self.tags[j], before, after, assoc);
    }

    /// The ancestor of each particle at the last resampling.
    pub fn ancestors(&self) -> &[usize] {
        &self.anc
    }

    /// Weighted mean pose (circular mean of the heading).
    pub fn estimate(&self) -> Pose {
        crate::geometry::mean_pose(&self.x, &self.w)
    }

    /// A step without laser returns; the weights do not change. Without
    /// `deferred` every pose is moved by the motion model (the prior is the
    /// proposal). With it every pose follows the mean model and its noise
    /// is accumulated, linearised (as EKF-SLAM's prediction):
    ///
    /// ```text
    /// x ← f(x, u),  C ← F C Fᵀ + Σ₁(β),  F = ∂f/∂x at x
    /// ```
    ///
    /// so that the next step with returns draws the pose at the end of the
    /// whole interval from N(f, F C Fᵀ + Σ₁) and the returns.
    pub fn predict_only(
        &mut self,
        ute: &crate::vehicle::Ute,
        noise: &crate::vehicle::StepNoise,
        u: crate::vehicle::Control,
        rng: &mut SimRng,
    ) -> Pose {
        if self.deferred {
            let ms = crate::mcl::interval_prior::MotionStep::new(ute, noise);
            for (x, c) in self.x.iter_mut().zip(self.acc.iter_mut()) {
                ms.accumulate(x, c, u);
            }
        } else {
            for x in self.x.iter_mut() {
                let xi = crate::carpark::normal3(rng);
                *x = ute.predict_mean(x, u) + noise.draw(x[2], &xi);
            }
        }
        self.estimate()
    }

    /// `stats` with this set's resampling figures filled in.
    pub fn stats_with(&self, stats: super::SlamStats) -> super::SlamStats {
        super::SlamStats {
            resamplings: self.resamplings,
            ess_fraction_sum: self.ess_fraction_sum,
            audit: self.audit.counts(),
            ..stats
        }
    }

    /// Label every particle by its own index in label slot `slot` (taken
    /// modulo [`LINEAGE_SLOTS`]).
    pub fn mark_ancestors(&mut self, slot: usize) {
        let slot = slot % LINEAGE_SLOTS;
        for (j, l) in self.lineage.iter_mut().enumerate() {
            l[slot] = j as u32;
        }
    }

    /// How many distinct labels of slot `slot` the particles carry: the
    /// number of particles alive at the marking step that still have
    /// descendants. Diagnostics only (allocates).
    pub fn distinct_ancestors(&self, slot: usize) -> usize {
        let slot = slot % LINEAGE_SLOTS;
        let mut seen = vec![false; self.len()];
        for l in &self.lineage {
            seen[l[slot] as usize] = true;
        }
        seen.iter().filter(|&&s| s).count()
    }

    /// √(Σ_j w_j ‖p_j − p̄‖²) over the positions: the particle cloud's spread.
    pub fn position_spread(&self) -> f64 {
        let (mut mx, mut my) = (0.0, 0.0);
        for (x, &w) in self.x.iter().zip(&self.w) {
            mx += w * x[0];
            my += w * x[1];
        }
        let mut s = 0.0;
        for (x, &w) in self.x.iter().zip(&self.w) {
            s += w * ((x[0] - mx).powi(2) + (x[1] - my).powi(2));
        }
        s.sqrt()
    }

    /// Index of the heaviest particle.
    pub fn best(&self) -> usize {
        let mut b = 0;
        for (k, &w) in self.w.iter().enumerate() {
            if w > self.w[b] {
                b = k;
            }
        }
        b
    }
}
