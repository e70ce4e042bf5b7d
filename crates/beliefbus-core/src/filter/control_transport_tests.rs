//! The control transport's mean jump and its rates carried across versions.

use super::*;
use crate::chain::snapshot::{encode, SnapshotMeta};
use crate::chain::{Chain, ChainConfig, Sampler};
use crate::model::linear::LinearSde;
use crate::model::Bounds;
use nalgebra::DMatrix;

/// The 2-D model of these tests: dx = (−x + u) dt + 0.5 dw, observed
/// y = x with noise sd 0.2, on [−3, 3]².
fn ou2(name: &str) -> LinearSde {
    LinearSde::new(
        name,
        DMatrix::from_row_slice(2, 2, &[-1.0, 0.0, 0.0, -1.0]),
        DMatrix::identity(2, 2),
        DMatrix::identity(2, 2) * 0.5,
        DMatrix::identity(2, 2),
        vec![0.2, 0.2],
        Bounds::new_box(&[-3.0, -3.0], &[3.0, 3.0]).unwrap(),
    )
}

/// Pure transport of a mass function away from the chain's border:
/// the mean moves by exactly v·h (first moment of (1) for any v), mass
/// is conserved, and the added spread is numerical diffusion of the
/// order of |v| h times the jump length.
#[test]
fn the_mean_moves_by_exactly_v_h_for_any_control_direction() {
    let m = ou2("t2");
    let mut c = Chain::new(&m, ChainConfig::moment_matched(2)).unwrap();
    c.grow(
        &m,
        &Sampler::Uniform,
        3000,
        &mut crate::rng::stream(9, 1),
        &mut vec![],
    )
    .unwrap();
    let meta = SnapshotMeta {
        version: 1,
        lineage: 1,
        t_pub_ns: 0,
    };
    let words = encode(&mut c, 0.01, meta);
    let view = SnapshotView::parse(&words).unwrap();
    let n = view.len();
    let mean = |phi: &[f64]| {
        let mut a = [0.0; 2];
        for (i, w) in phi.iter().enumerate() {
            for k in 0..2 {
                a[k] += w * view.state(i)[k];
            }
        }
        a
    };
    for v in [[1.5, 0.0], [0.0, -2.5], [2.0, 1.0], [-0.7, -3.0]] {
        let mut tr = ControlTransport::new(2, n);
        let mut phi: Vec<f64> = (0..n)
            .map(|i| {
                let z = view.state(i);
                (-(z[0] * z[0] + z[1] * z[1]) / (2.0 * 0.3f64.powi(2))).exp()
            })
            .collect();
        let s: f64 = phi.iter().sum();
        phi.iter_mut().for_each(|p| *p /= s);
        let m0 = mean(&phi);
        let mut tmp = vec![];
        let h = 0.02;
        for _ in 0..20 {
            assert!(tr.apply(&view, &v, h, 0.0, &mut phi, &mut tmp));
        }
        let m1 = mean(&phi);
        let mass: f64 = phi.iter().sum();
        assert!((mass - 1.0).abs() < 1e-12, "mass {mass}");
        // Exact where ±e_i is in the cone of C(z); the few states where
        // it is not (sparse neighbourhoods) are least-squares.
        assert!(tr.partial * 10 < tr.built, "{} of {}", tr.partial, tr.built);
        let scale = (v[0] * v[0] + v[1] * v[1]).sqrt() * 0.4;
        for k in 0..2 {
            let moved = m1[k] - m0[k];
            assert!(
                (moved - v[k] * 0.4).abs() < 0.03 * scale,
                "v {v:?}: moved {moved} want {} (partial {})",
                v[k] * 0.4,
                tr.partial
            );
        }
    }
}

