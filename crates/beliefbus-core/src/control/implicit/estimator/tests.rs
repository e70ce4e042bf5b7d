//! The estimator against exact answers: discrete Riccati, continuous LQR,
//! the double slit's analytic ψ and control, and across its options.

use super::*;
use crate::control::implicit::path::{DiagonalQuadraticCost, PathSetup};
use crate::model::affine::{LinearAffine, PathStructure};
use crate::model::double_slit::{DoubleSlit, SlitCost};
use nalgebra::{Matrix2, Vector2};

fn double_integrator(q: f64) -> LinearAffine {
    LinearAffine {
        m: 2,
        p: 1,
        r: 1,
        a: vec![0.0, 0.0, 1.0, 0.0],
        g: vec![0.0, 1.0],
        q: vec![q],
        structure: PathStructure::SecondOrder,
    }
}

/// P₀ of the discretised problem the path functional encodes: Euler
/// dynamics y_i = y_{i−1} + (A y_{i−1} + G u_{i−1})Δt, control cost
/// Δt·½uᵀRu, trapezoidal ½xᵀWx and terminal ½xᵀW_f x.
fn discrete_riccati(
    a: Matrix2<f64>,
    g: Vector2<f64>,
    r: f64,
    w: Matrix2<f64>,
    wf: Matrix2<f64>,
    dt: f64,
    n: usize,
) -> Matrix2<f64> {
    let ad = Matrix2::identity() + a * dt;
    let bd = g * dt;
    let mut p = wf + w * (dt / 2.0);
    for i in (0..n).rev() {
        let c = if i == 0 { dt / 2.0 } else { dt };
        let s = dt * r + (bd.transpose() * p * bd)[(0, 0)];
        let k = (bd.transpose() * p * ad) / s;
        p = w * c + ad.transpose() * p * ad - (ad.transpose() * p * bd) * k;
    }
    p
}

fn sampler_for(model: &LinearAffine, r: f64, dt: f64, n: usize, m: usize) -> PathSampler {
    let setup = PathSetup::new(model, &[r], dt).unwrap();
    PathSampler::new(setup, n, m, 4)
}

/// Acceptance test: on a linear-quadratic problem the controller's
/// u = γR⁻¹Gᵀ∂ₓ log ψ equals the Riccati control of the same
/// discretisation (to 1e-6), for every gradient method and sample size.
#[test]
fn linear_quadratic_control_equals_discrete_riccati() {
    let model = double_integrator(0.7);
    let (r, dt, n) = (0.5, 0.05, 40);
    let cost = DiagonalQuadraticCost::new(&[1.0, 0.2], &[3.0, 1.0]);
    let p0 = discrete_riccati(
        Matrix2::new(0.0, 1.0, 0.0, 0.0),
        Vector2::new(0.0, 1.0),
        r,
        Matrix2::new(1.0, 0.0, 0.0, 0.2),
        Matrix2::new(3.0, 0.0, 0.0, 1.0),
        dt,
        n,
    );
    let x = [1.3, -0.4];
    let u_ref = -(p0 * Vector2::new(x[0], x[1]))[1] / r;
    let mut rng = crate::rng::stream(3, 0);
    for (samples, gradient) in [
        (0, GradientMethod::Analytic),
        (16, GradientMethod::Analytic),
        (0, GradientMethod::FiniteDifference { h: 1e-4 }),
        (16, GradientMethod::FiniteDifference { h: 1e-4 }),
        (0, GradientMethod::LikelihoodRatio),
        (16, GradientMethod::LikelihoodRatio),
    ] {
        let mut s = sampler_for(&model, r, dt, n, 16);
        let opts = EstimatorOptions {
            samples,
            gradient,
            ..EstimatorOptions::default()
        };
        let e = s
            .estimate(&model, &cost, &x, n, None, &opts, &mut rng)
            .unwrap();
        assert!(
            (e.u[0] - u_ref).abs() < 1e-6 * (1.0 + u_ref.abs()),
            "{samples} samples, {gradient:?}: u = {} vs Riccati {u_ref}",
            e.u[0]
        );
        // Quadratic F: every weight equal.
        assert!((e.ess - samples.max(1) as f64).abs() < 1e-6 * samples.max(1) as f64);
        // J = −γ log ψ: φ equals the discrete optimal cost-to-go over γ.
        let j =
            0.5 * (Vector2::new(x[0], x[1]).transpose() * p0 * Vector2::new(x[0], x[1]))[(0, 0)];
        assert!((e.phi * s.setup().gamma - j).abs() < 1e-8 * j);
    }
}

