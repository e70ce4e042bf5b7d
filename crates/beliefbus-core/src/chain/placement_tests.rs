use super::{eliminate, predictive_even, predictive_points, PRIOR_FRACTION};
use crate::belief::Gaussian;
use crate::model::linear::LinearSde;
use crate::model::Bounds;
use nalgebra::DMatrix;
use rand::RngExt;

/// Smallest distance between two distinct points (brute force, d = 2).
fn min_pair(p: &[f64]) -> f64 {
    let n = p.len() / 2;
    let mut best = f64::INFINITY;
    for i in 0..n {
        for j in i + 1..n {
            best = best.min((p[2 * i] - p[2 * j]).hypot(p[2 * i + 1] - p[2 * j + 1]));
        }
    }
    best
}

/// Mean distance from each point to its nearest other point (d = 2).
fn mean_nn(p: &[f64]) -> f64 {
    let n = p.len() / 2;
    let mut s = 0.0;
    for i in 0..n {
        let mut best = f64::INFINITY;
        for j in 0..n {
            if i != j {
                best = best.min((p[2 * i] - p[2 * j]).hypot(p[2 * i + 1] - p[2 * j + 1]));
            }
        }
        s += best;
    }
    s / n as f64
}

#[test]
fn elimination_keeps_the_density_and_spreads_the_points() {
    // Candidates: density 1 on [0,1]², density 4 on [1,2]×[0,1]
    // (1200 + 4800); keep 1/4. Each region keeps ≈ 1/4 of its own
    // candidates, every kept point is a candidate, and the kept points'
    // mean nearest-neighbour distance beats an i.i.d. quarter's.
    let mut rng = crate::rng::stream(4, 0);
    let mut cand = vec![];
    for _ in 0..1200 {
        cand.push(rng.random::<f64>());
        cand.push(rng.random::<f64>());
    }
    for _ in 0..4800 {
        cand.push(1.0 + rng.random::<f64>());
        cand.push(rng.random::<f64>());
    }
    let kept = eliminate(&cand, 2, 1500);
    assert_eq!(kept.len(), 2 * 1500);
    for k in kept.chunks(2) {
        assert!(cand.chunks(2).any(|c| c == k), "{k:?} is not a candidate");
    }
    let left = kept.chunks(2).filter(|k| k[0] < 1.0).count() as f64;
    // 300 expected on the left; the binomial sd of an i.i.d. pick is ≈ 15
    assert!((left - 300.0).abs() < 45.0, "left region kept {left}");
    // i.i.d. quarter: every 4th candidate (candidates are i.i.d.)
    let iid: Vec<f64> = cand.chunks(2).step_by(4).flatten().copied().collect();
    let (even, random) = (mean_nn(&kept), mean_nn(&iid));
    assert!(
        even > 1.3 * random,
        "mean NN distance {even} vs i.i.d. {random}"
    );
}

#[test]
fn elimination_keeps_n_distinct_candidates_farther_apart_than_iid() {
    // 2000 uniform candidates on [0,1]², keep 400. Every kept point is a
    // distinct candidate, and the smallest pairwise distance beats that of
    // i.i.d. draws of 400 uniform points in every one of 10 seeded draws
    // (for 400 i.i.d. points the expected minimum is ≈ 1/(400·√(π·200))
    // ≈ 1e-4; Poisson-disk-like sets keep it near their spacing ≈ 0.03).
    for seed in 0..10 {
        let mut rng = crate::rng::stream(40, seed);
        let cand: Vec<f64> = (0..4000).map(|_| rng.random::<f64>()).collect();
        let kept = eliminate(&cand, 2, 400);
        assert_eq!(kept.len(), 800);
        let mut idx: Vec<usize> = kept
            .chunks(2)
            .map(|k| {
                cand.chunks(2)
                    .position(|c| c == k)
                    .expect("kept point is a candidate")
            })
            .collect();
        idx.sort_unstable();
        idx.dedup();
        assert_eq!(idx.len(), 400, "kept points are distinct");
        let iid: Vec<f64> = (0..800).map(|_| rng.random::<f64>()).collect();
        let (even, random) = (min_pair(&kept), min_pair(&iid));
        assert!(
            even > 3.0 * random,
            "seed {seed}: min distance {even} vs i.i.d. {random}"
        );
    }
}

