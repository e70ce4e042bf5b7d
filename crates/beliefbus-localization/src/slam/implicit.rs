//! SLAM with implicit sampling (paper 003 §4.2; the notes' §1.7, reading
//! (i), and erratum E8). Particle j carries its pose X^j and a map of
//! *sampled* landmark positions θ^{k,j} (no per-landmark covariance). At a
//! step with returns, for each particle:
//!
//! ```text
//! associate every return at f^j = X^j + R(X^j, u) δ (the shared ML rule)
//! re-observed landmarks (any):   F^j(x) = ½‖x − f^j‖²_{Σ₁⁻¹} + Σ_i ½‖z^i − h(x, θ^{k_i,j})‖²_{Σ₂⁻¹}
//!                                (implicit MCL with the particle's landmarks fixed)
//! else, a new feature:           F^j(x, θ) joint in 5-D ([`super::joint`])
//! sample  v = μ + L⁻ᵀ ξ,  log W^j += ½ ξᵀξ − F^j(v) − log det L + constants
//! further new features given x:  θ from ½‖z − h(x, θ)‖²_{Σ₂⁻¹} by the same linear map in 2-D
//! ```
//!
//! The constants (−½ log det Σ₁ wherever the linear map replaces the motion
//! model as proposal, per re-observed return −log 2π − ½ log det Σ₂, per new
//! one −½ log det Σ₂ + log(1/A), per discarded one log(1/A)) are those of
//! the normalised target against the normalised proposal; they differ
//! between particles only where the particles associate differently.
//!
//! Should Newton fail (a non-finite iterate) the particle moves by the
//! motion model and is weighted by the likelihood, as in implicit MCL: the
//! weights stay exact. Fallbacks are counted.
//!
//! Kept as `implicit`, the literal reading. Its map is refined by selection
//! alone: a landmark keeps the value drawn at its first sighting, so the
//! particles' landmark hypotheses collapse onto a few ancestors' draws and
//! every later sighting pulls the pose onto that draw. On the synthetic car
//! park with the model exact its error at M = 100 is about twice that of
//! [`super::implicit_refine`], which redraws the re-observed feature from
//! all of the particle's sightings of it (docs/slam.md has the figures).

use super::assoc::{innovation, inverse, near, Association, Forced, RangeBearing};
use super::joint::{minimise_joint, JointObjective};
use super::particles::SlamParticles;
use super::path_move::{MoveConfig, PathWindow};
use super::scan_assoc::ScanAssoc;
use super::step_setup::{begin_step, Begin, StepSetup};
use super::{SlamFilter, SlamModel, SlamStats};
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::geometry::{Point, Pose};
use crate::laser::{add_term, term_cost, Curvature, Observation};
use crate::mcl::newton::{minimise, NewtonSettings, Objective};
use beliefbus_core::rng::SimRng;
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3, Vector5};
use rand::RngExt;
use rand_distr::StandardNormal;

/// A sampled landmark: its position θ^{k,j} and the covariance of the
/// draw that produced it (the θ-block of H⁻¹), used only by the shared
/// association rule as the particle's landmark uncertainty Σ_m; F^j keeps
/// θ fixed (reading (i)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampledLandmark {
    pub m: Point,
    pub cov: Matrix2<f64>,
}

/// Implicit SLAM with M particles.
#[derive(Clone, Debug)]
pub struct ImplicitSlam {
    pub model: SlamModel,
    pub set: SlamParticles<SampledLandmark>,
    pub newton: NewtonSettings,
    stats: SlamStats,
    step: usize,
    known_obs: Vec<Observation>,
    known_map: Vec<Point>,
    new_obs: Vec<RangeBearing>,
    forced: Forced,
    shared: bool,
    scan: ScanAssoc,
    existence: Option<super::existence::ExistenceConfig>,
    assoc: Vec<Association>,
    mover: Option<PathWindow>,
}

impl ImplicitSlam {
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
            known_obs: Vec::with_capacity(32),
            known_map: Vec::with_capacity(32),
            new_obs: Vec::with_capacity(32),
            forced: Forced::with_capacity(32),
            shared: false,
            scan: ScanAssoc::with_capacity(32),
            existence: None,
            assoc: Vec::with_capacity(32),
            mover: None,
        })
    }
}

