//! Implicit SLAM with the re-observed feature drawn again (paper 003 §4.2,
//! `implicit-refine`): the paper's F^j(x_n, θ_n) over the pose and "the
//! location of the feature θ_n observed at time t_n", applied to every
//! sighting, new or not. A new feature is drawn exactly as in
//! [`super::implicit`] (flat prior, joint 5-D F); a re-observed one is drawn
//! again jointly with the pose from
//!
//! ```text
//! F^j(x, θ) = ½‖x − f^j‖²_{Σ₁⁻¹} + ½‖z − h(x, θ)‖²_{Σ₂⁻¹} + F_past^j(θ) [+ Σ_other known ½‖z_k − h(x, θ^{k,j})‖²_{Σ₂⁻¹}]
//! ```
//!
//! where F_past^j holds the particle's earlier sightings of that feature as
//! exact (not linearised) range-bearing terms at the particle's own past
//! poses ([`super::refined_map`]), and weighted by the backward-kernel rule
//! of [`super::refine`]: exact for the nonlinear target, the
//! Rao–Blackwellised Kalman weight on a linear-Gaussian model. Under the
//! notes' reading (i) ([`super::implicit`]) θ^{k,j} is drawn once and
//! stays, so the map is refined only by selection; here each sighting
//! redraws it from everything the particle has seen of it.
//!
//! With several returns in a step every feature they see, new or known, is
//! drawn jointly with the pose from one F^j over (x, θ_1, …, θ_p), whose
//! arrow-shaped Hessian is factored in O(p) ([`super::arrow`]); with one
//! return it is the 5-D F^j above. Should Newton fail, the particle moves
//! by the motion model, its known features stay and weigh it (reading
//! (i)'s fallback), new ones are drawn given the pose; fallbacks are
//! counted.

use super::arrow::Arrow;
use super::assoc::{inverse, near, Association, Forced, RangeBearing};
use super::implicit::sample_given_pose;
use super::joint::JointObjective;
use super::particles::SlamParticles;
use super::refine::{backward_at, backward_term, Objective};
use super::refined_map::{Past, RefinedLandmark};
use super::scan_assoc::ScanAssoc;
use super::step_setup::{begin_step, Begin, StepSetup};
use super::{SlamFilter, SlamModel, SlamStats};
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::geometry::{Point, Pose};
use crate::laser::{add_term, term_cost, Curvature, Observation};
use crate::mcl::newton::NewtonSettings;
use beliefbus_core::rng::SimRng;
use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector2, Vector3};
use rand::RngExt;
use rand_distr::StandardNormal;

/// F^j over v = (x₁, x₂, β, θ₁, θ₂): the joint objective of a sighting,
/// the feature's earlier sightings (if known) and other known returns.
pub struct SightingObjective<'a> {
    pub joint: JointObjective,
    pub past: Option<&'a RefinedLandmark>,
    pub fixed_obs: &'a [Observation],
    pub fixed_map: &'a [Point],
}

impl Objective<5> for SightingObjective<'_> {
    fn eval(
        &self,
        v: &SVector<f64, 5>,
        curv: Curvature,
        g: &mut SVector<f64, 5>,
        h: &mut SMatrix<f64, 5, 5>,
    ) -> f64 {
        let mut val = self.joint.eval(v, curv, g, h);
        let x = Pose::new(v[0], v[1], v[2]);
        if let Some(lm) = self.past {
            let (mut g2, mut h2) = (Vector2::zeros(), Matrix2::zeros());
            val += lm.add_past([v[3], v[4]], &self.joint.laser, curv, &mut g2, &mut h2);
            for a in 0..2 {
                g[3 + a] += g2[a];
                for b in 0..2 {
                    h[(3 + a, 3 + b)] += h2[(a, b)];
                }
            }
        }
        if !self.fixed_obs.is_empty() {
            let (mut g3, mut h3) = (Vector3::zeros(), Matrix3::zeros());
            for o in self.fixed_obs {
                val += add_term(
                    &x,
                    self.fixed_map[o.landmark],
                    o,
                    &self.joint.laser,
                    curv,
                    &mut g3,
                    &mut h3,
                );
            }
            for a in 0..3 {
                g[a] += g3[a];
                for b in 0..3 {
                    h[(a, b)] += h3[(a, b)];
                }
            }
        }
        val
    }
}

