//! The Gaussian projection against statistical bounds and exact identities.

use beliefbus_projection::rng::stream;
use beliefbus_projection::{Axis, ExpFamily, Gaussian, ParamGrid, ProjectionError};
use nalgebra::{DMatrix, DVector};
use rand::RngExt;
use rand_distr::StandardNormal;

fn target() -> (DVector<f64>, DMatrix<f64>) {
    let m = DVector::from_vec(vec![1.0, -2.0, 0.5]);
    let s = DMatrix::from_row_slice(3, 3, &[2.0, 0.6, -0.3, 0.6, 1.0, 0.2, -0.3, 0.2, 0.5]);
    (m, s)
}

/// Draws from N(m, S) through nalgebra's own Cholesky (independent of ours).
fn draws(m: &DVector<f64>, s: &DMatrix<f64>, n: usize, seed: u64) -> Vec<f64> {
    let l = s.clone().cholesky().expect("positive definite").l();
    let d = m.len();
    let mut rng = stream(seed, 0);
    let mut out = Vec::with_capacity(n * d);
    for _ in 0..n {
        let z = DVector::from_fn(d, |_, _| rng.sample::<f64, _>(StandardNormal));
        out.extend((m + &l * z).iter());
    }
    out
}

#[test]
fn projection_of_a_gaussian_sample_recovers_mean_and_covariance() {
    let (m, s) = target();
    let n = 20_000;
    let fam = Gaussian::new(3).unwrap();
    for seed in 0..5 {
        let x = draws(&m, &s, n, seed);
        let w = vec![1.0 / n as f64; n];
        let mut p = fam.new_params();
        fam.project(&x, &w, &mut p).unwrap();
        assert_eq!(p.rank, 3);
        for i in 0..3 {
            let se = (s[(i, i)] / n as f64).sqrt();
            assert!(
                (p.mean[i] - m[i]).abs() < 4.5 * se,
                "mean {i}: {} vs {}",
                p.mean[i],
                m[i]
            );
            for j in 0..3 {
                // Var of a sample covariance entry: (S_ii S_jj + S_ij²)/n.
                let se = ((s[(i, i)] * s[(j, j)] + s[(i, j)].powi(2)) / n as f64).sqrt();
                assert!(
                    (p.cov[(i, j)] - s[(i, j)]).abs() < 4.5 * se,
                    "cov {i}{j}: {} vs {}",
                    p.cov[(i, j)],
                    s[(i, j)]
                );
            }
        }
    }
}

#[test]
fn weighted_projection_recovers_the_reweighted_gaussian() {
    // Proposal N(0, 2²), weights ∝ N(1, 0.5²)/N(0, 2²): the weighted
    // particles represent N(1, 0.25), whose projection is N(1, 0.25).
    let fam = Gaussian::new(1).unwrap();
    let n = 50_000;
    let mut rng = stream(11, 1);
    let x: Vec<f64> = (0..n)
        .map(|_| 2.0 * rng.sample::<f64, _>(StandardNormal))
        .collect();
    let lw: Vec<f64> = x
        .iter()
        .map(|&x| -0.5 * ((x - 1.0) / 0.5f64).powi(2) + 0.5 * (x / 2.0).powi(2))
        .collect();
    let mut w = vec![0.0; n];
    beliefbus_projection::model::normalize_log_weights(&lw, &mut w).unwrap();
    let ess = 1.0 / w.iter().map(|w| w * w).sum::<f64>();
    let mut p = fam.new_params();
    fam.project(&x, &w, &mut p).unwrap();
    assert!(
        (p.mean[0] - 1.0).abs() < 5.0 * (0.25 / ess).sqrt(),
        "mean {}",
        p.mean[0]
    );
    assert!(
        (p.cov[(0, 0)] - 0.25).abs() < 5.0 * 0.25 * (2.0 / ess).sqrt(),
        "var {}",
        p.cov[(0, 0)]
    );
}

#[test]
fn projection_matches_the_weighted_sufficient_statistics_exactly() {
    // Eq. 14: E_θ[c] = Σ w c(x), for arbitrary non-Gaussian particles.
    let fam = Gaussian::new(2).unwrap();
    let mut rng = stream(3, 3);
    let n = 37;
    let x: Vec<f64> = (0..2 * n)
        .map(|_| rng.random::<f64>().powi(3) * 10.0 - 2.0)
        .collect();
    let raw: Vec<f64> = (0..n).map(|_| rng.random::<f64>() + 0.01).collect();
    let total: f64 = raw.iter().sum();
    let w: Vec<f64> = raw.iter().map(|r| r / total).collect();
    let mut p = fam.new_params();
    fam.project(&x, &w, &mut p).unwrap();
    let m = fam.num_stats();
    let (mut want, mut c, mut got) = (vec![0.0; m], vec![0.0; m], vec![0.0; m]);
    for (xi, wi) in x.chunks(2).zip(&w) {
        fam.stats(xi, &mut c);
        for k in 0..m {
            want[k] += wi * c[k];
        }
    }
    fam.expected_stats(&p, &mut got);
    for k in 0..m {
        assert!(
            (got[k] - want[k]).abs() < 1e-10 * (1.0 + want[k].abs()),
            "stat {k}: {} vs {}",
            got[k],
            want[k]
        );
    }
}