/// E5/E6 for partial noise: log ψ including every constant (Δt^{−N/2},
/// (det Σ)^{−n/2} and the Jacobian of the velocity→position change of
/// variables) equals the Gaussian integral done directly over the
/// velocities v₁..v_n with positions q_i = q_{i−1} + v_{i−1}Δt.
#[test]
fn second_order_log_psi_equals_the_integral_over_velocities() {
    let (q, r, dt, n) = (0.7, 0.5, 0.1, 5);
    let model = double_integrator(q);
    let cost = DiagonalQuadraticCost::new(&[1.0, 0.2], &[3.0, 1.0]);
    let mut s = sampler_for(&model, r, dt, n, 4);
    let gamma = s.setup().gamma;
    let x = [0.4, -0.8];
    let e = s
        .estimate(
            &model,
            &cost,
            &x,
            n,
            None,
            &EstimatorOptions {
                samples: 0,
                ..EstimatorOptions::default()
            },
            &mut crate::rng::stream(1, 1),
        )
        .unwrap();
    // F over velocities, written out directly.
    let f = |v: &[f64]| {
        let vv = |i: usize| if i == 0 { x[1] } else { v[i - 1] };
        let mut qs = vec![x[0]];
        for i in 1..=n {
            qs.push(qs[i - 1] + vv(i - 1) * dt);
        }
        let pot = |i: usize| 0.5 * qs[i] * qs[i] + 0.5 * 0.2 * vv(i) * vv(i);
        let mut tot = (1.5 * qs[n] * qs[n] + 0.5 * vv(n) * vv(n)) / gamma;
        for i in 1..=n {
            tot += dt / (2.0 * gamma) * (pot(i) + pot(i - 1));
            tot += (vv(i) - vv(i - 1)).powi(2) / (2.0 * q * q * dt);
        }
        tot
    };
    // Quadratic: F(v) = c + bᵀv + ½vᵀAv, read off by (exact) differences.
    let h = 1.0;
    let zero = vec![0.0; n];
    let c0 = f(&zero);
    let mut a = nalgebra::DMatrix::zeros(n, n);
    let mut b = nalgebra::DVector::zeros(n);
    for i in 0..n {
        let mut ei = zero.clone();
        ei[i] = h;
        let fp = f(&ei);
        ei[i] = -h;
        let fm = f(&ei);
        b[i] = (fp - fm) / (2.0 * h);
        a[(i, i)] = (fp - 2.0 * c0 + fm) / (h * h);
        for j in 0..i {
            let mut eij = zero.clone();
            eij[i] = h;
            eij[j] = h;
            let fij = f(&eij);
            eij[i] = 0.0;
            let fj = f(&eij);
            let mut ei2 = zero.clone();
            ei2[i] = h;
            let fi = f(&ei2);
            a[(i, j)] = (fij - fi - fj + c0) / (h * h);
            a[(j, i)] = a[(i, j)];
        }
    }
    let chol = a.clone().cholesky().unwrap();
    let ainv_b = chol.solve(&b);
    let log_det_a: f64 = 2.0 * chol.l().diagonal().iter().map(|v| v.ln()).sum::<f64>();
    let nf = n as f64;
    let log_integral =
        -c0 + 0.5 * b.dot(&ainv_b) + 0.5 * nf * (2.0 * std::f64::consts::PI).ln() - 0.5 * log_det_a;
    let log_psi =
        log_integral - 0.5 * nf * (2.0 * std::f64::consts::PI * dt).ln() - 0.5 * nf * (q * q).ln();
    assert!(
        (e.log_psi - log_psi).abs() < 1e-8,
        "{} vs {log_psi}",
        e.log_psi
    );
}