/// Implicit SLAM with refined re-observations, M particles.
#[derive(Clone, Debug)]
pub struct ImplicitRefineSlam {
    pub model: SlamModel,
    pub set: SlamParticles<RefinedLandmark>,
    pub newton: NewtonSettings,
    stats: SlamStats,
    step: usize,
    arrow: Arrow,
    /// Per return: its association.
    assoc: Vec<Association>,
    forced: Forced,
    scan: ScanAssoc,
    existence: Option<super::existence::ExistenceConfig>,
    shared: bool,
    /// Per block of the arrow: the landmark index (None: new).
    block_lm: Vec<Option<usize>>,
    zs: Vec<RangeBearing>,
    xi_t: Vec<Vector2<f64>>,
    th_draw: Vec<Point>,
    /// Associate, gate and report the map at each landmark's conditional
    /// mode given the particle's path, with its conditional covariance (as
    /// FastSLAM's landmark EKFs do); `false` (the default): at the last
    /// draw of θ with its covariance marginal over that step's pose. The
    /// mode was measured and loses on the synthetic car park (docs/slam-table6-gap.md).
    pub assoc_at_mode: bool,
}

impl ImplicitRefineSlam {
    pub fn new(
        model: SlamModel,
        m: usize,
        ess_threshold: f64,
        newton: NewtonSettings,
    ) -> Result<Self, LocalizationError> {
        model.validate()?;
        Ok(Self {
            model,
            set: SlamParticles::new(m, ess_threshold)?,
            newton,
            stats: SlamStats::default(),
            step: 0,
            arrow: Arrow::default(),
            assoc: Vec::with_capacity(32),
            forced: Forced::with_capacity(32),
            scan: ScanAssoc::with_capacity(32),
            existence: None,
            shared: false,
            block_lm: Vec::with_capacity(32),
            zs: Vec::with_capacity(32),
            xi_t: Vec::with_capacity(32),
            th_draw: Vec::with_capacity(32),
            assoc_at_mode: false,
        })
    }
}

