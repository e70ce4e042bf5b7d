use super::*;
use crate::chain_pomdp::tests::{lqg, quadratic, spec};
use crate::chain_pomdp::{build_with, GaussianObservation, Rows};
use beliefbus_core::chain::ChainConfig;
use beliefbus_core::model::linear::LinearSde;
use beliefbus_core::model::Bounds;
use beliefbus_core::rng::SimRng;
use nalgebra::DMatrix;
use rand::{RngExt, SeedableRng};

/// dx = u dt + σ dw in d dimensions on [lo, hi]^d.
fn walk(d: usize, sigma: f64, lo: f64, hi: f64) -> LinearSde {
    LinearSde::new(
        "walk",
        DMatrix::zeros(d, d),
        DMatrix::identity(d, d),
        DMatrix::identity(d, d) * sigma,
        DMatrix::identity(d, d),
        vec![0.1; d],
        Bounds::new_box(&vec![lo; d], &vec![hi; d]).expect("box"),
    )
}

fn mean_of(ch: &Chain, row: &[(u32, f64)]) -> Vec<f64> {
    let d = ch.dim();
    (0..d)
        .map(|c| row.iter().map(|&(j, p)| p * ch.state(j as usize)[c]).sum())
        .collect()
}

fn second_moment(pts: &[f64], d: usize, row: &[(u32, f64)], m: &[f64]) -> f64 {
    row.iter()
        .map(|&(j, p)| {
            p * (0..d)
                .map(|c| (pts[j as usize * d + c] - m[c]).powi(2))
                .sum::<f64>()
        })
        .sum()
}

/// Convex hull (counter-clockwise, Andrew's monotone chain) of 2-D points.
fn hull(pts: &[f64]) -> Vec<[f64; 2]> {
    let mut p: Vec<[f64; 2]> = pts.chunks(2).map(|v| [v[0], v[1]]).collect();
    p.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut h: Vec<[f64; 2]> = Vec::new();
    for pass in 0..2 {
        let start = h.len();
        let it: Vec<[f64; 2]> = if pass == 0 {
            p.clone()
        } else {
            p.iter().rev().copied().collect()
        };
        for q in it {
            while h.len() >= start + 2 && cross(h[h.len() - 2], h[h.len() - 1], q) <= 0.0 {
                h.pop();
            }
            h.push(q);
        }
        h.pop();
    }
    h
}

