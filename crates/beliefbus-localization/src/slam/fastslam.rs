//! FastSLAM 1.0 (Montemerlo et al. 2002) and FastSLAM 2.0 (Montemerlo et
//! al. 2003), the baselines of paper 003 §4.2: per particle a pose and one
//! 2-D EKF (mean m, covariance P) per landmark.
//!
//! ```text
//! 1.0  x^j ~ p(x | X^j, u)                       (motion-model proposal)
//!      log W^j += Σ_known log N(ν; 0, H_m P H_mᵀ + Σ₂)  at the sampled pose
//! 2.0  μ = f^j, Σ = Σ₁; for each known return:   (proposal including the observation)
//!        Q = H_m P H_mᵀ + Σ₂,  S = H_x Σ H_xᵀ + Q,  log W^j += log N(ν(μ); 0, S)
//!        K = Σ H_xᵀ S⁻¹,  μ += K ν,  Σ −= K S Kᵀ
//!      x^j ~ N(μ, Σ)
//! both: landmark EKF update at x^j  m += K_m ν,  P −= K_m S_m K_mᵀ,  K_m = P H_mᵀ S_m⁻¹
//!       new landmark  m = g(x^j, z),  P = G_z Σ₂ G_zᵀ,  log W^j += log(r/A)
//!       discarded return  log W^j += log(1/A)
//! ```
//!
//! The association (shared rule, [`super::assoc`]) is made at f^j with
//! S = H_x Σ₁ H_xᵀ + H_m P H_mᵀ + Σ₂. Particles' maps share blocks
//! ([`super::map`]) so resampling copies are cheap.

use super::assoc::{innovation, inverse, near, Association, Forced, RangeBearing};
use super::particles::SlamParticles;
use super::scan_assoc::ScanAssoc;
use super::step_setup::{begin_step, Begin, StepSetup};
use super::{SlamFilter, SlamModel, SlamStats};
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::geometry::{frame_rotation, Point, Pose};
use beliefbus_core::rng::SimRng;
use nalgebra::{Matrix2, Matrix3, Vector2};

/// One landmark's EKF.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Landmark {
    pub m: Vector2<f64>,
    pub p: Matrix2<f64>,
}

/// Which FastSLAM.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Version {
    One,
    Two,
}

/// log N(ν; 0, S) and S⁻¹ (None if S is not positive definite).
pub fn log_normal(nu: &Vector2<f64>, s: &Matrix2<f64>) -> Option<(f64, Matrix2<f64>)> {
    let det = s[(0, 0)] * s[(1, 1)] - s[(0, 1)] * s[(1, 0)];
    if !(det > 0.0) {
        return None;
    }
    let inv = Matrix2::new(s[(1, 1)], -s[(0, 1)], -s[(1, 0)], s[(0, 0)]) / det;
    let ll = -(2.0 * std::f64::consts::PI).ln() - 0.5 * det.ln() - 0.5 * nu.dot(&(inv * nu));
    Some((ll, inv))
}

/// FastSLAM 2.0's proposal update for one return, linearised at μ: with
/// S = H_x Σ H_xᵀ + Q, μ += K ν, Σ −= K S Kᵀ (K = Σ H_xᵀ S⁻¹); returns
/// log N(ν; 0, S), the return's factor of the weight. For a linear model
/// this is the optimal Gaussian proposal p(x | x_{n−1}, z) and its
/// predictive likelihood p(z | x_{n−1}).
pub fn gaussian_proposal_update(
    mu: &mut Pose,
    sig: &mut Matrix3<f64>,
    nu: &Vector2<f64>,
    hx: &nalgebra::Matrix2x3<f64>,
    q: &Matrix2<f64>,
) -> Option<f64> {
    let s = hx * *sig * hx.transpose() + q;
    let (ll, sinv) = log_normal(nu, &s)?;
    let k = *sig * hx.transpose() * sinv;
    *mu += k * nu;
    *sig -= k * s * k.transpose();
    *sig = 0.5 * (*sig + sig.transpose());
    Some(ll)
}

/// The EKF update of a landmark seen from a known pose x; returns the new
/// landmark and log N(ν; 0, H_m P H_mᵀ + Σ₂).
pub fn update_landmark(
    x: &Pose,
    lm: &Landmark,
    z: &RangeBearing,
    r: &Matrix2<f64>,
) -> Option<(Landmark, f64)> {
    let (nu, _, hm) = innovation(x, [lm.m[0], lm.m[1]], z);
    let s = hm * lm.p * hm.transpose() + r;
    let (ll, sinv) = log_normal(&nu, &s)?;
    let k = lm.p * hm.transpose() * sinv;
    let p = lm.p - k * s * k.transpose();
    Some((
        Landmark {
            m: lm.m + k * nu,
            p: 0.5 * (p + p.transpose()),
        },
        ll,
    ))
}

/// A new landmark from pose x and return z.
pub fn init_landmark(x: &Pose, z: &RangeBearing, r: &Matrix2<f64>) -> Landmark {
    let (m, _, gz) = inverse(x, z);
    Landmark {
        m: Vector2::new(m[0], m[1]),
        p: gz * r * gz.transpose(),
    }
}

