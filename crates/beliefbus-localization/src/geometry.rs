//! Planar geometry of the vehicle: a pose (x, y, β) is the laser's position
//! and the vehicle heading (paper 003 appendix: the state is the laser
//! point, not the rear axle), angles are wrapped to (−π, π], and the frame
//! rotation T(β) = [[cos β, −sin β, 0], [sin β, cos β, 0], [0, 0, 1]] carries
//! body-frame covariances into the world frame.

use nalgebra::{Matrix3, Vector3};
use std::f64::consts::PI;

/// A pose (x, y, β): metres, metres, radians.
pub type Pose = Vector3<f64>;

/// A landmark position (x, y) in metres.
pub type Point = [f64; 2];

/// Wrap an angle to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    if a > -PI && a <= PI {
        return a;
    }
    let w = a.rem_euclid(2.0 * PI);
    if w > PI {
        w - 2.0 * PI
    } else {
        w
    }
}

/// The frame rotation T(β) (a rotation of x, y by β; β unchanged).
pub fn frame_rotation(beta: f64) -> Matrix3<f64> {
    let (s, c) = beta.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// The laser position of a vehicle whose rear-axle centre is (xc, yc) with
/// heading β: (xc + a cos β − b sin β, yc + a sin β + b cos β) (appendix).
pub fn laser_point(xc: f64, yc: f64, beta: f64, a: f64, b: f64) -> [f64; 2] {
    let (s, c) = beta.sin_cos();
    [xc + a * c - b * s, yc + a * s + b * c]
}

/// The weighted mean of poses: positions averaged, heading by the mean of
/// (cos β, sin β) (weights summing to 1).
pub fn mean_pose(x: &[Pose], w: &[f64]) -> Pose {
    let (mut px, mut py, mut c, mut s) = (0.0, 0.0, 0.0, 0.0);
    for (p, &w) in x.iter().zip(w) {
        px += w * p[0];
        py += w * p[1];
        c += w * p[2].cos();
        s += w * p[2].sin();
    }
    Pose::new(px, py, s.atan2(c))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_lands_in_half_open_interval() {
        for k in -5..=5 {
            for a in [-3.0, -1.0, 0.0, 0.5, 3.1, PI] {
                let w = wrap_angle(a + 2.0 * PI * k as f64);
                assert!(w > -PI && w <= PI);
                assert!((w.sin() - a.sin()).abs() < 1e-12 && (w.cos() - a.cos()).abs() < 1e-12);
            }
        }
        assert_eq!(wrap_angle(-PI), PI);
    }

    #[test]
    fn rotation_is_orthogonal_with_unit_determinant() {
        let t = frame_rotation(0.7);
        assert!((t * t.transpose() - Matrix3::identity()).norm() < 1e-14);
        assert!((t.determinant() - 1.0).abs() < 1e-14);
    }
}
