//! A sampled landmark that remembers how it was seen: its current value θ,
//! the particle's last [`TERMS`] sightings (pose X_i^j and return z_i) as
//! exact terms of F_past(θ) = Σ_i ½‖z_i − h(X_i^j, θ)‖²_{Σ₂⁻¹}, and the
//! older sightings folded into one Gaussian factor ½θᵀΛθ − ηᵀθ,
//! linearised at the value θ had when they were folded.
//!
//! Memory per particle and landmark is constant, so the particle set takes
//! O(M·N) (paper 003 §4.2). The fold is the one approximation: with the
//! laser's Σ₂ (5 cm, 0.05°) a sighting's term is quadratic in θ to within
//! σ²/r ≈ 2·10⁻⁴ m at r = 15 m, far below any landmark's spread.

use super::assoc::{innovation, RangeBearing};
use super::refine::{newton, Minimum, Objective};
use crate::geometry::{Point, Pose};
use crate::laser::{add_term, Curvature, LaserNoise, Observation};
use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector2, Vector3};

/// Sightings kept exactly per landmark.
pub const TERMS: usize = 8;

/// One landmark of one particle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefinedLandmark {
    pub m: Point,
    /// θ-block of the last draw's H⁻¹: θ's spread marginal over the pose of
    /// that step.
    pub cov: Matrix2<f64>,
    /// θ's conditional given the particle's path: the minimiser of F_past
    /// and (∇²F_past)⁻¹ there ([`RefinedLandmark::refresh_mode`]); what a
    /// FastSLAM particle's landmark EKF holds as mean and covariance.
    pub mode: Point,
    pub mode_cov: Matrix2<f64>,
    /// The Newton minimum of F_past from θ = m, kept for the backward
    /// kernel of the next sighting (the same minimum it would find).
    pub past_min: Option<Minimum<2>>,
    poses: [Pose; TERMS],
    zs: [RangeBearing; TERMS],
    len: usize,
    lambda: Matrix2<f64>,
    eta: Vector2<f64>,
    /// Sightings folded into (Λ, η).
    pub folded: usize,
}

impl RefinedLandmark {
    /// A landmark first seen from x with return z, drawn at m.
    pub fn new(m: Point, cov: Matrix2<f64>, x: &Pose, z: &RangeBearing) -> Self {
        let mut s = Self {
            m,
            cov,
            mode: m,
            mode_cov: cov,
            past_min: None,
            poses: [Pose::zeros(); TERMS],
            zs: [RangeBearing {
                range: 0.0,
                bearing: 0.0,
            }; TERMS],
            len: 0,
            lambda: Matrix2::zeros(),
            eta: Vector2::zeros(),
            folded: 0,
        };
        s.add_sighting(x, z, &Matrix2::identity());
        s
    }

    /// Exact sightings held.
    pub fn sightings(&self) -> usize {
        self.len
    }

    /// Append a sighting; when full, fold the oldest into (Λ, η),
    /// linearising its term at the current θ. `rinv` is Σ₂⁻¹.
    pub fn add_sighting(&mut self, x: &Pose, z: &RangeBearing, rinv: &Matrix2<f64>) {
        if self.len == TERMS {
            let (nu, _, hm) = innovation(&self.poses[0], self.m, &self.zs[0]);
            // z − h(θ) ≈ ν₀ − H_m (θ − θ*):  ½‖·‖² = ½θᵀΛθ − ηᵀθ + const.
            let th = Vector2::new(self.m[0], self.m[1]);
            let a = hm.transpose() * rinv;
            self.lambda += a * hm;
            self.eta += a * (nu + hm * th);
            self.folded += 1;
            self.poses.copy_within(1.., 0);
            self.zs.copy_within(1.., 0);
            self.len -= 1;
        }
        self.poses[self.len] = *x;
        self.zs[self.len] = *z;
        self.len += 1;
    }

    /// Where association looks for the landmark and with what covariance:
    /// the conditional mode given the path, or the last draw.
    pub fn assoc_view(&self, at_mode: bool) -> (Point, Matrix2<f64>) {
        if at_mode {
            (self.mode, self.mode_cov)
        } else {
            (self.m, self.cov)
        }
    }

