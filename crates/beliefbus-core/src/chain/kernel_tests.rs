//! The transition kernels against their moment equations.

use super::*;
use crate::chain::linalg::cholesky;
use crate::rng::stream;
use rand::RngExt;

fn moments(d: usize, dz: &[f64], p: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let k = p.len();
    let mut m1 = vec![0.0; d];
    let mut m2 = vec![0.0; d * d];
    for j in 0..k {
        for i in 0..d {
            m1[i] += p[j] * dz[j * d + i];
            for c in 0..d {
                m2[i + c * d] += p[j] * dz[j * d + i] * dz[j * d + c];
            }
        }
    }
    (m1, m2)
}

#[test]
fn gaussian_with_cached_inverse_factor_equals_the_density_formula() {
    // p_k ∝ exp(−½ (Δz_k − fΔt)ᵀ (F FᵀΔt)⁻¹ (Δz_k − fΔt)) computed with
    // nalgebra's inverse, against the forward-substitution kernel and
    // the packed-L⁻¹ kernel (general and d = 4 paths), d = 2, 3, 4, 5.
    use crate::chain::linalg::lower_inverse_packed;
    use nalgebra::DMatrix;
    let mut rng = stream(17, 0);
    for d in [2usize, 3, 4, 5] {
        for _ in 0..20 {
            let k = 18;
            let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-1.0..1.0));
            let ffm = &a * a.transpose() + DMatrix::identity(d, d) * 0.05;
            let ff: Vec<f64> = ffm.iter().copied().collect();
            let f: Vec<f64> = (0..d).map(|_| rng.random_range(-2.0..2.0)).collect();
            let dz: Vec<f64> = (0..k * d).map(|_| rng.random_range(-0.3..0.3)).collect();
            let dt = rng.random_range(0.01..0.2);
            let mut chol = ff.clone();
            assert!(cholesky(&mut chol, d));
            let mut linv = vec![0.0; d * (d + 1) / 2];
            lower_inverse_packed(&chol, d, &mut linv);
            let prec = (&ffm * dt).try_inverse().unwrap();
            let q: Vec<f64> = (0..k)
                .map(|j| {
                    let y = DMatrix::from_fn(d, 1, |i, _| dz[j * d + i] - f[i] * dt);
                    0.5 * (y.transpose() * &prec * &y)[(0, 0)]
                })
                .collect();
            let qmin = q.iter().copied().fold(f64::INFINITY, f64::min);
            let s: f64 = q.iter().map(|v| (qmin - v).exp()).sum();
            let want: Vec<f64> = q.iter().map(|v| (qmin - v).exp() / s).collect();
            let dynl = LocalDyn {
                f: &f,
                ff: &ff,
                chol: Some(&chol),
            };
            let mut work = KernelWork::new();
            let mut p1 = vec![0.0; k];
            let mut p2 = vec![0.0; k];
            assert!(gaussian(d, &dz, dt, &dynl, &mut work, &mut p1));
            let mean: Vec<f64> = f.iter().map(|v| v * dt).collect();
            gaussian_packed_at(d, &dz, &mean, dt, &linv, &mut work, &mut p2);
            // The same neighbours as slots of a flat state array (x at
            // slot 0, neighbour j at slot j + 1).
            let x: Vec<f64> = (0..d).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut states = x.clone();
            for j in 0..k {
                states.extend((0..d).map(|i| x[i] + dz[j * d + i]));
            }
            let cols: Vec<u32> = (1..=k as u32).collect();
            let mut p3 = vec![0.0; k];
            gaussian_gather_at(d, &states, &cols, &x, &mean, dt, &linv, &mut work, &mut p3);
            for j in 0..k {
                let tol = 1e-9 * want[j] + 1e-300;
                assert!(
                    (p3[j] - want[j]).abs() <= tol,
                    "d {d}: {} vs {}",
                    p3[j],
                    want[j]
                );
            }
            for j in 0..k {
                // Rounding of q (up to ~10³ here, condition of F Fᵀ up to ~10²)
                // moves exp(−q) by ~1e-12 relative.
                let tol = 1e-9 * want[j] + 1e-300;
                assert!(
                    (p1[j] - want[j]).abs() <= tol,
                    "d {d}: {} vs {}",
                    p1[j],
                    want[j]
                );
                assert!(
                    (p2[j] - want[j]).abs() <= tol,
                    "d {d}: {} vs {}",
                    p2[j],
                    want[j]
                );
            }
        }
    }
}

#[test]
fn moment_matched_meets_local_consistency_exactly_when_surrounded() {
    // 2-D, 20 neighbours uniformly in the unit disc around z, diffusion-
    // dominated: the kernel's mean/second moment per unit holding time
    // equal f and FFᵀ + ffᵀΔt.
    let mut rng = stream(9, 0);
    let d = 2;
    let mut dz = vec![];
    while dz.len() < 40 {
        let (x, y) = (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        if x * x + y * y <= 1.0 {
            dz.push(x);
            dz.push(y);
        }
    }
    let f = [0.3, -0.2];
    let ff = [0.5, 0.1, 0.1, 0.4];
    let mut chol = ff;
    assert!(cholesky(&mut chol, 2));
    let dynl = LocalDyn {
        f: &f,
        ff: &ff,
        chol: Some(&chol),
    };
    let dt = holding_time(1.0, 0.55, 0.36, 2.0 * (d as f64 + 2.0), 2.0);
    let mut work = KernelWork::new();
    let mut p = vec![0.0; 20];
    let fit = moment_matched(d, &dz, dt, 1.0, &dynl, &mut work, &mut p);
    assert_eq!(fit.outcome, KernelOutcome::Exact);
    assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    assert!(p.iter().all(|v| *v >= 0.0));
    let h = fit.holding;
    let (m1, m2) = moments(d, &dz, &p);
    for i in 0..d {
        assert!((m1[i] / h - f[i]).abs() < 1e-8, "drift {i}");
        for c in 0..d {
            let want = ff[i + c * d] + f[i] * f[c] * dt;
            assert!((m2[i + c * d] / h - want).abs() < 1e-8, "second moment");
        }
    }
}

#[test]
fn gaussian_kernel_is_normalised_and_peaks_at_the_drift_target() {
    let d = 1;
    let dz = [-0.5, -0.1, 0.2, 0.45, 0.9];
    let f = [2.0];
    let ff = [0.04];
    let chol = [0.2];
    let dynl = LocalDyn {
        f: &f,
        ff: &ff,
        chol: Some(&chol),
    };
    let mut p = [0.0; 5];
    let mut work = KernelWork::new();
    assert!(gaussian(d, &dz, 0.2, &dynl, &mut work, &mut p));
    assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    // target z + fΔt = 0.4: the neighbour at 0.45 has the largest weight.
    let best = (0..5).max_by(|a, b| p[*a].total_cmp(&p[*b])).unwrap();
    assert_eq!(best, 3);
    // ratio check against the closed form
    let w = |x: f64| (-(x - 0.4f64).powi(2) / (2.0 * 0.04 * 0.2)).exp();
    assert!((p[2] / p[3] - w(0.2) / w(0.45)).abs() < 1e-9);
}