impl SlamFilter for ImplicitRefineSlam {
    fn name(&self) -> &'static str {
        "implicit-refine"
    }

    fn reset(&mut self, start: &Pose) {
        self.set.reset(start);
        self.stats = SlamStats::default();
        self.step = 0;
        self.forced.clear();
    }

    fn step(
        &mut self,
        u: crate::vehicle::Control,
        dt: f64,
        obs: &[RangeBearing],
        rng: &mut SimRng,
    ) -> Result<Pose, LocalizationError> {
        let at_mode = self.assoc_at_mode;
        let parts = particle_filter_parts!(self);
        let setup = match begin_step(parts, u, dt, obs, rng, |l: &RefinedLandmark| {
            l.assoc_view(at_mode)
        })? {
            Begin::Predicted(estimate) => return Ok(estimate),
            Begin::Update(c) => c,
        };
        let StepSetup {
            step,
            model,
            r,
            half_logdet_r,
            ln2pi,
            log_new,
            ..
        } = setup;
        let rinv = Matrix2::new(1.0 / r[(0, 0)], 0.0, 0.0, 1.0 / r[(1, 1)]);
        let (it, tol) = (self.newton.max_iter, self.newton.tol);
        let bad = |what| LocalizationError::NonFinite { what, step };
        for j in 0..self.set.len() {
            let before = self.set.maps[j].len();
            let x = self.set.x[j];
            let prior = setup.prior(&x, &self.set.acc[j], u);
            let (f, sx, prec) = (prior.f, prior.cov, prior.prec);
            self.assoc.clear();
            let map = &self.set.maps[j];
            self.scan.begin(obs.len());
            for (i, z) in obs.iter().enumerate() {
                let (zp, _, _) = inverse(&f, z);
                for (k, lm) in map.iter().enumerate() {
                    let (m, cov) = lm.assoc_view(at_mode);
                    if near(m, zp, &model.assoc) {
                        let (nu, hx, hm) = super::assoc::innovation(&f, m, z);
                        let s = hx * sx * hx.transpose() + hm * cov * hm.transpose() + r;
                        self.scan.offer(i, k, &nu, &s, &model.assoc);
                    }
                }
            }
            for (i, &a) in self.scan.decide(&model.assoc).iter().enumerate() {
                self.assoc.push(self.forced.get(i, map.len()).unwrap_or(a));
            }
            // One block per distinct known landmark (all its returns), one
            // per new return.
            self.arrow.begin(f, prec, model.laser);
            self.block_lm.clear();
            let (mut n_ret, mut n_new, mut discarded) = (0usize, 0usize, 0usize);
            for (i, a) in self.assoc.iter().enumerate() {
                match *a {
                    Association::Known(k) if !self.block_lm.contains(&Some(k)) => {
                        self.zs.clear();
                        for (z, b) in obs.iter().zip(&self.assoc).skip(i) {
                            if *b == Association::Known(k) {
                                self.zs.push(*z);
                            }
                        }
                        let lm = *map.get(k).ok_or_else(|| bad("landmark"))?;
                        self.arrow.push(Some(lm), &self.zs, lm.m);
                        self.block_lm.push(Some(k));
                        n_ret += self.zs.len();
                    }
                    Association::Known(_) => {}
                    Association::New => {
                        let (m0, _, _) = inverse(&f, &obs[i]);
                        self.arrow.push(None, std::slice::from_ref(&obs[i]), m0);
                        self.block_lm.push(None);
                        n_ret += 1;
                        n_new += 1;
                    }
                    Association::Discard => discarded += 1,
                }
            }
            self.stats.known += n_ret - n_new;
            self.stats.new += n_new;
            self.stats.discarded += discarded;
            let mut lw = discarded as f64 * log_new;
            let p = self.arrow.len();
            let xi_x = normal3(rng);
            self.xi_t.clear();
            for _ in 0..p {
                self.xi_t.push(Vector2::new(
                    rng.sample(StandardNormal),
                    rng.sample(StandardNormal),
                ));
            }
            let mut xn = prior.draw(&xi_x);
            let mut drawn = false;
            if p > 0 {
                let arrow = &mut self.arrow;
                if let Some(m) = arrow.minimise(it, tol) {
                    self.stats.newton_iters += m.iters;
                    if let Some(inc) = arrow.draw(&xi_x, &self.xi_t, &mut xn, &mut self.th_draw) {
                        let mut back = 0.0;
                        for blk in &arrow.blocks {
                            if let Some(lm) = &blk.past {
                                let past = Past {
                                    lm,
                                    laser: model.laser,
                                };
                                let old = SVector::<f64, 2>::new(lm.m[0], lm.m[1]);
                                let term = match &lm.past_min {
                                    Some(mn) => backward_at(&past, &old, mn),
                                    None => backward_term(&past, &old, it, tol).map(|t| t.0),
                                };
                                match term {
                                    Some(b) => back += b,
                                    None => back = f64::NAN,
                                }
                            }
                        }
                        if back.is_finite() {
                            lw += inc + back + prior.norm
                                - n_ret as f64 * half_logdet_r
                                - (n_ret - n_new) as f64 * ln2pi
                                + n_new as f64 * log_new;
                            drawn = true;
                        }
                    }
                }
                if !drawn {
                    self.stats.fallbacks += 1;
                    xn = prior.draw(&xi_x);
                }
            }
            if !xn.iter().all(|c| c.is_finite()) {
                return Err(bad("implicit-refine pose"));
            }
            let map = &mut self.set.maps[j];
            for (b, blk) in self.arrow.blocks.iter().enumerate() {
                let zs = &self.arrow.returns[blk.start..blk.start + blk.len];
                match (self.block_lm[b], blk.past) {
                    (Some(k), Some(mut lm)) => {
                        if drawn {
                            lm.m = self.th_draw[b];
                            lm.cov = self.arrow.cov(b).ok_or_else(|| bad("feature covariance"))?;
                        } else {
                            // Motion-model fallback: the feature stays, the
                            // returns weigh the pose (reading (i)'s step).
                            for z in zs {
                                let o = Observation {
                                    range: z.range,
                                    bearing: z.bearing,
                                    landmark: 0,
                                };
                                lw -=
                                    term_cost(&xn, lm.m, &o, &model.laser) + ln2pi + half_logdet_r;
                            }
                        }
                        for z in zs {
                            lm.add_sighting(&xn, z, &rinv);
                        }
                        lm.refresh_mode(model.laser, it, tol);
                        map.set(k, lm);
                    }
                    _ => {
                        let z0 = zs[0];
                        let mut lm = if drawn {
                            let cov = self.arrow.cov(b).ok_or_else(|| bad("feature covariance"))?;
                            RefinedLandmark::new(self.th_draw[b], cov, &xn, &z0)
                        } else {
                            let (th, inc) = sample_given_pose(&xn, &z0, &model, rng)
                                .ok_or(bad("new landmark sample"))?;
                            lw += inc - half_logdet_r + log_new;
                            RefinedLandmark::new(th.m, th.cov, &xn, &z0)
                        };
                        lm.refresh_mode(model.laser, it, tol);
                        map.push(lm);
                    }
                }
            }
            self.set.x[j] = xn;
            self.set.acc[j] = Matrix3::zeros();
            self.set.logw[j] += lw;
            self.set.audit_particle(j, before, &self.assoc);
            if let Some(c) = &self.existence {
                self.stats.removed +=
                    self.set
                        .apply_existence(c, j, before, &self.assoc, |l: &RefinedLandmark| {
                            l.assoc_view(at_mode).0
                        });
            }
        }
        self.forced.clear();
        self.set.reweight(step, rng)?;
        Ok(self.set.estimate())
    }

    fn set_assoc_at_mode(&mut self, on: bool) -> bool {
        self.assoc_at_mode = on;
        true
    }

    fn map(&self) -> Vec<Point> {
        let at_mode = self.assoc_at_mode;
        self.set.maps[self.set.best()]
            .iter()
            .map(|l| l.assoc_view(at_mode).0)
            .collect()
    }

    particle_set_diagnostics!();
}