    /// Find θ's conditional mode given the path (Newton on F_past from the
    /// current draw m) and keep it with its covariance; without a minimum
    /// (Newton failed) the draw and its marginal covariance stand in.
    pub fn refresh_mode(&mut self, laser: LaserNoise, max_iter: usize, tol: f64) {
        let start = SVector::<f64, 2>::new(self.m[0], self.m[1]);
        let found = newton(&Past { lm: self, laser }, start, max_iter, tol);
        self.past_min = found;
        match found.and_then(|mn| {
            let li = mn.l.try_inverse()?;
            Some((mn.mu, li.transpose() * li))
        }) {
            Some((mu, cov)) => {
                self.mode = [mu[0], mu[1]];
                self.mode_cov = cov;
            }
            None => {
                self.mode = self.m;
                self.mode_cov = self.cov;
            }
        }
    }

    /// F_past(θ) with its gradient and Hessian in θ, added to g and h.
    pub fn add_past(
        &self,
        th: Point,
        laser: &LaserNoise,
        curv: Curvature,
        g: &mut Vector2<f64>,
        h: &mut Matrix2<f64>,
    ) -> f64 {
        let t = Vector2::new(th[0], th[1]);
        let lt = self.lambda * t;
        let mut val = 0.5 * t.dot(&lt) - self.eta.dot(&t);
        *g += lt - self.eta;
        *h += self.lambda;
        for (x, z) in self.poses[..self.len].iter().zip(&self.zs[..self.len]) {
            let (mut g3, mut h3) = (Vector3::zeros(), Matrix3::zeros());
            let o = Observation {
                range: z.range,
                bearing: z.bearing,
                landmark: 0,
            };
            // The term depends on x₁₂ − θ: ∇_θ = −∇_{x₁₂}, ∇²_θθ = ∇²_{x₁₂}.
            val += add_term(x, th, &o, laser, curv, &mut g3, &mut h3);
            g[0] -= g3[0];
            g[1] -= g3[1];
            for a in 0..2 {
                for b in 0..2 {
                    h[(a, b)] += h3[(a, b)];
                }
            }
        }
        val
    }
}

/// F_past as an objective over θ.
pub struct Past<'a> {
    pub lm: &'a RefinedLandmark,
    pub laser: LaserNoise,
}