#[test]
fn elimination_returns_all_candidates_when_asked_for_more() {
    let cand = [0.0, 0.0, 1.0, 1.0, 2.0, 0.5];
    assert_eq!(eliminate(&cand, 2, 3), cand.to_vec());
    assert_eq!(eliminate(&cand, 2, 10), cand.to_vec());
}

/// dx1 = x2 dt, dx2 = −4 x1 dt + tiny noise: orbits are the ellipses
/// x1 = a cos 2t, x2 = −2a sin 2t, of period π.
fn ellipse_model() -> LinearSde {
    LinearSde::new(
        "ellipse",
        DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -4.0, 0.0]),
        DMatrix::zeros(2, 0),
        DMatrix::from_row_slice(2, 2, &[1e-4, 0.0, 0.0, 1e-4]),
        DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
        vec![0.1],
        Bounds::new_box(&[-3.0, -3.0], &[3.0, 3.0]).unwrap(),
    )
}

#[test]
fn predictive_points_are_uniform_in_arc_length_along_the_flow() {
    // Prior concentrated at (1, 0), horizon one period π: trajectories trace
    // the ellipse x1 = cos 2t, x2 = −2 sin 2t. The share of points with
    // |x1| > 0.7 is PRIOR_FRACTION (the prior draws sit at x1 = 1) plus
    // (1 − PRIOR_FRACTION) × the arc-length share of that part of the
    // ellipse, computed here by a fine polyline — not the time share
    // (the state is fastest at |x1| = 1, so time-uniform points would put
    // less there).
    let model = ellipse_model();
    let prior = Gaussian::diagonal(&[1.0, 0.0], &[1e-4, 1e-4]);
    let mut rng = crate::rng::stream(41, 0);
    let n = 20_000;
    let pts =
        predictive_points(&model, &prior, std::f64::consts::PI, n, 0.0, 1e-3, &mut rng).unwrap();
    assert_eq!(pts.len(), 2 * n);
    let (mut far, mut total, mut time_far) = (0.0, 0.0, 0usize);
    let k = 200_000;
    let p = |t: f64| ((2.0 * t).cos(), -2.0 * (2.0 * t).sin());
    for i in 0..k {
        let (t0, t1) = (
            i as f64 * std::f64::consts::PI / k as f64,
            (i + 1) as f64 * std::f64::consts::PI / k as f64,
        );
        let (a, b) = (p(t0), p(t1));
        let len = (a.0 - b.0).hypot(a.1 - b.1);
        total += len;
        if (0.5 * (a.0 + b.0)).abs() > 0.7 {
            far += len;
            time_far += 1;
        }
    }
    let arc_share = far / total;
    let time_share = time_far as f64 / k as f64;
    let want = PRIOR_FRACTION + (1.0 - PRIOR_FRACTION) * arc_share;
    let got = pts.chunks(2).filter(|x| x[0].abs() > 0.7).count() as f64 / n as f64;
    let sd = (want * (1.0 - want) / n as f64).sqrt();
    assert!(
        (got - want).abs() < 5.0 * sd,
        "share {got}, arc-length {want}"
    );
    // the test can tell the two laws apart
    let want_time = PRIOR_FRACTION + (1.0 - PRIOR_FRACTION) * time_share;
    assert!(
        (want - want_time).abs() > 20.0 * sd,
        "{want} vs {want_time}"
    );
    // on the orbit: x1² + x2²/4 = 1
    for x in pts.chunks(2) {
        assert!(
            (x[0] * x[0] + x[1] * x[1] / 4.0 - 1.0).abs() < 0.02,
            "{x:?}"
        );
    }
}

#[test]
fn predictive_even_is_seeded_and_stays_in_the_set() {
    let model = ellipse_model();
    let prior = Gaussian::diagonal(&[1.0, 0.0], &[0.1, 0.1]);
    let run = |seed| {
        let mut rng = crate::rng::stream(seed, 0);
        predictive_even(&model, &prior, 2.0, 300, 3, 0.1, 1e-2, &mut rng).unwrap()
    };
    let a = run(5);
    assert_eq!(a.len(), 600);
    assert_eq!(a, run(5));
    assert_ne!(a, run(6));
    let b = Bounds::new_box(&[-3.0, -3.0], &[3.0, 3.0]).unwrap();
    assert!(a.chunks(2).all(|x| b.contains(x)));
    // a singular prior is an error, not a panic
    let bad = Gaussian::zeros(2);
    let mut rng = crate::rng::stream(5, 0);
    assert!(predictive_points(&model, &bad, 1.0, 10, 0.0, 1e-2, &mut rng).is_err());
}