/// Sample a new landmark given the pose x: θ = g(x, z) + L⁻ᵀ ξ with
/// LLᵀ the Hessian of ½‖z − h(x, θ)‖²_{Σ₂⁻¹} at its minimiser g(x, z);
/// returns θ and ½ ξᵀξ − F(θ) − log det L.
pub(super) fn sample_given_pose(
    x: &Pose,
    z: &RangeBearing,
    model: &SlamModel,
    rng: &mut SimRng,
) -> Option<(SampledLandmark, f64)> {
    let (m0, _, _) = inverse(x, z);
    let o = Observation {
        range: z.range,
        bearing: z.bearing,
        landmark: 0,
    };
    let (mut g, mut h) = (Vector3::zeros(), Matrix3::zeros());
    add_term(x, m0, &o, &model.laser, Curvature::Exact, &mut g, &mut h);
    let h2 = Matrix2::new(h[(0, 0)], h[(0, 1)], h[(1, 0)], h[(1, 1)]);
    let l = h2.cholesky()?.l();
    let xi = Vector2::new(rng.sample(StandardNormal), rng.sample(StandardNormal));
    let y = l.tr_solve_lower_triangular(&xi)?;
    let th = [m0[0] + y[0], m0[1] + y[1]];
    let inc =
        0.5 * xi.dot(&xi) - term_cost(x, th, &o, &model.laser) - l[(0, 0)].ln() - l[(1, 1)].ln();
    let li = l.try_inverse()?;
    inc.is_finite().then_some((
        SampledLandmark {
            m: th,
            cov: li.transpose() * li,
        },
        inc,
    ))
}

