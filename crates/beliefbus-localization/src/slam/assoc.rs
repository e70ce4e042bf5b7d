//! The range/bearing geometry every SLAM filter shares and the one
//! maximum-likelihood data association they all use (paper 003 §4.2:
//! "the same ML data association for all methods", after Montemerlo et al.).
//!
//! ```text
//! h(x, m) = (‖m − x₁₂‖, atan2(m₂ − x₂, m₁ − x₁) − β + π/2)
//! H_x = [[−d₁/r, −d₂/r, 0], [d₂/r², −d₁/r², −1]],  H_m = [[d₁/r, d₂/r], [−d₂/r², d₁/r²]]   (d = m − x₁₂)
//! g(x, z) = x₁₂ + z_r (cos(β + z_b − π/2), sin(β + z_b − π/2))          (inverse observation)
//! ```
//!
//! Association of one return z against a map, evaluated at the predicted
//! pose (before the filter's own update):
//!
//! ```text
//! ν_k = wrap(z − h(x̂, m_k)),  S_k = H_x Σ_x H_xᵀ + H_m Σ_mk H_mᵀ + H_x Σ_xmk H_mᵀ + (·)ᵀ + Σ₂,
//! d_k² = ν_kᵀ S_k⁻¹ ν_k
//! k* = argmax_k N(ν_k; 0, S_k) over the k with d_k² < gate         → known landmark k*
//! otherwise: new landmark if every d_k² > new_threshold, else discarded (ambiguous)
//! ```
//!
//! Σ_x is each method's own pose uncertainty at the prediction (one motion
//! step Σ₁ for a particle, the joint P_xx for EKF-SLAM), Σ_m its landmark
//! uncertainty (a FastSLAM landmark EKF, the EKF-SLAM marginal, zero for the
//! sampled landmark of an implicit-SLAM particle): the rule and its
//! thresholds are the same for all four filters. Candidates whose landmark
//! lies farther than `radius` from the return's inverse-observation point
//! are not scored (d² is taken as infinite): a cheap spatial pre-filter.

use crate::geometry::{wrap_angle, Point, Pose};
use nalgebra::{Matrix2, Matrix2x3, Vector2};
use std::f64::consts::FRAC_PI_2;

/// One laser return without an identity: range (m), bearing (rad, laser
/// frame, π/2 straight ahead).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RangeBearing {
    pub range: f64,
    pub bearing: f64,
}

/// Thresholds of the association (chi-square with 2 degrees of freedom).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AssocConfig {
    /// Accept a landmark when d² < gate (9.21: 99 %).
    pub gate: f64,
    /// Start a new landmark when every d² > this (13.8: 99.9 %).
    pub new_threshold: f64,
    /// Pre-filter radius around the return's inverse-observation point (m).
    pub radius: f64,
}

impl Default for AssocConfig {
    fn default() -> Self {
        Self {
            gate: 9.21,
            new_threshold: 13.8,
            radius: 5.0,
        }
    }
}

/// The outcome for one return.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Association {
    Known(usize),
    New,
    Discard,
}

/// The innovation ν = wrap(z − h(x, m)) with H_x and H_m at (x, m).
pub fn innovation(
    x: &Pose,
    m: Point,
    z: &RangeBearing,
) -> (Vector2<f64>, Matrix2x3<f64>, Matrix2<f64>) {
    let d1 = m[0] - x[0];
    let d2 = m[1] - x[1];
    let r2 = d1 * d1 + d2 * d2;
    let r = r2.sqrt();
    let b = wrap_angle(d2.atan2(d1) - x[2] + FRAC_PI_2);
    let nu = Vector2::new(z.range - r, wrap_angle(z.bearing - b));
    let hx = Matrix2x3::new(-d1 / r, -d2 / r, 0.0, d2 / r2, -d1 / r2, -1.0);
    let hm = Matrix2::new(d1 / r, d2 / r, -d2 / r2, d1 / r2);
    (nu, hx, hm)
}

/// The inverse observation g(x, z) with G_x = ∂g/∂x and G_z = ∂g/∂z.
pub fn inverse(x: &Pose, z: &RangeBearing) -> (Point, Matrix2x3<f64>, Matrix2<f64>) {
    let phi = x[2] + z.bearing - FRAC_PI_2;
    let (s, c) = phi.sin_cos();
    let m = [x[0] + z.range * c, x[1] + z.range * s];
    let gx = Matrix2x3::new(1.0, 0.0, -z.range * s, 0.0, 1.0, z.range * c);
    let gz = Matrix2::new(c, -z.range * s, s, z.range * c);
    (m, gx, gz)
}

