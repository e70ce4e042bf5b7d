//! The controller against exact linear-quadratic answers (Riccati).

use super::*;
use crate::control::implicit::DiagonalQuadraticCost;
use crate::model::affine::{LinearAffine, PathStructure};
use nalgebra::{Matrix2, Vector2};

fn double_integrator() -> LinearAffine {
    LinearAffine {
        m: 2,
        p: 1,
        r: 1,
        a: vec![0.0, 0.0, 1.0, 0.0],
        g: vec![0.0, 1.0],
        q: vec![1.0],
        structure: PathStructure::SecondOrder,
    }
}

/// Acceptance test at the controller level: receding horizon on ẍ = u
/// with V = ½x₁², R = 1 gives the LQR law u = −(x₁ + √2 x₂) within 2 %
/// (Euler with Δt = 0.01 shifts the gain by O(Δt)), for both gradients.
#[test]
fn receding_controller_gives_the_lqr_control() {
    for gradient in [GradientConfig::Analytic, GradientConfig::FiniteDifference] {
        let cfg = PathIntegralConfig {
            horizon_steps: 1000,
            dt: 0.01,
            control_cost: 1.0,
            u_max: 100.0,
            budget_us: 0.0,
            gradient,
            ..PathIntegralConfig::default()
        };
        let cost = DiagonalQuadraticCost::new(&[1.0, 0.0], &[0.0, 0.0]);
        let mut c = PathIntegralController::new(double_integrator(), cost, cfg).unwrap();
        let mut u = [0.0];
        for (i, x) in [[1.0, 0.5], [-0.7, 0.2], [0.3, -1.0]].iter().enumerate() {
            c.compute(i as f64 * 0.01, &Gaussian::diagonal(x, &[0.0, 0.0]), &mut u)
                .unwrap();
            let lqr = -(x[0] + 2f64.sqrt() * x[1]);
            assert!(
                (u[0] - lqr).abs() < 0.02 * lqr.abs(),
                "{gradient:?} x={x:?}: {} vs {lqr}",
                u[0]
            );
        }
    }
}

/// Shrinking horizon: at time t the control uses n = (t_f − t)/Δt steps and
/// equals the discrete Riccati control of the remaining problem.
#[test]
fn shrinking_controller_follows_the_finite_horizon_riccati_control() {
    let (dt, tf, r) = (0.05, 2.0, 0.5);
    let cfg = PathIntegralConfig {
        horizon: HorizonMode::Shrinking,
        final_time: tf,
        horizon_steps: 100,
        dt,
        control_cost: r,
        u_max: 100.0,
        budget_us: 0.0,
        ..PathIntegralConfig::default()
    };
    let cost = DiagonalQuadraticCost::new(&[1.0, 0.2], &[3.0, 1.0]);
    let mut c = PathIntegralController::new(double_integrator(), cost, cfg).unwrap();
    let mut u = [0.0];
    for (k, x) in [(0usize, [1.3, -0.4]), (10, [0.6, -0.3]), (39, [0.1, 0.05])] {
        let t = k as f64 * dt;
        c.compute(t, &Gaussian::diagonal(&x, &[0.0, 0.0]), &mut u)
            .unwrap();
        let n = 40 - k;
        assert_eq!(c.stats().horizon_steps, n);
        // Discrete Riccati of the Euler problem (see the estimator tests).
        let ad = Matrix2::new(1.0, dt, 0.0, 1.0);
        let bd = Vector2::new(0.0, dt);
        let w = Matrix2::new(1.0, 0.0, 0.0, 0.2);
        let mut p = Matrix2::new(3.0, 0.0, 0.0, 1.0) + w * (dt / 2.0);
        for i in (0..n).rev() {
            let ci = if i == 0 { dt / 2.0 } else { dt };
            let s = dt * r + (bd.transpose() * p * bd)[(0, 0)];
            let kk = (bd.transpose() * p * ad) / s;
            p = w * ci + ad.transpose() * p * ad - (ad.transpose() * p * bd) * kk;
        }
        let expect = -(p * Vector2::new(x[0], x[1]))[1] / r;
        assert!(
            (u[0] - expect).abs() < 1e-6 * (1.0 + expect.abs()),
            "t={t}: {} vs {expect}",
            u[0]
        );
    }
    // Past the final time there is nothing left to control.
    c.compute(
        tf + 0.1,
        &Gaussian::diagonal(&[1.0, 0.0], &[0.0, 0.0]),
        &mut u,
    )
    .unwrap();
    assert_eq!(u[0], 0.0);
}

/// Belief-averaged ψ on a linear-quadratic problem: with ψ(x) ∝
/// exp(−xᵀPx/(2γ)) and x ~ N(m, Σ), ∂ log E[ψ] = −(P/γ)(I + ΣP/γ)⁻¹ m, so
/// u = −R⁻¹GᵀP(I + ΣP/γ)⁻¹m — not the certainty-equivalent −R⁻¹GᵀPm.
#[test]
fn belief_averaged_control_matches_the_gaussian_expectation() {
    let (dt, n, r) = (0.05, 40, 0.5);
    let model = double_integrator();
    let cost = DiagonalQuadraticCost::new(&[1.0, 0.2], &[3.0, 1.0]);
    let cfg = PathIntegralConfig {
        horizon_steps: n,
        dt,
        control_cost: r,
        u_max: 100.0,
        budget_us: 0.0,
        belief: BeliefMode::Sampled,
        belief_samples: MAX_BELIEF_SAMPLES,
        samples: 0,
        ..PathIntegralConfig::default()
    };
    let gamma = r; // Q = 1
    let mut c = PathIntegralController::new(model, cost, cfg).unwrap();
    // P₀ of the discretised problem (as above).
    let ad = Matrix2::new(1.0, dt, 0.0, 1.0);
    let bd = Vector2::new(0.0, dt);
    let w = Matrix2::new(1.0, 0.0, 0.0, 0.2);
    let mut p = Matrix2::new(3.0, 0.0, 0.0, 1.0) + w * (dt / 2.0);
    for i in (0..n).rev() {
        let ci = if i == 0 { dt / 2.0 } else { dt };
        let s = dt * r + (bd.transpose() * p * bd)[(0, 0)];
        let kk = (bd.transpose() * p * ad) / s;
        p = w * ci + ad.transpose() * p * ad - (ad.transpose() * p * bd) * kk;
    }
    let m = Vector2::new(0.8, -0.3);
    let sd = [0.1, 0.1];
    let sigma = Matrix2::new(sd[0] * sd[0], 0.0, 0.0, sd[1] * sd[1]);
    let expect = -(p
        * (Matrix2::identity() + sigma * p / gamma)
            .try_inverse()
            .unwrap()
        * m)[1]
        / r;
    let ce = -(p * m)[1] / r;
    let mut u = [0.0];
    let mut us = vec![];
    for i in 0..40 {
        c.compute(
            i as f64 * 1e-3,
            &Gaussian::diagonal(m.as_slice(), &sd),
            &mut u,
        )
        .unwrap();
        us.push(u[0]);
    }
    let mean = us.iter().sum::<f64>() / us.len() as f64;
    let sdev = (us.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (us.len() - 1) as f64).sqrt();
    let se = sdev / (us.len() as f64).sqrt();
    assert!(
        (mean - expect).abs() < 4.0 * se + 1e-3,
        "mean {mean} ± {se} vs {expect}"
    );
    // The belief matters here: certainty equivalence is clearly different.
    assert!(
        (ce - expect).abs() > 6.0 * se,
        "CE {ce} vs averaged {expect} (se {se})"
    );
}
