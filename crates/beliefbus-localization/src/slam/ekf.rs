//! EKF-SLAM (Smith, Self & Cheeseman; the reference of paper 003 §4.2): one
//! Gaussian over the pose and every landmark, y = (x₁, x₂, β, m¹, …, m^N).
//!
//! ```text
//! predict   x ← f(x, u),  P_xx ← F P_xx Fᵀ + Σ₁(β),  P_xm ← F P_xm,   F = I + δ ∂R/∂x
//! update    ν = wrap(z − h(x, m^k)),  H = [H_x 0 … H_m 0 …],  S = H P Hᵀ + Σ₂
//!           K = P Hᵀ S⁻¹,  y ← y + K ν,  P ← P − K S Kᵀ                  (O(n²))
//! augment   m = g(x, z),  P_mm = G_x P_xx G_xᵀ + G_z Σ₂ G_zᵀ,  P_m· = G_x P_x·
//! ```
//!
//! [`EkfState`] holds the algebra for any Jacobians (so a linear model makes
//! it a Kalman filter, which the tests check); [`EkfSlam`] drives it with the
//! Ute and the laser. Every return of a step is associated at the predicted
//! state by the shared ML rule (S as above, with the landmark's marginal and
//! cross-covariances), then applied in turn. The covariance lives in one
//! buffer with a capacity that doubles as landmarks are added (amortised
//! allocation; none in a step that adds no landmark).

use super::assoc::{innovation, inverse, near, Association, Forced, RangeBearing};
use super::assoc_audit::AssocAudit;
use super::map::SharedMap;
use super::scan_assoc::ScanAssoc;
use super::{SlamFilter, SlamModel, SlamStats};
use crate::error::LocalizationError;
use crate::geometry::{frame_rotation, wrap_angle, Point, Pose};
use crate::vehicle::Control;
use beliefbus_core::rng::SimRng;
use nalgebra::{Matrix2, Matrix2x3, Matrix3, Vector2};

/// The joint Gaussian (mean, covariance) of EKF-SLAM.
#[derive(Clone, Debug)]
pub struct EkfState {
    mean: Vec<f64>,
    cov: Vec<f64>,
    cap: usize,
    n: usize,
    pht: Vec<f64>,
    kg: Vec<f64>,
}

impl EkfState {
    /// A pose with covariance and no landmark.
    pub fn new(pose: &Pose, pose_cov: &Matrix3<f64>) -> Self {
        let cap = 3 + 2 * 64;
        let mut s = Self {
            mean: vec![0.0; cap],
            cov: vec![0.0; cap * cap],
            cap,
            n: 3,
            pht: vec![0.0; 2 * cap],
            kg: vec![0.0; 2 * cap],
        };
        s.reset(pose, pose_cov);
        s
    }

    /// Back to a pose with covariance and no landmark.
    pub fn reset(&mut self, pose: &Pose, pose_cov: &Matrix3<f64>) {
        self.n = 3;
        self.cov.fill(0.0);
        for i in 0..3 {
            self.mean[i] = pose[i];
            for j in 0..3 {
                self.cov[i * self.cap + j] = pose_cov[(i, j)];
            }
        }
    }

    /// State dimension 3 + 2N.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Number of landmarks N.
    pub fn landmarks(&self) -> usize {
        (self.n - 3) / 2
    }

    /// Covariance entry (i, j).
    pub fn cov(&self, i: usize, j: usize) -> f64 {
        self.cov[i * self.cap + j]
    }

    /// Mean entry i.
    pub fn mean(&self, i: usize) -> f64 {
        self.mean[i]
    }

    pub fn pose(&self) -> Pose {
        Pose::new(self.mean[0], self.mean[1], self.mean[2])
    }

    /// Landmark k's mean.
    pub fn landmark(&self, k: usize) -> Point {
        [self.mean[3 + 2 * k], self.mean[4 + 2 * k]]
    }