/// FastSLAM 1.0 or 2.0 with M particles.
#[derive(Clone, Debug)]
pub struct FastSlam {
    pub model: SlamModel,
    pub version: Version,
    pub set: SlamParticles<Landmark>,
    stats: SlamStats,
    step: usize,
    assoc: Vec<Association>,
    forced: Forced,
    shared: bool,
    scan: ScanAssoc,
    existence: Option<super::existence::ExistenceConfig>,
}

impl FastSlam {
    pub fn new(
        model: SlamModel,
        version: Version,
        m: usize,
        ess_threshold: f64,
    ) -> Result<Self, LocalizationError> {
        model.validate()?;
        Ok(Self {
            model,
            version,
            set: SlamParticles::new(m, ess_threshold)?,
            stats: SlamStats::default(),
            step: 0,
            assoc: Vec::with_capacity(32),
            forced: Forced::with_capacity(32),
            shared: false,
            scan: ScanAssoc::with_capacity(32),
            existence: None,
        })
    }
}

impl SlamFilter for FastSlam {
    fn name(&self) -> &'static str {
        match self.version {
            Version::One => "fastslam1",
            Version::Two => "fastslam2",
        }
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
        let parts = particle_filter_parts!(self);
        let setup = match begin_step(parts, u, dt, obs, rng, |l: &Landmark| {
            ([l.m[0], l.m[1]], l.p)
        })? {
            Begin::Predicted(estimate) => return Ok(estimate),
            Begin::Update(c) => c,
        };
        let StepSetup {
            step,
            model,
            r,
            log_new,
            ..
        } = setup;
        let bad = |what| LocalizationError::NonFinite { what, step };
        for j in 0..self.set.len() {
            let before = self.set.maps[j].len();
            let x = self.set.x[j];
            let prior = setup.prior(&x, &self.set.acc[j], u);
            let (f, sx) = (prior.f, prior.cov);
            self.assoc.clear();
            let map = &self.set.maps[j];
            self.scan.begin(obs.len());
            for (i, z) in obs.iter().enumerate() {
                let (zp, _, _) = inverse(&f, z);
                for (k, lm) in map.iter().enumerate() {
                    let m = [lm.m[0], lm.m[1]];
                    if near(m, zp, &model.assoc) {
                        let (nu, hx, hm) = innovation(&f, m, z);
                        let s = hx * sx * hx.transpose() + hm * lm.p * hm.transpose() + r;
                        self.scan.offer(i, k, &nu, &s, &model.assoc);
                    }
                }
            }
            for (i, &a) in self.scan.decide(&model.assoc).iter().enumerate() {
                self.assoc.push(self.forced.get(i, map.len()).unwrap_or(a));
            }
            let mut lw = 0.0;
            let xi = normal3(rng);
            let xn = match self.version {
                Version::One => prior.draw(&xi),
                Version::Two => {
                    let (mut mu, mut sig) = (f, sx);
                    for (z, a) in obs.iter().zip(&self.assoc) {
                        if let Association::Known(k) = *a {
                            let lm = map.get(k).expect("k < len");
                            let (nu, hx, hm) = innovation(&mu, [lm.m[0], lm.m[1]], z);
                            let q = hm * lm.p * hm.transpose() + r;
                            let ll = gaussian_proposal_update(&mut mu, &mut sig, &nu, &hx, &q)
                                .ok_or_else(|| bad("FastSLAM 2.0 innovation"))?;
                            lw += ll;
                        }
                    }
                    match sig.cholesky() {
                        Some(c) => mu + c.l() * xi,
                        None => {
                            self.stats.fallbacks += 1;
                            prior.draw(&xi)
                        }
                    }
                }
            };
            if !xn.iter().all(|c| c.is_finite()) {
                return Err(bad("FastSLAM pose"));
            }
            let map = &mut self.set.maps[j];
            for (z, a) in obs.iter().zip(&self.assoc) {
                match *a {
                    Association::Known(k) => {
                        let lm = *map.get(k).expect("k < len");
                        let (nl, ll) =
                            update_landmark(&xn, &lm, z, &r).ok_or_else(|| bad("landmark EKF"))?;
                        if self.version == Version::One {
                            lw += ll;
                        }
                        map.set(k, nl);
                        self.stats.known += 1;
                    }
                    Association::New => {
                        map.push(init_landmark(&xn, z, &r));
                        lw += z.range.ln() + log_new;
                        self.stats.new += 1;
                    }
                    Association::Discard => {
                        lw += log_new;
                        self.stats.discarded += 1;
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
                        .apply_existence(c, j, before, &self.assoc, |l: &Landmark| {
                            [l.m[0], l.m[1]]
                        });
            }
        }
        self.forced.clear();
        self.set.reweight(step, rng)?;
        Ok(self.set.estimate())
    }

    fn map(&self) -> Vec<Point> {
        self.set.maps[self.set.best()]
            .iter()
            .map(|l| [l.m[0], l.m[1]])
            .collect()
    }

    particle_set_diagnostics!();
}

/// Σ₁ in the world frame at heading β from the body-frame Cholesky factor.
pub fn world_step_cov(chol: &Matrix3<f64>, beta: f64) -> Matrix3<f64> {
    let t = frame_rotation(beta);
    t * chol * chol.transpose() * t.transpose()
}
