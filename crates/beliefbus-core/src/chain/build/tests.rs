//! Rows of batch and incremental construction against the ConnectState
//! formulas and a fresh k-d tree query; holding times under reconnection.

use super::*;
use crate::chain::sample::Sampler;
use crate::model::linear::LinearSde;
use crate::model::Bounds;
use nalgebra::DMatrix;

pub(crate) fn ou2(a1: f64, a2: f64, s: f64, half: f64) -> LinearSde {
    LinearSde::new(
        "ou2",
        DMatrix::from_row_slice(2, 2, &[-a1, 0.0, 0.0, -a2]),
        DMatrix::zeros(2, 0),
        DMatrix::from_row_slice(2, 2, &[s, 0.0, 0.0, s]),
        DMatrix::identity(2, 2),
        vec![0.1, 0.1],
        Bounds::new_box(&[-half, -half], &[half, half]).unwrap(),
    )
}

#[test]
fn incremental_and_batch_rows_are_distributions_and_views_round_trip() {
    let m = ou2(0.5, 1.0, 0.3, 1.0);
    let mut rng = crate::rng::stream(1, 0);
    for cfg in [
        ChainConfig::gaussian(2),
        ChainConfig::moment_matched(2),
        ChainConfig::gaussian(2).with_near(NearRule::Radius { gamma: 1.5 }),
    ] {
        let mut c = Chain::new(&m, cfg.clone()).unwrap();
        let mut touched = vec![];
        c.grow(&m, &Sampler::Uniform, 400, &mut rng, &mut touched)
            .unwrap();
        assert_eq!(c.len(), 400);
        assert!(touched.len() > 400);
        let view = c.view();
        view.validate().unwrap();
        // ids stable and unique
        assert!(view.ids.windows(2).all(|w| w[0] < w[1]));
        let c2 = Chain::from_view(&m, cfg.clone(), &view).unwrap();
        assert_eq!(c2.len(), 400);
        assert_eq!(c2.row(17), c.row(17));
        let pts = Sampler::Uniform.sample_many(m.bounds(), 300, &mut rng);
        let mut b = Chain::batch(&m, cfg, &pts).unwrap();
        b.view().validate().unwrap();
        // batch with k-NN: out-degree = k(n) unless zero-probability
        // entries were dropped.
        assert!(b.mean_out_degree() > 3.0);
    }
}

#[test]
fn near_lists_give_the_rows_of_a_fresh_query() {
    // Reconnection from the kept k-NN lists must give exactly what
    // ConnectState with a k-d tree query gives (Alg. 2.3), for every
    // reconnected slot, across growth of k = ⌈c log n⌉.
    let m = ou2(0.5, 1.0, 0.3, 1.0);
    let mut rng = crate::rng::stream(9, 0);
    for cfg in [ChainConfig::gaussian(2), ChainConfig::moment_matched(2)] {
        let pts = Sampler::Uniform.sample_many(m.bounds(), 200, &mut rng);
        let mut c = Chain::batch(&m, cfg, &pts).unwrap();
        let mut rec = vec![];
        let mut x = [0.0; 2];
        let mut checked = 0;
        let mut from_lists = 0;
        for step in 0..1500 {
            Sampler::Uniform.sample(m.bounds(), &mut rng, &mut x);
            let before = c.stats().connects;
            c.add_state(&m, &x, &mut rec).unwrap();
            assert_eq!(c.stats().connects - before, rec.len() as u64);
            if step % 50 != 0 {
                continue;
            }
            let mut fresh = c.clone();
            for &j in &rec {
                let j = j as usize;
                from_lists += (c.meta[j].near_k == c.knn_k(c.len()) as u32) as usize;
                fresh.reconnect(j).unwrap();
                let (ca, pa) = c.row(j);
                let (cb, pb) = fresh.row(j);
                assert_eq!(ca, cb, "slot {j}");
                for (a, b) in pa.iter().zip(pb) {
                    assert!((a - b).abs() <= 1e-12 * b.max(1e-300), "{a} vs {b}");
                }
                let (ha, hb) = (c.holding()[j], fresh.holding()[j]);
                assert!((ha - hb).abs() <= 1e-12 * hb, "{ha} vs {hb}");
                assert_eq!(c.near_count()[j], fresh.near_count()[j]);
                checked += 1;
            }
            // every list of the current k is the exact k-NN set
            let k = c.knn_k(c.len());
            for i in 0..c.len() {
                if c.meta[i].near_k as usize != k {
                    continue;
                }
                let mut d2: Vec<(f64, u32)> = (0..c.len())
                    .filter(|&j| j != i)
                    .map(|j| {
                        let s = (0..2).map(|a| (c.state(j)[a] - c.state(i)[a]).powi(2));
                        (s.sum(), j as u32)
                    })
                    .collect();
                d2.sort_by(|a, b| a.0.total_cmp(&b.0));
                let mut want: Vec<u32> = d2[..k].iter().map(|e| e.1).collect();
                let mut got = c.near_lists.row(i).0.to_vec();
                want.sort_unstable();
                got.sort_unstable();
                assert_eq!(got, want, "list of slot {i}");
                // the reverse-query bound is the list's k-th distance
                let kth = c.near_lists.row(i).1[k - 1];
                assert_eq!(c.rtree.as_ref().unwrap().bound(i as u32), Some(kth));
            }
        }
        assert!(
            checked > 200 && from_lists > checked / 2,
            "{checked} {from_lists}"
        );
    }
}