/// Running ML choice over candidates.
#[derive(Clone, Copy, Debug)]
pub struct Chooser {
    best: Option<(usize, f64)>,
    min_d2: f64,
}

impl Default for Chooser {
    fn default() -> Self {
        Self::new()
    }
}

/// The Mahalanobis distance d² = νᵀS⁻¹ν of an innovation and its
/// log-likelihood log N(ν; 0, S) up to the constant shared by all
/// candidates, −½d² − ½ log det S; `None` when S is not positive definite
/// or d² is not finite (the candidate is never chosen).
pub fn innovation_score(nu: &Vector2<f64>, s: &Matrix2<f64>) -> Option<(f64, f64)> {
    let det = s[(0, 0)] * s[(1, 1)] - s[(0, 1)] * s[(1, 0)];
    if !(det > 0.0) {
        return None;
    }
    let inv = Matrix2::new(s[(1, 1)], -s[(0, 1)], -s[(1, 0)], s[(0, 0)]) / det;
    let d2 = nu.dot(&(inv * nu));
    d2.is_finite().then(|| (d2, -0.5 * d2 - 0.5 * det.ln()))
}

impl Chooser {
    pub fn new() -> Self {
        Self {
            best: None,
            min_d2: f64::INFINITY,
        }
    }

    /// Score candidate k with innovation ν and covariance S.
    pub fn offer(&mut self, k: usize, nu: &Vector2<f64>, s: &Matrix2<f64>, cfg: &AssocConfig) {
        let Some((d2, ll)) = innovation_score(nu, s) else {
            return;
        };
        self.min_d2 = self.min_d2.min(d2);
        if d2 < cfg.gate && self.best.is_none_or(|(_, b)| ll > b) {
            self.best = Some((k, ll));
        }
    }

    /// The decision.
    pub fn decide(&self, cfg: &AssocConfig) -> Association {
        match self.best {
            Some((k, _)) => Association::Known(k),
            None if self.min_d2 > cfg.new_threshold => Association::New,
            None => Association::Discard,
        }
    }
}

/// Associations imposed from outside instead of the ML rule (the
/// known-association ablation): one per return of the next step, cleared
/// by the step. A `Known(k)` that a map does not hold is not imposed.
#[derive(Clone, Debug, Default)]
pub struct Forced(Vec<Association>);

impl Forced {
    pub fn with_capacity(n: usize) -> Self {
        Self(Vec::with_capacity(n))
    }

    /// Impose `a` on the next step's returns.
    pub fn set(&mut self, a: &[Association]) {
        self.0.clear();
        self.0.extend_from_slice(a);
    }

    pub fn clear(&mut self) {
        self.0.clear();
    }

