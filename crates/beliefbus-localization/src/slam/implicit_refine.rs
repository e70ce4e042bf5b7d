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
//! With several known returns in a step the first is redrawn and the
//! others enter F^j with their current θ (their sightings are recorded);
//! the synthetic car park has one return per step.

use super::assoc::{inverse, near, Association, Chooser, RangeBearing};
use super::implicit::sample_given_pose;
use super::joint::JointObjective;
use super::particles::SlamParticles;
use super::refine::{backward_term, cov_block, linear_map, newton, Objective};
use super::refined_map::{Past, RefinedLandmark};
use super::{SlamFilter, SlamModel, SlamStats};
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::geometry::{Point, Pose};
use crate::laser::{add_term, term_cost, Curvature, Observation};
use crate::mcl::newton::NewtonSettings;
use beliefbus_core::rng::SimRng;
use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector2, Vector3, Vector5};
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
    known: Vec<(usize, RangeBearing)>,
    fixed_obs: Vec<Observation>,
    fixed_map: Vec<Point>,
    new_obs: Vec<RangeBearing>,
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
            known: Vec::with_capacity(32),
            fixed_obs: Vec::with_capacity(32),
            fixed_map: Vec::with_capacity(32),
            new_obs: Vec::with_capacity(32),
        })
    }
}

fn xi5(rng: &mut SimRng) -> Vector5<f64> {
    Vector5::from_fn(|_, _| rng.sample(StandardNormal))
}