/// Acceptance test: over a long horizon the control approaches the
/// continuous-time LQR law of ẍ = u with cost ∫ ½(x₁² + u²): K = [1, √2].
#[test]
fn long_horizon_control_approaches_continuous_lqr() {
    let model = double_integrator(1.0);
    let (r, dt, n) = (1.0, 0.01, 1000);
    let cost = DiagonalQuadraticCost::new(&[1.0, 0.0], &[0.0, 0.0]);
    let mut s = sampler_for(&model, r, dt, n, 16);
    let mut rng = crate::rng::stream(4, 0);
    for x in [[1.0, 0.5], [-2.0, 0.3]] {
        let e = s
            .estimate(
                &model,
                &cost,
                &x,
                n,
                None,
                &EstimatorOptions::default(),
                &mut rng,
            )
            .unwrap();
        let lqr = -(x[0] + 2f64.sqrt() * x[1]);
        // Euler with Δt = 0.01 moves the gain by O(Δt): 2 % tolerance.
        assert!(
            (e.u[0] - lqr).abs() < 0.02 * lqr.abs(),
            "u = {} vs LQR {lqr}",
            e.u[0]
        );
    }
}

/// Acceptance test: the discretised ψ of the double slit after the wall
/// equals the analytic ψ (notes check 4: 0.191380 at x = 1, t = t₁).
#[test]
fn double_slit_psi_after_the_wall_matches_analytic() {
    let p = DoubleSlit::default();
    let model = p.model();
    let setup = PathSetup::new(&model, &[p.r], p.dt).unwrap();
    let mut s = PathSampler::new(setup, 100, 32, 4);
    let mut rng = crate::rng::stream(5, 0);
    for (x, t) in [(1.0, 1.0), (-4.5, 1.0), (2.0, 1.5), (7.0, 1.98)] {
        let n = p.steps_from(t);
        for samples in [0, 32] {
            let opts = EstimatorOptions {
                samples,
                ..EstimatorOptions::default()
            };
            let e = s
                .estimate(&model, &SlitCost, &[x], n, None, &opts, &mut rng)
                .unwrap();
            let exact = p.log_psi(x, t);
            assert!(
                (e.log_psi - exact).abs() < 1e-9,
                "x={x} t={t}: {} vs {exact}",
                e.log_psi
            );
            assert!((e.u[0] - p.control(x, t)).abs() < 1e-7 * (1.0 + e.u[0].abs()));
        }
    }
    let e = s
        .estimate(
            &model,
            &SlitCost,
            &[1.0],
            50,
            None,
            &EstimatorOptions::default(),
            &mut rng,
        )
        .unwrap();
    assert!((e.log_psi.exp() - 0.191380).abs() < 1e-6);
    // The printed path term with γ instead of σ gives 0.058 (E7): the
    // discrete ψ is sensitive to it, so this test would catch it.
}