impl Objective<2> for Past<'_> {
    fn eval(
        &self,
        v: &SVector<f64, 2>,
        curv: Curvature,
        g: &mut SVector<f64, 2>,
        h: &mut SMatrix<f64, 2, 2>,
    ) -> f64 {
        *g = Vector2::zeros();
        *h = Matrix2::zeros();
        self.lm.add_past([v[0], v[1]], &self.laser, curv, g, h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laser::predict;

    fn rb(x: &Pose, m: Point, e: (f64, f64)) -> RangeBearing {
        let (r, b) = predict(x, m);
        RangeBearing {
            range: r + e.0,
            bearing: b + e.1,
        }
    }

    /// F_past's θ-derivatives against central differences, with folded
    /// sightings present.
    #[test]
    fn past_derivatives_match_finite_differences() {
        let laser = LaserNoise {
            var_range: 0.01,
            var_bearing: 1e-4,
        };
        let rinv = Matrix2::new(100.0, 0.0, 0.0, 1e4);
        let m = [5.0, 7.0];
        let x0 = Pose::new(0.0, 0.0, 0.1);
        let mut lm = RefinedLandmark::new(m, Matrix2::identity(), &x0, &rb(&x0, m, (0.02, 0.003)));
        for k in 0..TERMS + 3 {
            let x = Pose::new(0.5 * k as f64, 0.2 * k as f64, 0.1 - 0.05 * k as f64);
            lm.add_sighting(&x, &rb(&x, m, (0.01 * k as f64, -0.002)), &rinv);
        }
        assert_eq!(lm.sightings(), TERMS);
        assert_eq!(lm.folded, 4);
        let past = Past { lm: &lm, laser };
        let v = SVector::<f64, 2>::new(5.3, 6.6);
        let (mut g, mut h) = (Vector2::zeros(), Matrix2::zeros());
        past.eval(&v, Curvature::Exact, &mut g, &mut h);
        let e = 1e-6;
        for k in 0..2 {
            let (mut vp, mut vm) = (v, v);
            vp[k] += e;
            vm[k] -= e;
            let fd = (past.value(&vp) - past.value(&vm)) / (2.0 * e);
            assert!(
                (fd - g[k]).abs() < 1e-5 * g.norm().max(1.0),
                "{fd} vs {}",
                g[k]
            );
            let (mut gp, mut gm, mut d) = (Vector2::zeros(), Vector2::zeros(), Matrix2::zeros());
            past.eval(&vp, Curvature::Exact, &mut gp, &mut d);
            past.eval(&vm, Curvature::Exact, &mut gm, &mut d);
            let col = (gp - gm) / (2.0 * e);
            for i in 0..2 {
                assert!((col[i] - h[(i, k)]).abs() < 1e-5 * h.norm(), "({i},{k})");
            }
        }
    }

    /// The conditional mode given the path, against an objective written
    /// out independently (the sightings' range-bearing costs summed by
    /// `term_cost`; the fold is off with ≤ TERMS sightings): its central
    /// difference gradient vanishes at the mode, and the inverse of its
    /// finite-difference Hessian is the stored covariance. The minimum
    /// kept for the backward kernel is the one Newton finds from the draw,
    /// so the next sighting's backward term is unchanged.
    #[test]
    fn refreshed_mode_is_the_minimiser_of_the_past_sightings_with_their_covariance() {
        use crate::laser::term_cost;
        use crate::slam::refine::{backward_at, backward_term};
        let laser = LaserNoise {
            var_range: 0.01,
            var_bearing: 1e-4,
        };
        let rinv = Matrix2::new(100.0, 0.0, 0.0, 1e4);
        let m = [5.0, 7.0];
        let poses: Vec<Pose> = (0..6)
            .map(|k| Pose::new(0.7 * k as f64, -0.3 * k as f64, 0.2 + 0.1 * k as f64))
            .collect();
        let errs = [
            (0.05, 0.004),
            (-0.08, -0.01),
            (0.02, 0.012),
            (0.11, -0.006),
            (-0.03, 0.0),
            (0.06, 0.009),
        ];
        let zs: Vec<RangeBearing> = poses.iter().zip(errs).map(|(x, e)| rb(x, m, e)).collect();
        // The last draw sits 20 cm off.
        let mut lm = RefinedLandmark::new([5.2, 6.85], Matrix2::identity(), &poses[0], &zs[0]);
        for (x, z) in poses.iter().zip(&zs).skip(1) {
            lm.add_sighting(x, z, &rinv);
        }
        lm.refresh_mode(laser, 50, 1e-14);
        let f = |t: [f64; 2]| -> f64 {
            poses
                .iter()
                .zip(&zs)
                .map(|(x, z)| {
                    let o = Observation {
                        range: z.range,
                        bearing: z.bearing,
                        landmark: 0,
                    };
                    term_cost(x, t, &o, &laser)
                })
                .sum()
        };
        let e = 1e-4;
        let at = |d0: f64, d1: f64| f([lm.mode[0] + d0, lm.mode[1] + d1]);
        let g = [
            (at(e, 0.0) - at(-e, 0.0)) / (2.0 * e),
            (at(0.0, e) - at(0.0, -e)) / (2.0 * e),
        ];
        let h00 = (at(e, 0.0) - 2.0 * at(0.0, 0.0) + at(-e, 0.0)) / (e * e);
        let h11 = (at(0.0, e) - 2.0 * at(0.0, 0.0) + at(0.0, -e)) / (e * e);
        let h01 = (at(e, e) - at(e, -e) - at(-e, e) + at(-e, -e)) / (4.0 * e * e);
        let h = Matrix2::new(h00, h01, h01, h11);
        // Curvature ~ 1e3 per m²: a gradient of 1e-3 is a micrometre off.
        assert!(g[0].abs() < 1e-3 && g[1].abs() < 1e-3, "gradient {g:?}");
        let cov = h.try_inverse().unwrap();
        assert!(
            (cov - lm.mode_cov).norm() < 1e-4 * cov.norm(),
            "{cov:?} vs {:?}",
            lm.mode_cov
        );
        // Not the draw: the mode moved from it by more than its spread.
        let d = Vector2::new(lm.mode[0] - lm.m[0], lm.mode[1] - lm.m[1]);
        assert!(d.dot(&(cov.try_inverse().unwrap() * d)) > 25.0);
        assert_eq!(lm.assoc_view(true), (lm.mode, lm.mode_cov));
        assert_eq!(lm.assoc_view(false), (lm.m, lm.cov));
        // The kept minimum gives the backward term Newton would give.
        let past = Past { lm: &lm, laser };
        let old = SVector::<f64, 2>::new(lm.m[0], lm.m[1]);
        let (t, _) = backward_term(&past, &old, 50, 1e-14).unwrap();
        assert_eq!(
            backward_at(&past, &old, lm.past_min.as_ref().unwrap()),
            Some(t)
        );
    }
}