impl SlamFilter for ImplicitRefineSlam {
    fn name(&self) -> &'static str {
        "implicit-refine"
    }

    fn reset(&mut self, start: &Pose) {
        self.set.reset(start);
        self.stats = SlamStats::default();
        self.step = 0;
    }

    fn step(
        &mut self,
        u: crate::vehicle::Control,
        dt: f64,
        obs: &[RangeBearing],
        rng: &mut SimRng,
    ) -> Result<Pose, LocalizationError> {
        self.step += 1;
        let step = self.step;
        let (ute, noise) = self.model.step_noise(u, dt)?;
        if obs.is_empty() {
            return Ok(self.set.predict_only(&ute, &noise, u, rng));
        }
        self.stats.updates += 1;
        let model = self.model;
        let r = model.r();
        let rinv = Matrix2::new(1.0 / r[(0, 0)], 0.0, 0.0, 1.0 / r[(1, 1)]);
        let half_logdet_r = 0.5 * (r[(0, 0)] * r[(1, 1)]).ln();
        let ln2pi = (2.0 * std::f64::consts::PI).ln();
        let log_new = model.log_new_density();
        let s0 = noise.chol * noise.chol.transpose();
        let motion_norm = -(0..3).map(|i| noise.chol[(i, i)].ln()).sum::<f64>();
        let (it, tol) = (self.newton.max_iter, self.newton.tol);
        let bad = |what| LocalizationError::NonFinite { what, step };
        for j in 0..self.set.len() {
            let x = self.set.x[j];
            let f = ute.predict_mean(&x, u);
            let t = crate::geometry::frame_rotation(x[2]);
            let sx = t * s0 * t.transpose();
            let prec = noise.precision(x[2]);
            self.known.clear();
            self.fixed_obs.clear();
            self.fixed_map.clear();
            self.new_obs.clear();
            let mut discarded = 0usize;
            let map = &self.set.maps[j];
            for z in obs {
                let (zp, _, _) = inverse(&f, z);
                let mut ch = Chooser::new();
                for (k, lm) in map.iter().enumerate() {
                    if near(lm.m, zp, &model.assoc) {
                        let (nu, hx, hm) = super::assoc::innovation(&f, lm.m, z);
                        let s = hx * sx * hx.transpose() + hm * lm.cov * hm.transpose() + r;
                        ch.offer(k, &nu, &s, &model.assoc);
                    }
                }
                match ch.decide(&model.assoc) {
                    Association::Known(k) => self.known.push((k, *z)),
                    Association::New => self.new_obs.push(*z),
                    Association::Discard => discarded += 1,
                }
            }
            self.stats.known += self.known.len();
            self.stats.new += self.new_obs.len();
            self.stats.discarded += discarded;
            let mut lw = discarded as f64 * log_new;
            let mut new_start = 0;
            let xn;
            if let Some(&(k0, z0)) = self.known.first() {
                for (i, &(k, z)) in self.known.iter().enumerate().skip(1) {
                    self.fixed_obs.push(Observation {
                        range: z.range,
                        bearing: z.bearing,
                        landmark: i - 1,
                    });
                    self.fixed_map
                        .push(map.get(k).ok_or_else(|| bad("landmark"))?.m);
                }
                let lm0 = *map.get(k0).ok_or_else(|| bad("landmark"))?;
                let obj = SightingObjective {
                    joint: JointObjective {
                        f,
                        prec,
                        z: z0,
                        laser: model.laser,
                    },
                    past: Some(&lm0),
                    fixed_obs: &self.fixed_obs,
                    fixed_map: &self.fixed_map,
                };
                let xi = xi5(rng);
                let old = SVector::<f64, 2>::new(lm0.m[0], lm0.m[1]);
                let v0 = Vector5::new(f[0], f[1], f[2], old[0], old[1]);
                let past = Past {
                    lm: &lm0,
                    laser: model.laser,
                };
                let sample = newton(&obj, v0, it, tol).and_then(|m| {
                    self.stats.newton_iters += m.iters;
                    let (v, inc) = linear_map(&obj, &m, &xi)?;
                    let (back, _) = backward_term(&past, &old, it, tol)?;
                    Some((v, inc + back, cov_block(&m.l, 3)?))
                });
                let nk = self.known.len() as f64;
                lw -= nk * (ln2pi + half_logdet_r);
                let mut lm = lm0;
                match sample {
                    Some((v, inc, cov)) => {
                        xn = Pose::new(v[0], v[1], v[2]);
                        lw += inc + motion_norm;
                        lm.m = [v[3], v[4]];
                        lm.cov = cov;
                    }
                    None => {
                        self.stats.fallbacks += 1;
                        xn = f + noise.draw(x[2], &Vector3::new(xi[0], xi[1], xi[2]));
                        let o = Observation {
                            range: z0.range,
                            bearing: z0.bearing,
                            landmark: 0,
                        };
                        lw -= term_cost(&xn, lm.m, &o, &model.laser);
                        for o in &self.fixed_obs {
                            lw -= term_cost(&xn, self.fixed_map[o.landmark], o, &model.laser);
                        }
                    }
                }
                lm.add_sighting(&xn, &z0, &rinv);
                let map = &mut self.set.maps[j];
                map.set(k0, lm);
                for &(k, z) in self.known.iter().skip(1) {
                    let mut other = *map.get(k).ok_or_else(|| bad("landmark"))?;
                    other.add_sighting(&xn, &z, &rinv);
                    map.set(k, other);
                }
            } else if let Some(z0) = self.new_obs.first().copied() {
                let obj = SightingObjective {
                    joint: JointObjective {
                        f,
                        prec,
                        z: z0,
                        laser: model.laser,
                    },
                    past: None,
                    fixed_obs: &[],
                    fixed_map: &[],
                };
                let xi = xi5(rng);
                let (m0, _, _) = inverse(&f, &z0);
                let v0 = Vector5::new(f[0], f[1], f[2], m0[0], m0[1]);
                let sample = newton(&obj, v0, it, tol).and_then(|m| {
                    self.stats.newton_iters += m.iters;
                    let (v, inc) = linear_map(&obj, &m, &xi)?;
                    Some((v, inc, cov_block(&m.l, 3)?))
                });
                match sample {
                    Some((v, inc, cov)) => {
                        xn = Pose::new(v[0], v[1], v[2]);
                        lw += inc + motion_norm - half_logdet_r + log_new;
                        self.set.maps[j].push(RefinedLandmark::new([v[3], v[4]], cov, &xn, &z0));
                        new_start = 1;
                    }
                    None => {
                        self.stats.fallbacks += 1;
                        xn = f + noise.draw(x[2], &Vector3::new(xi[0], xi[1], xi[2]));
                    }
                }
            } else {
                xn = f + noise.draw(x[2], &normal3(rng));
            }
            for z in &self.new_obs[new_start..] {
                let (th, inc) =
                    sample_given_pose(&xn, z, &model, rng).ok_or(bad("new landmark sample"))?;
                lw += inc - half_logdet_r + log_new;
                self.set.maps[j].push(RefinedLandmark::new(th.m, th.cov, &xn, z));
            }
            if !xn.iter().all(|c| c.is_finite()) {
                return Err(bad("implicit-refine pose"));
            }
            self.set.x[j] = xn;
            self.set.logw[j] += lw;
        }
        self.set.reweight(step, rng)?;
        Ok(self.set.estimate())
    }

    fn map(&self) -> Vec<Point> {
        self.set.maps[self.set.best()].iter().map(|l| l.m).collect()
    }

    fn stats(&self) -> SlamStats {
        self.set.stats_with(self.stats)
    }
}