/// Rates prepared for a new version by reuse (old rate sets whose
/// targets survive, translated by id) and solving (new states, lost
/// targets) still move the mean by exactly v·h, and only the new or
/// broken rate sets are solved.
#[test]
fn rates_carried_to_a_new_version_by_id_stay_exact() {
    let m = ou2("t2r");
    let mut c = Chain::new(&m, ChainConfig::moment_matched(2)).unwrap();
    // The chain of the test above (3000 uniform states, same stream),
    // where one-hop rate sets are exact away from the border.
    let mut rng = crate::rng::stream(9, 1);
    c.grow(&m, &Sampler::Uniform, 3000, &mut rng, &mut vec![])
        .unwrap();
    let meta = |version| SnapshotMeta {
        version,
        lineage: 1,
        t_pub_ns: 0,
    };
    let w1 = encode(&mut c, 0.01, meta(1));
    // Version 2: 300 more states, then the states with x₀ > 2.5 retired.
    c.grow(&m, &Sampler::Uniform, 300, &mut rng, &mut vec![])
        .unwrap();
    let keep: Vec<bool> = (0..c.len()).map(|i| c.state(i)[0] <= 2.5).collect();
    let mut c2 = crate::chain::retire::retire(&m, &mut c, &keep, &mut vec![]).unwrap();
    let w2 = encode(&mut c2, 0.01, meta(2));
    let (v1, v2) = (
        SnapshotView::parse(&w1).unwrap(),
        SnapshotView::parse(&w2).unwrap(),
    );
    let slots = [0, 1, 2, 3];
    let mut t1 = ControlTransport::new(2, v1.len());
    for z in 0..v1.len() {
        t1.prepare_state(&v1, z, &slots, None);
    }
    assert_eq!(t1.built as usize, 4 * v1.len());
    let (mut o2n, mut n2o) = (vec![u32::MAX; v1.len()], vec![u32::MAX; v2.len()]);
    let (mut i, mut j) = (0, 0);
    while i < v1.len() && j < v2.len() {
        match v1.ids[i].cmp(&v2.ids[j]) {
            std::cmp::Ordering::Equal => {
                o2n[i] = j as u32;
                n2o[j] = i as u32;
                i += 1;
                j += 1;
            }
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
        }
    }
    let mut t2 = ControlTransport::new(2, v2.len());
    let mut solved = 0;
    for z in 0..v2.len() {
        let old = (n2o[z] != u32::MAX).then_some((&t1, n2o[z] as usize, &o2n[..]));
        solved += t2.prepare_state(&v2, z, &slots, old);
    }
    let new_states = n2o.iter().filter(|&&o| o == u32::MAX).count();
    assert!(new_states >= 250, "{new_states}");
    assert!(
        solved >= 4 * new_states && solved < 4 * v2.len() / 2,
        "solved {solved} of {} (new states {new_states})",
        4 * v2.len()
    );
    let n = v2.len();
    let mean = |phi: &[f64]| {
        let mut a = [0.0; 2];
        for (i, w) in phi.iter().enumerate() {
            for k in 0..2 {
                a[k] += w * v2.state(i)[k];
            }
        }
        a
    };
    let built = t2.built;
    for v in [[1.5, 0.0], [-0.7, -2.0]] {
        let mut phi: Vec<f64> = (0..n)
            .map(|i| {
                let z = v2.state(i);
                (-(z[0] * z[0] + z[1] * z[1]) / (2.0 * 0.3f64.powi(2))).exp()
            })
            .collect();
        let s: f64 = phi.iter().sum();
        phi.iter_mut().for_each(|p| *p /= s);
        let m0 = mean(&phi);
        let mut tmp = vec![];
        for _ in 0..20 {
            assert!(t2.apply(&v2, &v, 0.02, 0.0, &mut phi, &mut tmp));
        }
        let m1 = mean(&phi);
        let scale = (v[0] * v[0] + v[1] * v[1]).sqrt() * 0.4;
        for k in 0..2 {
            let moved = m1[k] - m0[k];
            assert!(
                (moved - v[k] * 0.4).abs() < 0.03 * scale,
                "v {v:?}: moved {moved} want {}",
                v[k] * 0.4
            );
        }
    }
    // Everything the transport needed was prepared.
    assert_eq!(t2.built, built);
}
