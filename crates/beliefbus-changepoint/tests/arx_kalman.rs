//! The ARX filter's per-particle Kalman statistics against an independent
//! batch fit: on a segment with no change, (μ_{C,t}, V_{C,t}) must equal
//! the regularised least-squares solution of (14),
//! V_{s,t} = (V⁻¹ + Σφφᵀ)⁻¹, μ_{s,t} = V_{s,t}(V⁻¹μ + Σ yφ),
//! computed here by Gauss-Jordan elimination on the normal equations.

use beliefbus_changepoint::arx::linalg::kalman_update;
use beliefbus_changepoint::arx::plant::{ArxPlant, ThetaRegion};
use beliefbus_changepoint::arx::rbpf::{ArxRbpf, ArxRbpfConfig};
use beliefbus_changepoint::arx::ThetaPrior;
use beliefbus_changepoint::rng;
use rand_distr::{Distribution, StandardNormal};

/// Solve A X = B (A n×n, B n×m) by Gauss-Jordan with partial pivoting.
fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
    let n = a.len();
    for c in 0..n {
        let p = (c..n)
            .max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))
            .unwrap();
        a.swap(c, p);
        b.swap(c, p);
        for r in 0..n {
            if r != c {
                let f = a[r][c] / a[c][c];
                for k in 0..n {
                    a[r][k] -= f * a[c][k];
                }
                for k in 0..b[0].len() {
                    b[r][k] -= f * b[c][k];
                }
            }
        }
    }
    for r in 0..n {
        let d = a[r][r];
        for x in b[r].iter_mut() {
            *x /= d;
        }
    }
    b
}

fn batch(prior: &ThetaPrior<3>, data: &[(f64, [f64; 3])]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let vinv = solve(
        prior.v.iter().map(|r| r.to_vec()).collect(),
        (0..3)
            .map(|i| (0..3).map(|j| if i == j { 1.0 } else { 0.0 }).collect())
            .collect(),
    );
    let mut a = vinv.clone();
    let mut rhs: Vec<f64> = (0..3)
        .map(|i| (0..3).map(|j| vinv[i][j] * prior.mu[j]).sum())
        .collect();
    for (y, phi) in data {
        for i in 0..3 {
            rhs[i] += y * phi[i];
            for j in 0..3 {
                a[i][j] += phi[i] * phi[j];
            }
        }
    }
    let mu = solve(a.clone(), rhs.iter().map(|&x| vec![x]).collect());
    let cov = solve(
        a,
        (0..3)
            .map(|i| (0..3).map(|j| if i == j { 1.0 } else { 0.0 }).collect())
            .collect(),
    );
    (mu.into_iter().map(|r| r[0]).collect(), cov)
}

fn segment(n: usize, seed: u64) -> Vec<(f64, [f64; 3])> {
    // A plant with a change probability so small no change happens.
    let mut r = rng::stream(seed, 0);
    let mut plant = ArxPlant::<3>::new(
        2,
        1e-12,
        ThetaPrior::standard(),
        ThetaRegion::StableAr,
        &mut r,
    )
    .unwrap();
    let mut out = vec![];
    for _ in 0..n {
        let (y, phi, _, jumped) = plant.observe(&mut r);
        assert!(!jumped);
        let u: f64 = StandardNormal.sample(&mut r);
        plant.apply(y, u);
        out.push((y, phi));
    }
    out
}

#[test]
fn rank_one_recursions_equal_the_batch_fit() {
    let prior = ThetaPrior::new(
        [0.1, -0.2, 0.5],
        [[2.0, 0.3, 0.0], [0.3, 1.0, 0.1], [0.0, 0.1, 0.5]],
    )
    .unwrap();
    let data = segment(200, 4);
    let (mut mu, mut v) = (prior.mu, prior.v);
    for (t, (y, phi)) in data.iter().enumerate() {
        kalman_update(&mut mu, &mut v, phi, *y);
        if t % 37 == 0 || t + 1 == data.len() {
            let (bm, bv) = batch(&prior, &data[..=t]);
            for i in 0..3 {
                assert!(
                    (mu[i] - bm[i]).abs() < 1e-9,
                    "t={t} mu[{i}] {} vs {}",
                    mu[i],
                    bm[i]
                );
                for j in 0..3 {
                    assert!((v[i][j] - bv[i][j]).abs() < 1e-9);
                }
            }
        }
    }
}

/// With ρ = 1e-12 no particle proposes a change, so every particle's
/// statistics — and the Bayes estimate (15) — are the batch fit of the whole
/// segment; with a diffuse prior that is ordinary least squares.
#[test]
fn filter_statistics_on_an_unbroken_segment_are_the_least_squares_fit() {
    let prior = ThetaPrior::new(
        [0.0; 3],
        [[1e6, 0.0, 0.0], [0.0, 1e6, 0.0], [0.0, 0.0, 1e6]],
    )
    .unwrap();
    let data = segment(300, 9);
    let cfg = ArxRbpfConfig {
        rho: 1e-12,
        ..ArxRbpfConfig::default()
    };
    let mut f = ArxRbpf::<3>::new(prior, cfg, rng::stream(1, 1)).unwrap();
    // The filter starts at t₀ = 3; the first two pairs only fill the lags.
    let used = &data[2..];
    let mut est = [0.0; 3];
    for (y, phi) in used {
        est = f.step(*y, phi).unwrap();
    }
    let (bm, bv) = batch(&prior, used);
    for j in 0..50 {
        let (c, mu, v) = f.particle(j).unwrap();
        assert_eq!(c, 1, "particle {j} changed");
        for i in 0..3 {
            assert!((mu[i] - bm[i]).abs() < 1e-8);
            assert!((v[i][i] - bv[i][i]).abs() < 1e-8 * bv[i][i].abs().max(1e-6));
        }
    }
    for i in 0..3 {
        assert!((est[i] - bm[i]).abs() < 1e-8);
    }
    assert_eq!(f.prob_change_since(2), 0.0);
}