/// ConnectState (Alg. 2.2) written out from the formulas, independent
/// of the chain's caches, lists and trees: brute-force k nearest (ties
/// by slot), r their largest distance, f and F Fᵀ from the model,
/// Δt = r²/(‖FFᵀ‖₂ + r‖f‖), p ∝ exp(−½ yᵀ(FFᵀΔt)⁻¹y), y = Δz − fΔt
/// (nalgebra inverse and eigenvalues), p < MIN_PROB dropped and the rest
/// renormalised. Returns the row sorted by column, and Δt.
fn reference_row<M: SdeModel>(
    m: &M,
    states: &[f64],
    d: usize,
    i: usize,
    k: usize,
) -> (Vec<u32>, Vec<f64>, f64) {
    use nalgebra::{DMatrix, DVector};
    let x = &states[i * d..(i + 1) * d];
    let mut near: Vec<(f64, u32)> = states
        .chunks_exact(d)
        .enumerate()
        .filter(|(j, _)| *j != i)
        .map(|(j, p)| {
            (
                p.iter().zip(x).map(|(a, b)| (a - b) * (a - b)).sum(),
                j as u32,
            )
        })
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    near.truncate(k);
    let r = near.last().unwrap().0.sqrt();
    let dims = m.dims();
    let mut f = vec![0.0; d];
    m.drift(x, &vec![0.0; dims.control], &mut f);
    let mut bigf = vec![0.0; d * dims.noise];
    m.diffusion(x, &mut bigf);
    let bf = DMatrix::from_column_slice(d, dims.noise, &bigf);
    let ff = &bf * bf.transpose();
    let ff_norm = ff
        .clone()
        .symmetric_eigenvalues()
        .iter()
        .fold(0.0f64, |a, v| a.max(v.abs()));
    let f = DVector::from_vec(f);
    let dt = r * r / (ff_norm + r * f.norm());
    let prec = (ff * dt).try_inverse().unwrap();
    let q: Vec<f64> = near
        .iter()
        .map(|&(_, j)| {
            let z = &states[j as usize * d..(j as usize + 1) * d];
            let y = DVector::from_fn(d, |c, _| z[c] - x[c]) - &f * dt;
            0.5 * (y.transpose() * &prec * &y)[(0, 0)]
        })
        .collect();
    let qmin = q.iter().copied().fold(f64::INFINITY, f64::min);
    let s: f64 = q.iter().map(|v| (qmin - v).exp()).sum();
    let mut row: Vec<(u32, f64)> = near
        .iter()
        .zip(&q)
        .map(|(&(_, j), v)| (j, (qmin - v).exp() / s))
        .filter(|e| e.1 >= MIN_PROB)
        .collect();
    let kept: f64 = row.iter().map(|e| e.1).sum();
    row.sort_by_key(|e| e.0);
    (
        row.iter().map(|e| e.0).collect(),
        row.iter().map(|e| e.1 / kept).collect(),
        dt,
    )
}

/// Chain row `i` sorted by column.
fn sorted_row(c: &Chain, i: usize) -> (Vec<u32>, Vec<f64>) {
    let (cols, probs) = c.row(i);
    let mut e: Vec<(u32, f64)> = cols.iter().copied().zip(probs.iter().copied()).collect();
    e.sort_by_key(|e| e.0);
    (
        e.iter().map(|e| e.0).collect(),
        e.iter().map(|e| e.1).collect(),
    )
}

fn assert_row_matches<M: SdeModel>(c: &Chain, m: &M, i: usize, k: usize) {
    let d = c.dim();
    let (rc, rp, rdt) = reference_row(m, c.states(), d, i, k);
    let (cc, cp) = sorted_row(c, i);
    assert_eq!(cc, rc, "columns of slot {i} at n {}", c.len());
    for (a, b) in cp.iter().zip(&rp) {
        // exp(−q) with q up to ~30 for kept entries: rounding of q
        // (and of L⁻¹ vs the inverse) is ≪ 1e-9 relative.
        assert!((a - b).abs() <= 1e-9 * b, "slot {i}: {a} vs {b}");
    }
    let h = c.holding()[i];
    assert!(
        (h - rdt).abs() <= 1e-12 * rdt,
        "Δt of slot {i}: {h} vs {rdt}"
    );
}

