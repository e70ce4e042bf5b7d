//! The k-d tree with reverse queries against brute force.

use super::*;
use crate::rng::stream;
use rand::RngExt;

fn brute(pts: &[f64], d: usize, q: &[f64], skip: u32) -> Vec<(u32, f64)> {
    let mut v: Vec<(u32, f64)> = pts
        .chunks_exact(d)
        .enumerate()
        .filter(|(i, _)| *i as u32 != skip)
        .map(|(i, p)| {
            (
                i as u32,
                p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum(),
            )
        })
        .collect();
    v.sort_by(|a, b| a.1.total_cmp(&b.1));
    v
}

/// k-NN lists kept by reverse queries under insertion equal brute-force
/// k-NN sets, and `nearest` equals brute force, for bulk-built and
/// incrementally built trees (incl. a grid with many equal coordinates).
/// About 95 lines: one scenario (bulk and incremental trees on the same
/// points, then the grid) checked step by step against brute force.
#[test]
fn nearest_and_reverse_lists_match_brute_force() {
    let mut rng = stream(11, 0);
    for (d, grid) in [
        (1usize, false),
        (2, false),
        (4, false),
        (2, true),
        (9, false),
    ] {
        let k = 6;
        let n0 = 300;
        let n = 900;
        let mut pts: Vec<f64> = (0..n * d)
            .map(|_| {
                let v: f64 = rng.random_range(-1.0..1.0);
                if grid {
                    (v * 8.0).round() / 8.0
                } else {
                    v
                }
            })
            .collect();
        if grid {
            // Distinct points only (lists of equal points tie).
            pts.truncate(n0 * d);
            let mut extra = vec![];
            for i in 0..40 {
                for j in 0..15 {
                    extra.extend_from_slice(&[i as f64 * 0.05 + 2.0, j as f64 * 0.07]);
                }
            }
            pts.extend(extra);
        }
        let n = pts.len() / d;
        let mut t = KnnTree::from_points(d, &pts[..n0 * d]);
        let mut lists: Vec<Vec<(u32, f64)>> = vec![];
        let mut out = vec![];
        for i in 0..n0 {
            t.nearest(&pts[i * d..(i + 1) * d], k, i as u32, &mut out);
            t.set_bound(i as u32, out[k - 1].1);
            lists.push(out.clone());
        }
        for i in n0..n {
            let q = &pts[i * d..(i + 1) * d];
            t.insert(q, i as u32);
            let mut two = vec![];
            t.nearest(q, k, i as u32, &mut two);
            let both = i % 2 == 0;
            lists.push(two.clone());
            let mut visit = |j: u32, d2: f64, b: f64| {
                if j as usize == i {
                    return b;
                }
                let l = &mut lists[j as usize];
                assert_eq!(b, l[k - 1].1);
                l.pop();
                let p = l.partition_point(|e| e.1 <= d2);
                l.insert(p, (i as u32, d2));
                l[k - 1].1
            };
            if both {
                // One traversal: i's own bound is still 0.
                t.nearest_and_reverse(q, k, i as u32, &mut out, &mut visit);
                assert_eq!(out, two);
            } else {
                t.set_bound(i as u32, two[k - 1].1);
                t.reverse(q, &mut visit);
            }
            t.set_bound(i as u32, two[k - 1].1);
            if i % 97 == 0 || i == n - 1 {
                let pts_now = &pts[..(i + 1) * d];
                for j in 0..=i {
                    let want = brute(pts_now, d, &pts[j * d..(j + 1) * d], j as u32);
                    let mut w: Vec<u32> = want[..k].iter().map(|e| e.0).collect();
                    let mut g: Vec<u32> = lists[j].iter().map(|e| e.0).collect();
                    w.sort_unstable();
                    g.sort_unstable();
                    if !grid {
                        assert_eq!(g, w, "d {d} list {j} at n {i}");
                    }
                    assert_eq!(lists[j][k - 1].1, want[k - 1].1, "d {d} k-th of {j}");
                    assert_eq!(t.bound(j as u32), Some(want[k - 1].1));
                }
                let q: Vec<f64> = (0..d).map(|_| rng.random_range(-1.2..1.2)).collect();
                t.nearest(&q, 9, u32::MAX, &mut out);
                let want = brute(pts_now, d, &q, u32::MAX);
                let g: Vec<f64> = out.iter().map(|e| e.1).collect();
                let w: Vec<f64> = want[..9].iter().map(|e| e.1).collect();
                assert_eq!(g, w, "d {d}");
            }
        }
        assert_eq!(t.len(), n);
    }
}