/// Before the wall: two basins, weighted samples. ψ(1, 0) and u(1, 0)
/// agree with the erf solution within Monte Carlo error.
#[test]
fn double_slit_psi_before_the_wall_matches_analytic() {
    let p = DoubleSlit::default();
    let model = p.model();
    let setup = PathSetup::new(&model, &[p.r], p.dt).unwrap();
    let m = 4000;
    let mut s = PathSampler::new(setup, 100, m, 4);
    let mut rng = crate::rng::stream(6, 0);
    let n = p.steps_from(0.0);
    let gate = p.gate_from(0.0);
    assert_eq!(gate.unwrap().step, 50);
    for gradient in [
        GradientMethod::Analytic,
        GradientMethod::FiniteDifference { h: 1e-4 },
    ] {
        let opts = EstimatorOptions {
            samples: m,
            gradient,
            ..EstimatorOptions::default()
        };
        let e = s
            .estimate(&model, &SlitCost, &[1.0], n, gate, &opts, &mut rng)
            .unwrap();
        let exact = p.log_psi(1.0, 0.0);
        // Relative error of an importance-sampling mean ~ 1/√ESS: 4σ bound.
        let tol = 4.0 / e.ess.sqrt();
        assert!(e.ess > 50.0, "ESS {}", e.ess);
        assert!(
            (e.log_psi - exact).abs() < tol,
            "log ψ {} vs {exact} (tol {tol})",
            e.log_psi
        );
        let u = p.control(1.0, 0.0);
        assert!(
            (e.u[0] - u).abs() < 0.02 * u.abs(),
            "{gradient:?}: u {} vs {u}",
            e.u[0]
        );
        if gradient == GradientMethod::Analytic {
            // Gate marginal: every sample passes, all weights are equal
            // (F is quadratic) and ψ is exact to rounding.
            assert_eq!(e.pass_fraction, 1.0);
            // Equal weights within each slit; the upper slit carries e⁻⁹ of the mass.
            assert!(e.ess > 0.999 * m as f64, "ESS {}", e.ess);
            assert!(
                (e.log_psi - exact).abs() < 1e-9,
                "log ψ {} vs {exact}",
                e.log_psi
            );
            assert!((e.u[0] - u).abs() < 1e-3 * u.abs(), "u {} vs {u}", e.u[0]);
        } else {
            // Rejection: both slits pinned at their inner edge, about half pass.
            assert!(
                e.pass_fraction > 0.4 && e.pass_fraction < 0.6,
                "{}",
                e.pass_fraction
            );
        }
    }
    // The paper's recipe (smallest basin, indicator only) also lands near.
    let opts = EstimatorOptions {
        samples: m,
        gradient: GradientMethod::FiniteDifference { h: 1e-4 },
        gate_mode: GateMode::SmallestBasin,
        ..EstimatorOptions::default()
    };
    let e = s
        .estimate(&model, &SlitCost, &[1.0], n, gate, &opts, &mut rng)
        .unwrap();
    assert!(
        (e.u[0] - p.control(1.0, 0.0)).abs() < 0.2 * 5.1,
        "paper recipe u {}",
        e.u[0]
    );
}

/// The likelihood-ratio control −γR⁻¹Gᵀ E_w[∂ₓF] (no extra solves)
/// against the analytic u(1, 0) of the double slit and the paper's
/// finite differences: 40 independent estimates of 64 samples each; the
/// mean agrees with both within 4 standard errors (of the difference).
#[test]
fn likelihood_ratio_control_agrees_with_fd_and_the_exact_double_slit_control() {
    let p = DoubleSlit::default();
    let model = p.model();
    let setup = PathSetup::new(&model, &[p.r], p.dt).unwrap();
    let m = 64;
    let mut s = PathSampler::new(setup, 100, m, 4);
    let mut rng = crate::rng::stream(8, 0);
    let n = p.steps_from(0.0);
    let gate = p.gate_from(0.0);
    let exact = p.control(1.0, 0.0);
    let mut stats = vec![];
    for gradient in [
        GradientMethod::LikelihoodRatio,
        GradientMethod::FiniteDifference { h: 1e-4 },
    ] {
        let opts = EstimatorOptions {
            samples: m,
            gradient,
            gate_sampling: GateSampling::Rejection,
            ..EstimatorOptions::default()
        };
        let us: Vec<f64> = (0..40)
            .map(|_| {
                s.estimate(&model, &SlitCost, &[1.0], n, gate, &opts, &mut rng)
                    .unwrap()
                    .u[0]
            })
            .collect();
        let mean = us.iter().sum::<f64>() / us.len() as f64;
        let var = us.iter().map(|u| (u - mean).powi(2)).sum::<f64>() / (us.len() - 1) as f64;
        stats.push((mean, (var / us.len() as f64).sqrt()));
    }
    let ((lr, se_lr), (fd, se_fd)) = (stats[0], stats[1]);
    // Self-normalised weights bias the mean by O(1/M): allow 1 % of u.
    assert!(
        (lr - exact).abs() < 4.0 * se_lr + 0.01 * exact.abs(),
        "LR {lr} ± {se_lr} vs exact {exact}"
    );
    assert!(
        (lr - fd).abs() < 4.0 * (se_lr * se_lr + se_fd * se_fd).sqrt() + 0.01 * exact.abs(),
        "LR {lr} ± {se_lr} vs FD {fd} ± {se_fd}"
    );
    // The marginal gate sampler (every sample passes) gives it too.
    let opts = EstimatorOptions {
        samples: 1000,
        gradient: GradientMethod::LikelihoodRatio,
        ..EstimatorOptions::default()
    };
    let mut s = PathSampler::new(PathSetup::new(&model, &[p.r], p.dt).unwrap(), 100, 1000, 4);
    let e = s
        .estimate(&model, &SlitCost, &[1.0], n, gate, &opts, &mut rng)
        .unwrap();
    assert!(
        (e.u[0] - exact).abs() < 0.03 * exact.abs(),
        "{} vs {exact}",
        e.u[0]
    );
}