    /// The 2×2 block of rows a.., columns b...
    fn block2(&self, a: usize, b: usize) -> Matrix2<f64> {
        Matrix2::new(
            self.cov(a, b),
            self.cov(a, b + 1),
            self.cov(a + 1, b),
            self.cov(a + 1, b + 1),
        )
    }

    /// P_xx.
    pub fn pose_cov(&self) -> Matrix3<f64> {
        Matrix3::from_fn(|i, j| self.cov(i, j))
    }

    /// P_{m^k m^k}.
    pub fn landmark_cov(&self, k: usize) -> Matrix2<f64> {
        self.block2(3 + 2 * k, 3 + 2 * k)
    }

    /// H P Hᵀ for H = [H_x at the pose, H_m at landmark k].
    pub fn project(&self, hx: &Matrix2x3<f64>, hm: &Matrix2<f64>, k: usize) -> Matrix2<f64> {
        let l = 3 + 2 * k;
        let pxm = Matrix2x3::from_fn(|i, j| self.cov(l + i, j)).transpose();
        hx * self.pose_cov() * hx.transpose()
            + hm * self.landmark_cov(k) * hm.transpose()
            + hx * pxm * hm.transpose()
            + hm * pxm.transpose() * hx.transpose()
    }

    /// Predict: the pose mean becomes `pose`, P_xx ← F P_xx Fᵀ + Q, P_xm ← F P_xm.
    pub fn predict(&mut self, pose: &Pose, fx: &Matrix3<f64>, q: &Matrix3<f64>) {
        let cap = self.cap;
        let pxx = self.pose_cov();
        let nxx = fx * pxx * fx.transpose() + q;
        for j in 3..self.n {
            let col = [self.cov(0, j), self.cov(1, j), self.cov(2, j)];
            for i in 0..3 {
                let v = fx[(i, 0)] * col[0] + fx[(i, 1)] * col[1] + fx[(i, 2)] * col[2];
                self.cov[i * cap + j] = v;
                self.cov[j * cap + i] = v;
            }
        }
        for i in 0..3 {
            self.mean[i] = pose[i];
            for j in 0..3 {
                self.cov[i * cap + j] = nxx[(i, j)];
            }
        }
    }

    /// Update with innovation ν of a return on landmark k; `wrap_heading`
    /// wraps β after the update. None if S is not positive definite.
    pub fn update(
        &mut self,
        nu: &Vector2<f64>,
        hx: &Matrix2x3<f64>,
        hm: &Matrix2<f64>,
        k: usize,
        r: &Matrix2<f64>,
        wrap_heading: bool,
    ) -> Option<()> {
        let (n, cap, l) = (self.n, self.cap, 3 + 2 * k);
        if l + 1 >= n {
            return None;
        }
        // P Hᵀ, n × 2 (row-major pairs).
        for i in 0..n {
            let row = &self.cov[i * cap..i * cap + n];
            for a in 0..2 {
                self.pht[2 * i + a] = hx[(a, 0)] * row[0]
                    + hx[(a, 1)] * row[1]
                    + hx[(a, 2)] * row[2]
                    + hm[(a, 0)] * row[l]
                    + hm[(a, 1)] * row[l + 1];
            }
        }
        let mut s = *r;
        for a in 0..2 {
            for b in 0..2 {
                let mut v = 0.0;
                for c in 0..3 {
                    v += hx[(a, c)] * self.pht[2 * c + b];
                }
                v += hm[(a, 0)] * self.pht[2 * l + b] + hm[(a, 1)] * self.pht[2 * (l + 1) + b];
                s[(a, b)] += v;
            }
        }
        let s = 0.5 * (s + s.transpose());
        let sinv = s.try_inverse()?;
        if !(s[(0, 0)] > 0.0 && s.determinant() > 0.0) {
            return None;
        }
        for i in 0..n {
            let (p0, p1) = (self.pht[2 * i], self.pht[2 * i + 1]);
            self.kg[2 * i] = p0 * sinv[(0, 0)] + p1 * sinv[(1, 0)];
            self.kg[2 * i + 1] = p0 * sinv[(0, 1)] + p1 * sinv[(1, 1)];
            self.mean[i] += self.kg[2 * i] * nu[0] + self.kg[2 * i + 1] * nu[1];
        }
        if wrap_heading {
            self.mean[2] = wrap_angle(self.mean[2]);
        }
        // P ← P − K (P Hᵀ)ᵀ, kept symmetric by computing the upper triangle.
        for i in 0..n {
            let (k0, k1) = (self.kg[2 * i], self.kg[2 * i + 1]);
            for j in i..n {
                let v = self.cov[i * cap + j] - k0 * self.pht[2 * j] - k1 * self.pht[2 * j + 1];
                self.cov[i * cap + j] = v;
                self.cov[j * cap + i] = v;
            }
        }
        Some(())
    }