impl SlamFilter for ImplicitSlam {
    fn name(&self) -> &'static str {
        "implicit"
    }

    fn reset(&mut self, start: &Pose) {
        self.set.reset(start);
        self.stats = SlamStats::default();
        self.step = 0;
        self.forced.clear();
        if let Some(w) = self.mover.as_mut() {
            w.reset(start);
        }
    }

    fn set_path_move(&mut self, cfg: Option<MoveConfig>) -> Result<bool, LocalizationError> {
        if cfg.is_some() && self.set.deferred {
            // The move needs every pose of its window drawn, which the
            // deferred prediction does not do.
            return Err(LocalizationError::Param {
                key: "move".into(),
                msg: "does not combine with interval_prior=on".into(),
            });
        }
        self.mover = match cfg {
            Some(c) => Some(PathWindow::new(self.set.len(), c)?),
            None => None,
        };
        Ok(true)
    }

    fn move_counts(&self) -> (usize, usize) {
        self.mover
            .as_ref()
            .map_or((0, 0), |w| (w.proposed, w.accepted))
    }

    fn step(
        &mut self,
        u: crate::vehicle::Control,
        dt: f64,
        obs: &[RangeBearing],
        rng: &mut SimRng,
    ) -> Result<Pose, LocalizationError> {
        if self.mover.is_some() && self.existence.is_some() {
            // The move's sighting lists hold landmark indices that removal
            // would renumber.
            return Err(LocalizationError::Param {
                key: "existence".into(),
                msg: "does not combine with the resample-move".into(),
            });
        }
        let parts = particle_filter_parts!(self);
        let setup = match begin_step(parts, u, dt, obs, rng, |l: &SampledLandmark| (l.m, l.cov))? {
            Begin::Predicted(estimate) => {
                if let Some(w) = self.mover.as_mut() {
                    let (ute, noise) = self.model.step_noise(u, dt)?;
                    w.advance(ute, u, noise);
                    for (j, x) in self.set.x.iter().enumerate() {
                        w.set_pose(j, *x);
                    }
                }
                return Ok(estimate);
            }
            Begin::Update(c) => c,
        };
        let StepSetup {
            step,
            ute,
            noise,
            model,
            r,
            half_logdet_r,
            ln2pi,
            log_new,
            ..
        } = setup;
        if let Some(w) = self.mover.as_mut() {
            w.advance(ute, u, noise);
        }
        for j in 0..self.set.len() {
            let before = self.set.maps[j].len();
            let x = self.set.x[j];
            let prior = setup.prior(&x, &self.set.acc[j], u);
            let (f, sx, prec) = (prior.f, prior.cov, prior.prec);
            self.known_obs.clear();
            self.known_map.clear();
            self.new_obs.clear();
            let mut discarded = 0usize;
            let map = &self.set.maps[j];
            self.scan.begin(obs.len());
            for (i, z) in obs.iter().enumerate() {
                let (zp, _, _) = inverse(&f, z);
                for (k, lm) in map.iter().enumerate() {
                    if near(lm.m, zp, &model.assoc) {
                        let (nu, hx, hm) = innovation(&f, lm.m, z);
                        let s = hx * sx * hx.transpose() + hm * lm.cov * hm.transpose() + r;
                        self.scan.offer(i, k, &nu, &s, &model.assoc);
                    }
                }
            }
            self.assoc.clear();
            for (i, &a) in self.scan.decide(&model.assoc).iter().enumerate() {
                self.assoc.push(self.forced.get(i, map.len()).unwrap_or(a));
            }
            for (z, a) in obs.iter().zip(&self.assoc) {
                match *a {
                    Association::Known(k) => {
                        if let Some(w) = self.mover.as_mut() {
                            w.add_sighting(j, k, *z);
                        }
                        self.known_obs.push(Observation {
                            range: z.range,
                            bearing: z.bearing,
                            landmark: self.known_map.len(),
                        });
                        self.known_map.push(map.get(k).expect("k < len").m);
                    }
                    Association::New => self.new_obs.push(*z),
                    Association::Discard => discarded += 1,
                }
            }
            self.stats.known += self.known_obs.len();
            self.stats.new += self.new_obs.len();
            self.stats.discarded += discarded;
            let mut lw = discarded as f64 * log_new;
            // The i-th new return becomes landmark base + i whichever way
            // it is drawn below.
            if let Some(w) = self.mover.as_mut() {
                let base = map.len();
                for (i, z) in self.new_obs.iter().enumerate() {
                    w.add_sighting(j, base + i, *z);
                }
            }
            let mut new_start = 0;
            let xn;
            if !self.known_obs.is_empty() {
                let obj = Objective {
                    f,
                    prec,
                    obs: &self.known_obs,
                    map: &self.known_map,
                    laser: model.laser,
                };
                let xi = normal3(rng);
                let sample = minimise(&obj, &self.newton, step).ok().and_then(|m| {
                    self.stats.newton_iters += m.iters;
                    let y = m.l.tr_solve_lower_triangular(&xi)?;
                    let xs = m.mu + y;
                    let inc = 0.5 * xi.dot(&xi) - obj.value(&xs) - m.log_det_l;
                    inc.is_finite().then_some((xs, inc))
                });
                let nk = self.known_obs.len() as f64;
                lw -= nk * (ln2pi + half_logdet_r);
                match sample {
                    Some((xs, inc)) => {
                        xn = xs;
                        lw += inc + prior.norm;
                    }
                    None => {
                        self.stats.fallbacks += 1;
                        xn = prior.draw(&xi);
                        for o in &self.known_obs {
                            lw -= term_cost(&xn, self.known_map[o.landmark], o, &model.laser);
                        }
                    }
                }
            } else if let Some(z0) = self.new_obs.first().copied() {
                let obj = JointObjective {
                    f,
                    prec,
                    z: z0,
                    laser: model.laser,
                };
                let xi = Vector5::from_fn(|_, _| rng.sample(StandardNormal));
                let sample = minimise_joint(&obj, self.newton.max_iter, self.newton.tol, step)
                    .ok()
                    .and_then(|m| {
                        self.stats.newton_iters += m.iters;
                        let y = m.l.tr_solve_lower_triangular(&xi)?;
                        let v = m.mu + y;
                        let inc = 0.5 * xi.dot(&xi) - obj.value(&v) - m.log_det_l;
                        // θ-block of H⁻¹ = L⁻ᵀ L⁻¹.
                        let li = m.l.try_inverse()?;
                        let hinv = li.transpose() * li;
                        let cov =
                            Matrix2::new(hinv[(3, 3)], hinv[(3, 4)], hinv[(4, 3)], hinv[(4, 4)]);
                        inc.is_finite().then_some((v, inc, cov))
                    });
                match sample {
                    Some((v, inc, cov)) => {
                        xn = Pose::new(v[0], v[1], v[2]);
                        lw += inc + prior.norm - half_logdet_r + log_new;
                        self.set.maps[j].push(SampledLandmark {
                            m: [v[3], v[4]],
                            cov,
                        });
                        new_start = 1;
                    }
                    None => {
                        self.stats.fallbacks += 1;
                        xn = prior.draw(&Vector3::new(xi[0], xi[1], xi[2]));
                    }
                }
            } else {
                xn = prior.draw(&normal3(rng));
            }
            for z in &self.new_obs[new_start..] {
                let (th, inc) =
                    sample_given_pose(&xn, z, &model, rng).ok_or(LocalizationError::NonFinite {
                        what: "new landmark sample",
                        step,
                    })?;
                lw += inc - half_logdet_r + log_new;
                self.set.maps[j].push(th);
            }
            if !xn.iter().all(|c| c.is_finite()) {
                return Err(LocalizationError::NonFinite {
                    what: "implicit SLAM pose",
                    step,
                });
            }
            self.set.x[j] = xn;
            self.set.acc[j] = Matrix3::zeros();
            self.set.logw[j] += lw;
            self.set.audit_particle(j, before, &self.assoc);
            if let Some(c) = &self.existence {
                self.stats.removed +=
                    self.set
                        .apply_existence(c, j, before, &self.assoc, |l: &SampledLandmark| l.m);
            }
            if let Some(w) = self.mover.as_mut() {
                w.set_pose(j, xn);
            }
        }
        self.forced.clear();
        let before = self.set.resamplings;
        self.set.reweight(step, rng)?;
        if let Some(w) = self.mover.as_mut() {
            if self.set.resamplings > before {
                w.resample(self.set.ancestors());
                for j in 0..self.set.len() {
                    let map = &self.set.maps[j];
                    self.set.x[j] = w.move_particle(
                        j,
                        &model.laser,
                        |k| map.get(k).expect("a sighting's landmark is in the map").m,
                        rng,
                    );
                }
            }
        }
        Ok(self.set.estimate())
    }

    fn map(&self) -> Vec<Point> {
        self.set.maps[self.set.best()].iter().map(|l| l.m).collect()
    }

    particle_set_diagnostics!();
}