/// The warm start advanced by a fraction of a step re-samples the plan
/// between its grid points: a second-order plan with positions linear in
/// time moves exactly (tail extrapolated linearly), whole and
/// fractional parts combine, and beyond the plan it resets.
#[test]
fn warm_start_advances_by_fractional_steps() {
    let model = double_integrator(1.0);
    let (dt, n) = (0.04, 20);
    let mut s = sampler_for(&model, 0.5, dt, n, 1);
    // z_i = q(t + (i+1)Δt) with q(τ) = 0.3 + 1.7 τ.
    let q = |tau: f64| 0.3 + 1.7 * tau;
    let mut rng = crate::rng::stream(1, 0);
    let cost = DiagonalQuadraticCost::new(&[1.0, 0.2], &[3.0, 1.0]);
    let opts = EstimatorOptions {
        samples: 0,
        ..EstimatorOptions::default()
    };
    s.estimate(&model, &cost, &[0.3, 1.7], n, None, &opts, &mut rng)
        .unwrap();
    for i in 0..n {
        s.warm[i] = q((i + 1) as f64 * dt);
    }
    s.advance_warm_start(0.25, n);
    for i in 0..n {
        let want = q((i as f64 + 1.25) * dt);
        assert!((s.warm_start()[i] - want).abs() < 1e-12, "{i}");
    }
    s.advance_warm_start(1.5, n - 2);
    assert_eq!(s.warm_steps(), n - 2);
    for i in 0..n - 2 {
        let want = q((i as f64 + 2.75) * dt);
        assert!((s.warm_start()[i] - want).abs() < 1e-12, "{i}");
    }
    // Whole steps still shift as before.
    s.shift_warm_start(1, n);
    assert!((s.warm_start()[0] - q(3.75 * dt)).abs() < 1e-12);
    assert!((s.warm_start()[n - 1] - q((n as f64 + 2.75) * dt)).abs() < 1e-12);
    s.advance_warm_start(n as f64 + 0.5, n);
    assert_eq!(s.warm_steps(), 0);
}

/// The random map gives the same ψ as the linear map on a Gaussian F.
#[test]
fn random_map_estimate_agrees_on_gaussian_paths() {
    let p = DoubleSlit::default();
    let model = p.model();
    let setup = PathSetup::new(&model, &[p.r], p.dt).unwrap();
    let mut s = PathSampler::new(setup, 60, 8, 2);
    let mut rng = crate::rng::stream(7, 0);
    let opts = EstimatorOptions {
        samples: 8,
        map: MapKind::Random,
        gradient: GradientMethod::FiniteDifference { h: 1e-4 },
        ..EstimatorOptions::default()
    };
    let e = s
        .estimate(&model, &SlitCost, &[1.0], 50, None, &opts, &mut rng)
        .unwrap();
    assert!((e.log_psi - p.log_psi(1.0, 1.0)).abs() < 1e-8);
    assert!((e.ess - 8.0).abs() < 1e-6);
    assert!((e.u[0] - p.control(1.0, 1.0)).abs() < 1e-5);
}
