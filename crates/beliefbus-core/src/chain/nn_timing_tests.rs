//! The chain's two nearest-neighbour structures on its own workload:
//! [`SpatialIndex`] (kiddo) and [`KnnTree`] (reverse queries with per-point
//! bounds), on uniform and belief-concentrated points (90 % N(½, 0.05²)
//! per axis, 10 % uniform, as `Sampler::Mixture` places them), d = 2–6,
//! n = 10³–10⁵, k = max(⌈1.5 ln n⌉, 2 + d + d(d+1)/2) (the k-NN Near rule
//! with its moment floor). Reported per operation: bulk build, k-NN query,
//! and the reverse query of an insertion (every point whose k-th
//! neighbour is farther than the new point) — the KnnTree's own traversal
//! against kiddo's radius query at the largest k-th radius, filtered. The
//! two reverse answers must be equal (checked); times are printed only.
//! `cargo test -p beliefbus-core --release --lib nn_structures -- --ignored --nocapture`

use std::time::Instant;

use rand::RngExt;
use rand_distr::{Distribution, Normal};

use super::index::SpatialIndex;
use super::knn_tree::KnnTree;

fn points(n: usize, d: usize, concentrated: bool, seed: u64) -> Vec<f64> {
    let mut rng = crate::rng::stream(seed, 0);
    let g = Normal::new(0.5, 0.05).unwrap();
    let mut p = Vec::with_capacity(n * d);
    for _ in 0..n {
        let uniform = !concentrated || rng.random::<f64>() < 0.1;
        for _ in 0..d {
            p.push(if uniform {
                rng.random::<f64>()
            } else {
                g.sample(&mut rng)
            });
        }
    }
    p
}

#[test]
#[ignore]
fn nn_structures() {
    let mut nn = Vec::new();
    for concentrated in [false, true] {
        for d in [2usize, 4, 6] {
            for n in [1_000usize, 10_000, 100_000] {
                let k = ((1.5 * (n as f64).ln()).ceil() as usize).max(2 + d + d * (d + 1) / 2);
                let pts = points(n, d, concentrated, 7);
                let t0 = Instant::now();
                let kd = SpatialIndex::from_points(d, &pts).unwrap();
                let kd_build = t0.elapsed().as_nanos() as f64 / n as f64;
                let t0 = Instant::now();
                let mut rt = KnnTree::from_points(d, &pts);
                let rt_build = t0.elapsed().as_nanos() as f64 / n as f64;
                // Bounds: squared distance to the k-th other point.
                let mut b = vec![0.0; n];
                for i in 0..n {
                    kd.nearest(&pts[i * d..(i + 1) * d], k + 1, &mut nn);
                    b[i] = nn.last().unwrap().1;
                    rt.set_bound(i as u32, b[i]);
                }
                let bmax = b.iter().cloned().fold(0.0, f64::max);
                let q = points(2000, d, concentrated, 8);
                let nq = 2000;
                let t0 = Instant::now();
                let mut s1 = 0.0;
                for j in 0..nq {
                    kd.nearest(&q[j * d..(j + 1) * d], k, &mut nn);
                    s1 += nn[k - 1].1;
                }
                let kd_knn = t0.elapsed().as_nanos() as f64 / nq as f64;
                let t0 = Instant::now();
                let mut s2 = 0.0;
                for j in 0..nq {
                    rt.nearest(&q[j * d..(j + 1) * d], k, u32::MAX, &mut nn);
                    s2 += nn[k - 1].1;
                }
                let rt_knn = t0.elapsed().as_nanos() as f64 / nq as f64;
                assert!((s1 - s2).abs() <= 1e-9 * s1.abs(), "k-NN answers differ");
                let t0 = Instant::now();
                let mut h1 = 0usize;
                for j in 0..nq {
                    kd.within(&q[j * d..(j + 1) * d], bmax.sqrt(), &mut nn);
                    h1 += nn.iter().filter(|&&(s, d2)| d2 < b[s as usize]).count();
                }
                let kd_rev = t0.elapsed().as_nanos() as f64 / nq as f64;
                let t0 = Instant::now();
                let mut h2 = 0usize;
                for j in 0..nq {
                    rt.reverse(&q[j * d..(j + 1) * d], &mut |_, _, bound| {
                        h2 += 1;
                        bound
                    });
                }
                let rt_rev = t0.elapsed().as_nanos() as f64 / nq as f64;
                assert_eq!(h1, h2, "reverse answers differ");
                eprintln!(
                    "{} d={d} n={n:>6} k={k:>2}: build kiddo {kd_build:>5.0} / knn_tree {rt_build:>5.0} ns/pt; k-NN kiddo {kd_knn:>6.0} / knn_tree {rt_knn:>6.0} ns; reverse kiddo+filter {kd_rev:>8.0} / knn_tree {rt_rev:>6.0} ns ({:.1} hits)",
                    if concentrated { "concentrated" } else { "uniform     " },
                    h1 as f64 / nq as f64
                );
            }
        }
    }
}