/// Signed distance of x to the hull's boundary (positive inside).
fn inside_by(h: &[[f64; 2]], x: &[f64]) -> f64 {
    (0..h.len())
        .map(|i| {
            let (a, b) = (h[i], h[(i + 1) % h.len()]);
            let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
            ((x[1] - a[1]) * ex - (x[0] - a[0]) * ey) / (ex * ex + ey * ey).sqrt()
        })
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn every_row_is_a_distribution_with_the_exact_mean_or_the_hull_point_toward_it() {
    let m = walk(2, 0.1, -2.0, 2.0);
    let mut rng = SimRng::seed_from_u64(7);
    let pts: Vec<f64> = (0..300).map(|_| rng.random_range(-2.0..2.0)).collect();
    let ch = Chain::batch(&m, ChainConfig::gaussian(2), &pts).expect("chain");
    let hl = hull(ch.states());
    let h = 0.25;
    let (mut inside, mut moved) = (0, 0);
    for u in [
        [0.0, 0.0],
        [1.0, -1.0],
        [0.3, 0.7],
        [-1.0, -1.0],
        [0.0, 1.0],
    ] {
        let rows = moment_rows(&ch, &m, &u, h);
        for (i, row) in rows.rows.iter().enumerate() {
            let total: f64 = row.iter().map(|e| e.1).sum();
            assert!((total - 1.0).abs() < 1e-12, "row {i} sums to {total}");
            assert!(row.iter().all(|e| e.1 > 0.0));
            let z = ch.state(i);
            let target: Vec<f64> = (0..2).map(|c| (z[c] + u[c] * h).clamp(-2.0, 2.0)).collect();
            let mean = mean_of(&ch, row);
            if inside_by(&hl, &target) > 1e-9 {
                inside += 1;
                for c in 0..2 {
                    assert!(
                        (mean[c] - target[c]).abs() < 1e-9,
                        "row {i} u {u:?}: mean {mean:?} target {target:?}"
                    );
                }
            } else if inside_by(&hl, &target) < -1e-9 {
                moved += 1;
                // On the hull's boundary, on the segment from z to the target.
                assert!(inside_by(&hl, &mean).abs() < 1e-9, "row {i}: {mean:?}");
                let (vx, vy) = (target[0] - z[0], target[1] - z[1]);
                let (wx, wy) = (mean[0] - z[0], mean[1] - z[1]);
                assert!((vx * wy - vy * wx).abs() < 1e-9, "row {i} off the segment");
                assert!(vx * wx + vy * wy >= -1e-12);
            }
        }
    }
    assert!(inside > 500 && moved > 20, "inside {inside}, moved {moved}");
}

#[test]
fn the_minimum_spread_is_the_brute_force_minimum_over_all_simplices() {
    let mut rng = SimRng::seed_from_u64(11);
    for trial in 0..20 {
        let n = 9;
        let pts: Vec<f64> = (0..2 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        // m a random convex combination of the points (inside their hull).
        let w: Vec<f64> = (0..n).map(|_| rng.random::<f64>().powi(3)).collect();
        let wt: f64 = w.iter().sum();
        let m: Vec<f64> = (0..2)
            .map(|c| (0..n).map(|j| w[j] / wt * pts[2 * j + c]).sum())
            .collect();
        let d2 = |j: usize| (pts[2 * j] - m[0]).powi(2) + (pts[2 * j + 1] - m[1]).powi(2);
        // Brute force: every triangle containing m, by barycentric
        // coordinates.
        let mut best = f64::INFINITY;
        for a in 0..n {
            for b in a + 1..n {
                for c in b + 1..n {
                    let (ax, ay) = (pts[2 * a], pts[2 * a + 1]);
                    let (e1x, e1y) = (pts[2 * b] - ax, pts[2 * b + 1] - ay);
                    let (e2x, e2y) = (pts[2 * c] - ax, pts[2 * c + 1] - ay);
                    let det = e1x * e2y - e1y * e2x;
                    if det.abs() < 1e-14 {
                        continue;
                    }
                    let (px, py) = (m[0] - ax, m[1] - ay);
                    let l1 = (px * e2y - py * e2x) / det;
                    let l2 = (e1x * py - e1y * px) / det;
                    let l0 = 1.0 - l1 - l2;
                    if l0 >= -1e-12 && l1 >= -1e-12 && l2 >= -1e-12 {
                        best = best.min(l0 * d2(a) + l1 * d2(b) + l2 * d2(c));
                    }
                }
            }
        }
        let mut row = Vec::new();
        let info = moment_row(&pts, 2, 0, &m, &[0.0; 4], n, &mut row);
        assert_eq!(info.spread, Spread::Minimum);
        assert!(!info.shrunk);
        assert!(row.len() <= 3, "trial {trial}: support {}", row.len());
        let v = second_moment(&pts, 2, &row, &m);
        assert!(
            (v - best).abs() < 1e-9,
            "trial {trial}: LP {v}, brute force {best}"
        );
        let mean: Vec<f64> = (0..2)
            .map(|c| row.iter().map(|&(j, p)| p * pts[2 * j as usize + c]).sum())
            .collect();
        assert!((mean[0] - m[0]).abs() < 1e-9 && (mean[1] - m[1]).abs() < 1e-9);
    }
}

#[test]
fn in_one_dimension_the_minimum_is_the_bracketing_pair() {
    let pts: Vec<f64> = (0..20).map(|i| -1.9 + 0.2 * i as f64).collect();
    let mut rng = SimRng::seed_from_u64(3);
    let mut row = Vec::new();
    for _ in 0..200 {
        let m = rng.random_range(-1.9..1.9);
        let info = moment_row(&pts, 1, 5, &[m], &[1e-6], 12, &mut row);
        let a = -1.9 + 0.2 * ((m + 1.9) / 0.2).floor();
        let expect = (m - a) * (a + 0.2 - m);
        assert!(row.len() <= 2);
        assert!((info.trace - expect).abs() < 1e-9, "m {m}: {}", info.trace);
        let mean: f64 = row.iter().map(|&(j, p)| p * pts[j as usize]).sum();
        assert!((mean - m).abs() < 1e-9);
    }
}

#[test]
fn the_trace_is_the_diffusions_where_the_states_allow_it() {
    // A 15 × 15 grid on [−1, 1]² (spacing 1/7): the least spread is at
    // most (1/7)²/2 ≈ 0.01, below τ = 0.05.
    let g: Vec<f64> = (0..15).map(|i| -1.0 + i as f64 / 7.0).collect();
    let pts: Vec<f64> = g
        .iter()
        .flat_map(|&x| g.iter().flat_map(move |&y| [x, y]))
        .collect();
    let cov = [0.02, 0.0, 0.0, 0.03];
    let mut rng = SimRng::seed_from_u64(5);
    let mut row = Vec::new();
    for _ in 0..100 {
        let m = [rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5)];
        let info = moment_row(&pts, 2, 112, &m, &cov, 36, &mut row);
        assert_eq!(info.spread, Spread::Matched);
        let v = second_moment(&pts, 2, &row, &m);
        assert!((v - 0.05).abs() < 1e-9, "trace {v}");
        let total: f64 = row.iter().map(|e| e.1).sum();
        assert!((total - 1.0).abs() < 1e-12);
        for c in 0..2 {
            let mean: f64 = row.iter().map(|&(j, p)| p * pts[2 * j as usize + c]).sum();
            assert!((mean - m[c]).abs() < 1e-9, "mean {mean} vs {}", m[c]);
        }
    }
}

/// The K-step distribution from δ_{x₀}: (mean, variance).
fn propagate(ch: &Chain, rows: &[Vec<(u32, f64)>], from: usize, steps: usize) -> (f64, f64) {
    let n = ch.len();
    let mut b = vec![0.0; n];
    b[from] = 1.0;
    for _ in 0..steps {
        let mut nb = vec![0.0; n];
        for (i, &bi) in b.iter().enumerate() {
            for &(j, p) in &rows[i] {
                nb[j as usize] += bi * p;
            }
        }
        b = nb;
    }
    let mean: f64 = (0..n).map(|i| b[i] * ch.state(i)[0]).sum();
    let var: f64 = (0..n).map(|i| b[i] * (ch.state(i)[0] - mean).powi(2)).sum();
    (mean, var)
}

#[test]
fn on_a_fine_grid_the_chain_diffuses_exactly_as_the_sde() {
    // Every row's conditional mean moves u h and its conditional variance
    // is σ² h, so after K steps the variance is K σ² h = σ² T exactly
    // (law of total variance), far from the walls.
    let sigma = 0.1;
    let m = walk(1, sigma, -1.0, 1.0);
    let pts: Vec<f64> = (0..201).map(|i| -1.0 + 0.01 * i as f64).collect();
    let ch = Chain::batch(&m, ChainConfig::gaussian(1), &pts).expect("chain");
    let (h, k, u) = (0.01, 50, 0.5);
    let rows = moment_rows(&ch, &m, &[u], h);
    // All but the wall state (its target is itself, on the hull's edge).
    assert!(rows.matched >= 200, "matched {}", rows.matched);
    let from = (0..201)
        .find(|&i| (ch.state(i)[0] + 0.5).abs() < 1e-9)
        .expect("x0");
    let (mean, var) = propagate(&ch, &rows.rows, from, k);
    let t = h * k as f64;
    assert!((mean - (-0.5 + u * t)).abs() < 1e-9, "mean {mean}");
    assert!(
        (var - sigma * sigma * t).abs() < 1e-9 * sigma * sigma * t + 1e-12,
        "variance {var} against σ²T = {}",
        sigma * sigma * t
    );
    // On a coarse grid (spacing 0.1, σ²h = 10⁻⁴ below the pairs' spread)
    // the chain spreads more, never less.
    let coarse: Vec<f64> = (0..21).map(|i| -1.0 + 0.1 * i as f64).collect();
    let ch = Chain::batch(&m, ChainConfig::gaussian(1), &coarse).expect("chain");
    let rows = moment_rows(&ch, &m, &[0.37], h);
    let from = (0..21)
        .find(|&i| (ch.state(i)[0] + 0.5).abs() < 1e-9)
        .expect("x0");
    let (mean, var) = propagate(&ch, &rows.rows, from, k);
    assert!((mean - (-0.5 + 0.37 * t)).abs() < 1e-9, "mean {mean}");
    assert!(var > sigma * sigma * t, "variance {var}");
}

#[test]
fn a_target_past_the_last_state_stops_at_that_state() {
    // States on [−0.9, 0.9] in the box [−1, 1]: from 0.7 with u h = 0.5 the
    // clamped target 1.0 lies beyond the hull; the row is all at 0.9.
    let m = walk(1, 0.1, -1.0, 1.0);
    let pts: Vec<f64> = (0..10).map(|i| -0.9 + 0.2 * i as f64).collect();
    let ch = Chain::batch(&m, ChainConfig::gaussian(1), &pts).expect("chain");
    let rows = moment_rows(&ch, &m, &[1.0], 0.5);
    let i = (0..10)
        .find(|&i| (ch.state(i)[0] - 0.7).abs() < 1e-9)
        .expect("0.7");
    let row = &rows.rows[i];
    assert_eq!(row.len(), 1);
    assert!((ch.state(row[0].0 as usize)[0] - 0.9).abs() < 1e-12);
    assert!(rows.shrunk >= 2, "shrunk {}", rows.shrunk);
}

#[test]
fn the_belief_update_over_moment_rows_is_the_direct_bayes_update() {
    let m = lqg(0.3);
    let ch = super::super::tests::chain(&m, 60, 1);
    let obs = GaussianObservation {
        model: &m,
        std: vec![0.3],
    };
    let us = [0.0, 0.5, -0.5];
    let cp = build_with(
        &ch,
        &m,
        &obs,
        &quadratic,
        &spec(60, &us, 1.0, 0.2),
        Rows::Moment,
    )
    .expect("pomdp");
    let mut rng = SimRng::seed_from_u64(9);
    let mut b: Vec<f64> = (0..60).map(|_| rng.random::<f64>()).collect();
    let s: f64 = b.iter().sum();
    b.iter_mut().for_each(|v| *v /= s);
    for step in 0..30 {
        let a = step % us.len();
        let y = [rng.random_range(-1.0..1.0)];
        // Direct: rows computed here, prediction, then the likelihood.
        let rows = moment_rows(&ch, &m, &[us[a]], cp.period);
        let mut pred = vec![0.0; 60];
        for (i, &bi) in b.iter().enumerate() {
            for &(j, p) in &rows.rows[i] {
                pred[j as usize] += bi * p;
            }
        }
        let mut post: Vec<f64> = (0..60)
            .map(|j| pred[j] * (-0.5 * ((y[0] - ch.state(j)[0]) / 0.3).powi(2)).exp())
            .collect();
        let s: f64 = post.iter().sum();
        post.iter_mut().for_each(|v| *v /= s);
        let mut out = vec![0.0; 60];
        assert!(cp.update(&b, a, &y, &obs, &mut out));
        for j in 0..60 {
            assert!(
                (out[j] - post[j]).abs() < 1e-12,
                "step {step} state {j}: {} vs {}",
                out[j],
                post[j]
            );
        }
        b = out;
    }
}

/// Splitting the period into k sub-steps and taking the product of their
/// rows cannot make a constant-drift move less diffusive: every sub-step
/// row is mean-exact, so the product is a mean-exact distribution for the
/// whole move, and the one-step row is the least-spread such distribution
/// (the LP above). Checked on a 150-point 2-D set like the light-dark
/// chains' (spacing ≈ 0.3), moves of 0.3–0.9 from interior states.
#[test]
fn sub_steps_never_spread_less_than_the_one_step_row() {
    let mut rng = SimRng::seed_from_u64(5);
    let n = 150;
    let pts: Vec<f64> = (0..2 * n).map(|_| rng.random_range(-2.0..2.0)).collect();
    let k0 = 4 * 9;
    let row_at = |from: usize, step: &[f64]| {
        let m: Vec<f64> = (0..2).map(|c| pts[2 * from + c] + step[c]).collect();
        let mut row = Vec::new();
        let info = moment_row(&pts, 2, from, &m, &[0.0; 4], k0, &mut row);
        (row, info)
    };
    let mut grew = 0;
    let mut checked = 0;
    for _ in 0..400 {
        let from = rng.random_range(0..n);
        let z = [pts[2 * from], pts[2 * from + 1]];
        let len = rng.random_range(0.3..0.9);
        let ang = rng.random_range(0.0..std::f64::consts::TAU);
        let step = [len * ang.cos(), len * ang.sin()];
        if z.iter()
            .zip(&step)
            .any(|(a, b)| (a + b).abs() > 0.9 || a.abs() > 0.9)
        {
            continue;
        }
        let target = [z[0] + step[0], z[1] + step[1]];
        let mut traces = Vec::new();
        let mut left_hull = false;
        for k in [1usize, 2, 4] {
            let sub = [step[0] / k as f64, step[1] / k as f64];
            let mut dist = vec![(from as u32, 1.0)];
            for _ in 0..k {
                let mut next = vec![0.0; n];
                for &(j, p) in &dist {
                    let (row, info) = row_at(j as usize, &sub);
                    // Near the hull the row's mean is moved (module doc):
                    // no longer the constant-drift move compared here.
                    left_hull |= info.shrunk;
                    for (i, q) in row {
                        next[i as usize] += p * q;
                    }
                }
                dist = (0..n as u32).zip(next).filter(|&(_, p)| p > 0.0).collect();
            }
            if left_hull {
                break;
            }
            let mean: Vec<f64> = (0..2)
                .map(|c| dist.iter().map(|&(j, p)| p * pts[2 * j as usize + c]).sum())
                .collect();
            assert!(
                (mean[0] - target[0]).abs() < 1e-9 && (mean[1] - target[1]).abs() < 1e-9,
                "{k} sub-steps: mean {mean:?}, target {target:?}"
            );
            traces.push(second_moment(&pts, 2, &dist, &target));
        }
        if left_hull {
            continue;
        }
        assert!(
            traces[1] >= traces[0] - 1e-12 && traces[2] >= traces[0] - 1e-12,
            "sub-steps spread less: {traces:?}"
        );
        grew += usize::from(traces[2] > 1.5 * traces[0]);
        checked += 1;
    }
    assert!(checked >= 10, "{checked} interior moves");
    // Not a tie: sub-steps usually spread much more.
    assert!(2 * grew >= checked, "{grew} of {checked} grew by half");
}
