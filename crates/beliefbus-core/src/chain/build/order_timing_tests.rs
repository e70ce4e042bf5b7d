//! Batch construction time and the space-filling order's locality (mean
//! distance between consecutive states) on concentrated states, d = 2–6.
//! A measurement, not a check (Morton: the order it replaced):
//! `cargo test -p beliefbus-core --release --lib batch_order_timing -- --ignored --nocapture`

use super::*;
use crate::model::linear::LinearSde;
use crate::model::Bounds;
use nalgebra::DMatrix;
use rand_distr::{Distribution, Normal};

fn locality(points: &[f64], d: usize, order: &[u32]) -> f64 {
    let dist = |a: u32, b: u32| {
        let (a, b) = (a as usize, b as usize);
        (0..d)
            .map(|c| (points[a * d + c] - points[b * d + c]).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    order.windows(2).map(|w| dist(w[0], w[1])).sum::<f64>() / (order.len() - 1) as f64
}

#[test]
#[ignore]
fn batch_order_timing() {
    for d in [2usize, 4, 6] {
        let m = LinearSde::new(
            "oud",
            -DMatrix::identity(d, d),
            DMatrix::zeros(d, 0),
            DMatrix::identity(d, d) * 0.5,
            DMatrix::identity(d, d),
            vec![0.2; d],
            Bounds::new_box(&vec![-3.0; d], &vec![3.0; d]).unwrap(),
        );
        let n = 20_000;
        let g = Normal::new(0.0, 0.7).unwrap();
        let mut rng = crate::rng::stream(11, 0);
        let pts: Vec<f64> = (0..n * d).map(|_| g.sample(&mut rng)).collect();
        let t0 = std::time::Instant::now();
        let c = Chain::batch(&m, ChainConfig::moment_matched(d), &pts).unwrap();
        let build = t0.elapsed().as_secs_f64();
        let ident: Vec<u32> = (0..n as u32).collect();
        let h = crate::chain::order::hilbert_order(&pts, d);
        eprintln!(
            "d={d} n={n}: batch build {build:.3} s ({} rows); consecutive distance: input {:.4}, hilbert {:.4}{}",
            c.len(),
            locality(&pts, d, &ident),
            locality(&pts, d, &h),
            morton_line(&pts, d)
        );
    }
}

fn morton_line(pts: &[f64], d: usize) -> String {
    format!(", morton {:.4}", locality(pts, d, &morton_order(d, pts)))
}

/// The Morton (Z-curve) order batch construction used before the Hilbert
/// order replaced it: kept here only as the reference of the locality
/// figure.
fn morton_order(d: usize, points: &[f64]) -> Vec<u32> {
    let n = points.len() / d.max(1);
    if d == 0 || n == 0 {
        return vec![];
    }
    let bits = (63 / d).min(16) as u32;
    let mut lo = [f64::INFINITY; MAX_INDEX_DIM];
    let mut hi = [f64::NEG_INFINITY; MAX_INDEX_DIM];
    for p in points.chunks_exact(d) {
        for c in 0..d {
            lo[c] = lo[c].min(p[c]);
            hi[c] = hi[c].max(p[c]);
        }
    }
    let levels = ((1u64 << bits) - 1) as f64;
    let mut keyed: Vec<(u64, u32)> = points
        .chunks_exact(d)
        .enumerate()
        .map(|(i, p)| {
            let mut q = [0u64; MAX_INDEX_DIM];
            for c in 0..d {
                let w = hi[c] - lo[c];
                let t = if w > 0.0 { (p[c] - lo[c]) / w } else { 0.0 };
                q[c] = (t * levels).clamp(0.0, levels) as u64;
            }
            let mut key = 0u64;
            for b in (0..bits).rev() {
                for qc in &q[..d] {
                    key = (key << 1) | ((qc >> b) & 1);
                }
            }
            (key, i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}
