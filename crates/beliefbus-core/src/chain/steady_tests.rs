use super::*;
use crate::filter::ekf::{Ekf, EkfConfig};
use crate::filter::kalman::Kalman;
use crate::filter::BayesFilter;
use crate::model::planar_quadrotor::{attitude_held, PlanarQuadrotor, PlanarQuadrotorParams};
use crate::model::{Bounds, Measurement};

fn scalar_ou(a: f64, s: f64, r: f64) -> LinearSde {
    LinearSde::new(
        "ou",
        DMatrix::from_element(1, 1, -a),
        DMatrix::zeros(1, 0),
        DMatrix::from_element(1, 1, s),
        DMatrix::from_element(1, 1, 1.0),
        vec![r],
        Bounds::new_box(&[-10.0], &[10.0]).unwrap(),
    )
}

/// Scalar Ornstein–Uhlenbeck observed directly: the prior-form DARE
/// M = A² M R/(M + R) + Q has the closed form
/// M = (−b + √(b² + 4QR))/2, b = R(1 − A²) − Q, and P = M R/(M + R).
#[test]
fn the_scalar_steady_posterior_is_the_closed_form_riccati_solution() {
    let (a, s, sy, dt) = (0.7, 0.4, 0.2, 0.05);
    let m = scalar_ou(a, s, sy);
    let g = steady_posterior(&m, &[0.3], &[], dt).unwrap();
    let ad = (-a * dt).exp();
    let q = s * s * (1.0 - (-2.0 * a * dt).exp()) / (2.0 * a);
    let r = sy * sy;
    let b = r * (1.0 - ad * ad) - q;
    let mm = 0.5 * (-b + (b * b + 4.0 * q * r).sqrt());
    let p = mm * r / (mm + r);
    assert!(
        (g.cov_at(0, 0) - p).abs() < 1e-12 * p,
        "{} vs {p}",
        g.cov_at(0, 0)
    );
    assert_eq!(g.mean[0], 0.3);
}

/// A linear model's P∞ is the covariance the exact Kalman filter reaches
/// (its covariance does not depend on the data, so zeros stand in for it).
#[test]
fn on_the_attitude_held_quadrotor_it_is_the_kalman_filters_limit() {
    let m = attitude_held(&PlanarQuadrotorParams::default()).unwrap();
    let dt = 0.01;
    let g = steady_posterior(&m, &[0.0; 4], &[0.0, 0.0], dt).unwrap();
    let prior = Gaussian::diagonal(&[0.0; 4], &[0.05; 4]);
    let mut kf = Kalman::new(m.clone(), &prior, 0.0).unwrap();
    for j in 0..3000 {
        kf.predict((j + 1) as f64 * dt, &[0.0, 0.0]).unwrap();
        kf.update(&Measurement::full(&[0.0, 0.0])).unwrap();
    }
    let k = kf.belief();
    for a in 0..4 {
        for c in 0..4 {
            let (x, y) = (g.cov_at(a, c), k.cov_at(a, c));
            assert!(
                (x - y).abs() < 1e-9 * k.cov_at(a, a).max(k.cov_at(c, c)),
                "{a},{c}: {x} vs {y}"
            );
        }
    }
    // Singular diffusion, yet a full-rank posterior with the position–
    // velocity correlation the chain versions need.
    assert!(g.cov_at(0, 2) > 0.0 && g.cov_at(0, 0) > 0.0);
}

/// The 6-D planar quadrotor at hover (an equilibrium under the hover
/// thrust): the EKF fed the noise-free reading of the hover position stays
/// there, and its covariance — the RK4 moment equations, not the matrix
/// exponential — settles to P∞.
#[test]
fn on_the_planar_quadrotor_at_hover_it_is_the_ekfs_limit() {
    let m = PlanarQuadrotor::new(PlanarQuadrotorParams::default()).unwrap();
    let (dt, x0) = (0.01, [0.2, -0.1, 0.0, 0.0, 0.0, 0.0]);
    let u = m.hover();
    let g = steady_posterior(&m, &x0, &u, dt).unwrap();
    let prior = Gaussian::diagonal(&x0, &[0.05, 0.05, 0.02, 0.05, 0.05, 0.05]);
    let mut ekf = Ekf::new(m.clone(), &EkfConfig { max_dt: 0.001 }, &prior, 0.0).unwrap();
    for j in 0..3000 {
        ekf.predict((j + 1) as f64 * dt, &u).unwrap();
        ekf.update(&Measurement::full(&[0.2, -0.1])).unwrap();
    }
    let e = ekf.belief();
    for a in 0..6 {
        for c in 0..6 {
            let (x, y) = (g.cov_at(a, c), e.cov_at(a, c));
            let tol = 1e-5 * (e.cov_at(a, a) * e.cov_at(c, c)).sqrt();
            assert!((x - y).abs() < tol, "{a},{c}: {x} vs {y}");
        }
    }
    // The attitude is seen only through the velocity it tilts: correlated.
    let corr = g.cov_at(2, 3) / (g.cov_at(2, 2) * g.cov_at(3, 3)).sqrt();
    assert!(corr < -0.5, "θ–vx correlation {corr}");
}

#[test]
fn bad_inputs_and_an_unobserved_unstable_mode_are_typed_errors() {
    let m = scalar_ou(0.7, 0.4, 0.2);
    assert!(matches!(
        steady_posterior(&m, &[0.0, 1.0], &[], 0.01),
        Err(ChainError::Config(_))
    ));
    assert!(matches!(
        steady_posterior(&m, &[0.0], &[], 0.0),
        Err(ChainError::Delta(_))
    ));
    // x₁ grows unobserved: no steady state.
    let unstable = LinearSde::new(
        "unstable",
        DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.0, -1.0]),
        DMatrix::zeros(2, 0),
        DMatrix::identity(2, 2),
        DMatrix::from_row_slice(1, 2, &[0.0, 1.0]),
        vec![0.1],
        Bounds::new_box(&[-10.0; 2], &[10.0; 2]).unwrap(),
    );
    assert!(matches!(
        steady_posterior(&unstable, &[0.0, 0.0], &[], 0.1),
        Err(ChainError::Config(_))
    ));
}