    /// Append landmark m = g(x, z) with ∂g/∂x = G_x, ∂g/∂z = G_z.
    pub fn augment(&mut self, m: Point, gx: &Matrix2x3<f64>, gz: &Matrix2<f64>, r: &Matrix2<f64>) {
        if self.n + 2 > self.cap {
            let ncap = 2 * self.cap;
            let mut cov = vec![0.0; ncap * ncap];
            for i in 0..self.n {
                cov[i * ncap..i * ncap + self.n]
                    .copy_from_slice(&self.cov[i * self.cap..i * self.cap + self.n]);
            }
            self.cov = cov;
            self.mean.resize(ncap, 0.0);
            self.pht.resize(2 * ncap, 0.0);
            self.kg.resize(2 * ncap, 0.0);
            self.cap = ncap;
        }
        let (n, cap) = (self.n, self.cap);
        for j in 0..n {
            let col = [self.cov(0, j), self.cov(1, j), self.cov(2, j)];
            for a in 0..2 {
                let v = gx[(a, 0)] * col[0] + gx[(a, 1)] * col[1] + gx[(a, 2)] * col[2];
                self.cov[(n + a) * cap + j] = v;
                self.cov[j * cap + n + a] = v;
            }
        }
        let pmm = gx * self.pose_cov() * gx.transpose() + gz * r * gz.transpose();
        for a in 0..2 {
            for b in 0..2 {
                self.cov[(n + a) * cap + n + b] = pmm[(a, b)];
            }
        }
        self.mean[n] = m[0];
        self.mean[n + 1] = m[1];
        self.n += 2;
    }
}

/// ∂f/∂x = I + δ ∂R/∂x of the corrected kinematics (R depends on β only).
pub fn motion_jacobian(ute: &crate::vehicle::Ute, beta: f64, u: Control) -> Matrix3<f64> {
    let (s, c) = beta.sin_cos();
    let k = u.alpha.tan() / ute.l;
    let mut f = Matrix3::identity();
    f[(0, 2)] = ute.dt * u.v * (-s - k * (ute.a * c - ute.b * s));
    f[(1, 2)] = ute.dt * u.v * (c - k * (ute.a * s + ute.b * c));
    f
}

/// EKF-SLAM on the Ute.
#[derive(Clone, Debug)]
pub struct EkfSlam {
    pub model: SlamModel,
    pub state: EkfState,
    stats: SlamStats,
    step: usize,
    assoc: Vec<Association>,
    forced: Forced,
    scan: ScanAssoc,
    /// Each landmark's true origin and the association's score
    /// ([`super::assoc_audit`]).
    tags: SharedMap<u32>,
    audit: AssocAudit,
}

impl EkfSlam {
    pub fn new(model: SlamModel) -> Result<Self, LocalizationError> {
        model.validate()?;
        Ok(Self {
            model,
            state: EkfState::new(&Pose::zeros(), &Matrix3::zeros()),
            stats: SlamStats::default(),
            step: 0,
            assoc: Vec::with_capacity(32),
            forced: Forced::with_capacity(32),
            scan: ScanAssoc::with_capacity(32),
            tags: SharedMap::new(),
            audit: AssocAudit::default(),
        })
    }
}