    /// Impose `a` on the next return in order.
    pub fn push(&mut self, a: Association) {
        self.0.push(a);
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The imposed association of return `i` against a map of `len`
    /// landmarks, if any.
    pub fn get(&self, i: usize, len: usize) -> Option<Association> {
        match self.0.get(i).copied()? {
            Association::Known(k) if k >= len => None,
            a => Some(a),
        }
    }
}

/// Whether landmark m is close enough to the return's point to be scored.
pub fn near(m: Point, zp: Point, cfg: &AssocConfig) -> bool {
    (m[0] - zp[0]).powi(2) + (m[1] - zp[1]).powi(2) <= cfg.radius * cfg.radius
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laser::predict;
    use nalgebra::Matrix3;

    #[test]
    fn forced_associations_apply_only_to_landmarks_the_map_holds() {
        let mut f = Forced::with_capacity(4);
        assert_eq!(f.get(0, 3), None);
        f.set(&[
            Association::Known(2),
            Association::New,
            Association::Known(5),
        ]);
        assert_eq!(f.get(0, 3), Some(Association::Known(2)));
        assert_eq!(f.get(1, 3), Some(Association::New));
        assert_eq!(f.get(2, 3), None);
        assert_eq!(f.get(3, 3), None);
        f.clear();
        assert_eq!(f.get(0, 3), None);
    }

    #[test]
    fn jacobians_match_finite_differences_and_inverse_inverts() {
        let x = Pose::new(1.0, -2.0, 2.9);
        let z = RangeBearing {
            range: 7.0,
            bearing: 2.5,
        };
        let (m, gx, gz) = inverse(&x, &z);
        let (r, b) = predict(&x, m);
        assert!((r - 7.0).abs() < 1e-12 && (b - 2.5).abs() < 1e-12);
        let (nu, hx, hm) = innovation(&x, m, &z);
        assert!(nu.norm() < 1e-12);
        let h = 1e-6;
        for k in 0..3 {
            let (mut xp, mut xm) = (x, x);
            xp[k] += h;
            xm[k] -= h;
            let (a, _, _) = innovation(&xp, m, &z);
            let (c, _, _) = innovation(&xm, m, &z);
            // ν = z − h, so ∂ν/∂x = −H_x.
            let col = -(a - c) / (2.0 * h);
            assert!((col - hx.column(k)).norm() < 1e-6, "Hx col {k}");
            let (p, _, _) = inverse(&xp, &z);
            let (q, _, _) = inverse(&xm, &z);
            let gcol = Vector2::new(p[0] - q[0], p[1] - q[1]) / (2.0 * h);
            assert!((gcol - gx.column(k)).norm() < 1e-6, "Gx col {k}");
        }
        for k in 0..2 {
            let (mut mp, mut mm) = (m, m);
            mp[k] += h;
            mm[k] -= h;
            let (a, _, _) = innovation(&x, mp, &z);
            let (c, _, _) = innovation(&x, mm, &z);
            assert!((-(a - c) / (2.0 * h) - hm.column(k)).norm() < 1e-6);
            let mut zp = z;
            let mut zm = z;
            if k == 0 {
                zp.range += h;
                zm.range -= h;
            } else {
                zp.bearing += h;
                zm.bearing -= h;
            }
            let (p, _, _) = inverse(&x, &zp);
            let (q, _, _) = inverse(&x, &zm);
            let gcol = Vector2::new(p[0] - q[0], p[1] - q[1]) / (2.0 * h);
            assert!((gcol - gz.column(k)).norm() < 1e-6);
        }
    }

    /// Three landmarks, two of them 1.2 m apart; a return generated from
    /// the second (with a small error) must pick it, a return far from all
    /// must start a new landmark, and one in the band between the gate and
    /// the new-landmark threshold is discarded.
    #[test]
    fn association_picks_the_right_landmark() {
        let cfg = AssocConfig::default();
        let x = Pose::new(0.0, 0.0, 0.0);
        let map = [[10.0, 2.0], [10.0, 3.2], [4.0, -6.0]];
        let sx = Matrix3::from_diagonal(&nalgebra::Vector3::new(0.01, 0.01, 1e-4));
        let r2 = Matrix2::from_diagonal(&Vector2::new(0.05, 8.7e-4));
        let decide = |z: RangeBearing| {
            let (zp, _, _) = inverse(&x, &z);
            let mut ch = Chooser::new();
            for (k, &m) in map.iter().enumerate() {
                if near(m, zp, &cfg) {
                    let (nu, hx, _) = innovation(&x, m, &z);
                    let s = hx * sx * hx.transpose() + r2;
                    ch.offer(k, &nu, &s, &cfg);
                }
            }
            ch.decide(&cfg)
        };
        let (r, b) = predict(&x, map[1]);
        assert_eq!(
            decide(RangeBearing {
                range: r + 0.1,
                bearing: b - 0.01
            }),
            Association::Known(1)
        );
        let (r, b) = predict(&x, map[0]);
        assert_eq!(
            decide(RangeBearing {
                range: r - 0.2,
                bearing: b + 0.02
            }),
            Association::Known(0)
        );
        assert_eq!(
            decide(RangeBearing {
                range: 12.0,
                bearing: 2.8
            }),
            Association::New
        );
        // d² ≈ 0.6²/(0.05 + pose part) ≈ 6.5 in range plus a bearing part
        // that puts it between the thresholds.
        let (r, b) = predict(&x, map[2]);
        let mut ch = Chooser::new();
        let z = RangeBearing {
            range: r + 0.75,
            bearing: b,
        };
        let (nu, hx, _) = innovation(&x, map[2], &z);
        let s = hx * sx * hx.transpose() + r2;
        ch.offer(2, &nu, &s, &cfg);
        let d2 = nu.dot(&(s.try_inverse().unwrap() * nu));
        assert!(d2 > cfg.gate && d2 < cfg.new_threshold, "{d2}");
        assert_eq!(ch.decide(&cfg), Association::Discard);
    }
}