#[test]
fn cholesky_equals_nalgebra_and_draws_have_the_covariance() {
    let (m, s) = target();
    let fam = Gaussian::new(3).unwrap();
    let p = fam.params(m.as_slice(), s.transpose().as_slice()).unwrap();
    let l = s.clone().cholesky().unwrap().l();
    assert!((&p.chol - &l).amax() < 1e-12);
    let n = 40_000;
    let mut rng = stream(5, 5);
    let mut x = vec![0.0; 3 * n];
    for xi in x.chunks_mut(3) {
        fam.sample(&p, &mut rng, xi);
    }
    let mut q = fam.new_params();
    fam.project(&x, &vec![1.0 / n as f64; n], &mut q).unwrap();
    for i in 0..3 {
        assert!((q.mean[i] - m[i]).abs() < 4.5 * (s[(i, i)] / n as f64).sqrt());
        for j in 0..3 {
            let se = ((s[(i, i)] * s[(j, j)] + s[(i, j)].powi(2)) / n as f64).sqrt();
            assert!((q.cov[(i, j)] - s[(i, j)]).abs() < 4.5 * se);
        }
    }
}

#[test]
fn degenerate_projections_are_point_masses_or_subspaces() {
    let fam = Gaussian::new(2).unwrap();
    let mut rng = stream(9, 9);
    // All particles equal: σ = 0, every draw is the mean.
    let x = [3.0, -1.0].repeat(50);
    let w = vec![1.0 / 50.0; 50];
    let mut p = fam.new_params();
    fam.project(&x, &w, &mut p).unwrap();
    assert_eq!(p.rank, 0);
    assert!((p.mean[0] - 3.0).abs() < 1e-12 && (p.mean[1] + 1.0).abs() < 1e-12);
    let mut d = [0.0; 2];
    for _ in 0..100 {
        fam.sample(&p, &mut rng, &mut d);
        assert_eq!(d, [p.mean[0], p.mean[1]]);
    }
    // Particles on the line x2 = 2 x1 + 1: rank one, draws stay on it.
    let x: Vec<f64> = (0..200)
        .flat_map(|i| {
            let t = i as f64 * 0.1 - 3.0;
            [t, 2.0 * t + 1.0]
        })
        .collect();
    let w = vec![1.0 / 200.0; 200];
    fam.project(&x, &w, &mut p).unwrap();
    assert_eq!(p.rank, 1);
    for _ in 0..1000 {
        fam.sample(&p, &mut rng, &mut d);
        assert!(
            (d[1] - 2.0 * d[0] - 1.0).abs() < 1e-9 * (1.0 + d[0].abs()),
            "{d:?} left the line"
        );
    }
    // The std = 0 grid point.
    fam.params_from_grid(&[4.0, 1.0, 0.0, 0.0], &mut p).unwrap();
    assert_eq!(p.rank, 0);
    assert!(matches!(
        fam.params_from_grid(&[4.0, 1.0, -0.1, 0.0], &mut p),
        Err(ProjectionError::Invalid { .. })
    ));
    // Not positive semi-definite input is refused, not factored.
    assert!(fam.params(&[0.0, 0.0], &[1.0, 2.0, 2.0, 1.0]).is_err());
}

#[test]
fn nearest_grid_point_is_the_euclidean_nearest() {
    let grid = ParamGrid::inventory_paper();
    assert_eq!(grid.len(), 806);
    let mut rng = stream(1, 2);
    let mut pt = [0.0; 2];
    for _ in 0..2000 {
        let c = [
            rng.random::<f64>() * 20.0 - 2.0,
            rng.random::<f64>() * 6.0 - 0.5,
        ];
        let got = grid.nearest(&c).unwrap();
        let best = (0..grid.len())
            .map(|i| {
                grid.point(i, &mut pt);
                ((c[0] - pt[0]).powi(2) + (c[1] - pt[1]).powi(2), i)
            })
            .fold((f64::INFINITY, 0), |b, x| if x.0 < b.0 { x } else { b });
        grid.point(got, &mut pt);
        let d_got = (c[0] - pt[0]).powi(2) + (c[1] - pt[1]).powi(2);
        assert!(
            d_got <= best.0 + 1e-12,
            "{c:?}: {got} at {d_got} vs {} at {}",
            best.1,
            best.0
        );
    }
    assert!(grid.nearest(&[f64::NAN, 0.0]).is_err());
    assert!(Axis::range(0.0, 0.0, 1.0).is_err());
}