impl SlamFilter for EkfSlam {
    fn name(&self) -> &'static str {
        "ekf"
    }

    fn reset(&mut self, start: &Pose) {
        self.state.reset(start, &Matrix3::zeros());
        self.stats = SlamStats::default();
        self.step = 0;
        self.forced.clear();
        self.tags = SharedMap::new();
        self.audit.reset();
    }

    fn step(
        &mut self,
        u: Control,
        dt: f64,
        obs: &[RangeBearing],
        _rng: &mut SimRng,
    ) -> Result<Pose, LocalizationError> {
        self.step += 1;
        let step = self.step;
        let (ute, noise) = self.model.step_noise(u, dt)?;
        let x = self.state.pose();
        let t = frame_rotation(x[2]);
        let q = t * noise.chol * noise.chol.transpose() * t.transpose();
        let fx = motion_jacobian(&ute, x[2], u);
        let mut f = ute.predict_mean(&x, u);
        f[2] = wrap_angle(f[2]);
        self.state.predict(&f, &fx, &q);
        if obs.is_empty() {
            return Ok(self.state.pose());
        }
        self.stats.updates += 1;
        let model = self.model;
        let r = model.r();
        self.assoc.clear();
        self.scan.begin(obs.len());
        for (i, z) in obs.iter().enumerate() {
            let (zp, _, _) = inverse(&f, z);
            for k in 0..self.state.landmarks() {
                let m = self.state.landmark(k);
                if near(m, zp, &model.assoc) {
                    let (nu, hx, hm) = innovation(&f, m, z);
                    let s = self.state.project(&hx, &hm, k) + r;
                    self.scan.offer(i, k, &nu, &s, &model.assoc);
                }
            }
        }
        let n = self.state.landmarks();
        for (i, &a) in self.scan.decide(&model.assoc).iter().enumerate() {
            self.assoc.push(self.forced.get(i, n).unwrap_or(a));
        }
        self.forced.clear();
        for (z, a) in obs.iter().zip(&self.assoc) {
            let x = self.state.pose();
            match *a {
                Association::Known(k) => {
                    let (nu, hx, hm) = innovation(&x, self.state.landmark(k), z);
                    self.state.update(&nu, &hx, &hm, k, &r, true).ok_or(
                        LocalizationError::NotPositiveDefinite("EKF-SLAM innovation covariance"),
                    )?;
                    self.stats.known += 1;
                }
                Association::New => {
                    let (m, gx, gz) = inverse(&x, z);
                    self.state.augment(m, &gx, &gz, &r);
                    self.stats.new += 1;
                }
                Association::Discard => self.stats.discarded += 1,
            }
        }
        self.audit
            .score(&mut self.tags, n, self.state.landmarks(), &self.assoc);
        let p = self.state.pose();
        if !p.iter().all(|c| c.is_finite()) {
            return Err(LocalizationError::NonFinite {
                what: "EKF-SLAM pose",
                step,
            });
        }
        Ok(p)
    }

    fn map(&self) -> Vec<Point> {
        (0..self.state.landmarks())
            .map(|k| self.state.landmark(k))
            .collect()
    }

    fn force_association(&mut self, a: &[Association]) {
        self.forced.set(a);
    }

    fn set_exclusion(&mut self, e: super::scan_assoc::Exclusion) {
        self.scan.exclusive = e;
    }

    fn position_spread(&self) -> f64 {
        let p = self.state.pose_cov();
        (p[(0, 0)] + p[(1, 1)]).max(0.0).sqrt()
    }

    fn stats(&self) -> SlamStats {
        SlamStats {
            audit: self.audit.counts(),
            ..self.stats
        }
    }

    fn set_true_landmarks(&mut self, ids: &[usize]) {
        self.audit.set_truth(ids);
    }
}