#[test]
fn batch_and_incremental_rows_equal_the_connect_state_formulas() {
    // Gaussian kernel, k-NN rule, ship (d = 4) and OU (d = 2): every row
    // of a batch chain, and every row (re)connected by each incremental
    // insertion (Alg. 2.3: the new state and all of Near(z)), equal
    // ConnectState written out from the formulas on brute-force k-NN.
    use crate::model::ship::{Ship, ShipParams};
    let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
    let ou = ou2(0.5, 1.0, 0.3, 1.0);
    fn check<M: SdeModel>(m: &M, seed: u64) {
        let d = m.dims().state;
        let mut rng = crate::rng::stream(seed, 0);
        let pts = Sampler::Uniform.sample_many(m.bounds(), 300, &mut rng);
        let mut c = Chain::batch(m, ChainConfig::gaussian(d), &pts).unwrap();
        let k = c.knn_k(c.len());
        for i in 0..c.len() {
            assert_row_matches(&c, m, i, k);
        }
        let mut rec = vec![];
        let mut x = [0.0; MAX_STATE];
        let mut checked = 0;
        for _ in 0..400 {
            Sampler::Uniform.sample(m.bounds(), &mut rng, &mut x[..d]);
            c.add_state(m, &x[..d], &mut rec).unwrap();
            let k = c.knn_k(c.len());
            for &j in &rec {
                assert_row_matches(&c, m, j as usize, k);
                checked += 1;
            }
        }
        assert!(checked > 400 * k / 2, "{checked}");
    }
    check(&ship, 21);
    check(&ou, 22);
}

#[test]
fn reconnection_shrinks_holding_times() {
    // Alg. 2.3: a state's Δt is recomputed with the current n whenever a
    // new sample lands near it, so Δt of the first states decreases.
    let m = ou2(0.5, 1.0, 0.3, 1.0);
    let mut rng = crate::rng::stream(4, 0);
    let mut c = Chain::new(&m, ChainConfig::gaussian(2)).unwrap();
    let mut t = vec![];
    c.grow(&m, &Sampler::Uniform, 50, &mut rng, &mut t).unwrap();
    let early: f64 = c.holding()[..10].iter().sum();
    c.grow(&m, &Sampler::Uniform, 5000, &mut rng, &mut t)
        .unwrap();
    let late: f64 = c.holding()[..10].iter().sum();
    assert!(late < 0.3 * early, "{late} vs {early}");
}

#[test]
fn a_build_in_slices_is_the_batch_chain() {
    // Alg. 2.1 connects every state with the final n, so stopping between
    // units of work changes nothing: one unit per call gives the rows,
    // holding times and radii of the batch chain bit for bit.
    let m = ou2(0.5, 1.0, 0.3, 1.0);
    let mut rng = crate::rng::stream(4, 0);
    for cfg in [ChainConfig::gaussian(2), ChainConfig::moment_matched(2)] {
        let pts = Sampler::Uniform.sample_many(m.bounds(), 300, &mut rng);
        let mut whole = Chain::batch(&m, cfg.clone(), &pts).unwrap();
        let mut b = BatchBuild::new(&m, cfg, pts.clone()).unwrap();
        let (_, total) = b.progress();
        assert_eq!(total, 2 * 300 + 2);
        let mut calls = 0;
        let mut last = 0;
        while !b.run(&m, || false).unwrap() {
            calls += 1;
            let (done, _) = b.progress();
            assert_eq!(done, last + 1, "one unit per call");
            last = done;
        }
        assert_eq!(calls + 1, total);
        assert_eq!(b.progress(), (total, total));
        let mut sliced = b.finish().unwrap();
        assert_eq!(sliced.holding(), whole.holding());
        assert_eq!(sliced.radius(), whole.radius());
        let (vs, vw) = (sliced.view(), whole.view());
        assert_eq!(
            (vs.row_offsets, vs.cols, vs.probs),
            (vw.row_offsets, vw.cols, vw.probs)
        );
    }
}

#[test]
fn an_unfinished_build_is_not_a_chain() {
    let m = ou2(0.5, 1.0, 0.3, 1.0);
    let pts = Sampler::Uniform.sample_many(m.bounds(), 50, &mut crate::rng::stream(5, 0));
    let mut b = BatchBuild::new(&m, ChainConfig::gaussian(2), pts).unwrap();
    let mut budget = 60;
    assert!(!b
        .run(&m, || {
            budget -= 1;
            budget > 0
        })
        .unwrap());
    assert_eq!(b.progress().0, 60);
    assert!(!b.is_done());
    assert!(matches!(b.finish(), Err(ChainError::State(_))));
    // Points of the wrong length are refused with a typed error.
    assert!(matches!(
        BatchBuild::new(&m, ChainConfig::gaussian(2), vec![0.0; 3]),
        Err(ChainError::State(_))
    ));
}
