//! The collapse count of the chain filters (batch and live): an
//! observation far in the tail of the belief counts, a healthy run does
//! not.

use crate::belief::Gaussian;
use crate::chain::snapshot::{encode, SnapshotMeta};
use crate::chain::{Chain, ChainConfig, Sampler, TimeEqualized};
use crate::filter::chain_filter::ChainFilter;
use crate::filter::ekf::{Ekf, EkfConfig};
use crate::filter::live_chain::LiveChainFilter;
use crate::filter::BayesFilter;
use crate::model::linear::LinearSde;
use crate::model::{simulate_observation, Bounds, Measurement};
use nalgebra::DMatrix;
use std::time::Duration;

/// dx = A x dt + 0.5 dw, y = x + 0.2 v on [−2.5, 2.5]².
fn ou2() -> LinearSde {
    LinearSde::new(
        "ou2",
        DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.5, -1.0]),
        DMatrix::zeros(2, 0),
        DMatrix::from_row_slice(2, 2, &[0.5, 0.0, 0.0, 0.5]),
        DMatrix::identity(2, 2),
        vec![0.2, 0.2],
        Bounds::new_box(&[-2.5, -2.5], &[2.5, 2.5]).unwrap(),
    )
}

const DT: f64 = 0.05;

fn prior() -> Gaussian {
    Gaussian::diagonal(&[0.3, -0.2], &[0.3, 0.3])
}

fn chain(n: usize) -> Chain {
    let m = ou2();
    let mut c = Chain::new(&m, ChainConfig::moment_matched(2)).unwrap();
    let mut t = vec![];
    c.grow(
        &m,
        &Sampler::Uniform,
        n,
        &mut crate::rng::stream(5, 1),
        &mut t,
    )
    .unwrap();
    c
}

/// 40 steps on the model's own record (the update keeps ρ ≈ 0.3 of the
/// support: prior std ≈ obs σ), then an observation 2 away from a belief
/// of std ≈ 0.15 (ρ ~ 10⁻⁵): exactly one collapse.
fn healthy_then_tail(f: &mut dyn BayesFilter) -> (u64, u64) {
    let m = ou2();
    let mut rng = crate::rng::stream(8, 0);
    let mut x = [0.3, -0.2];
    let mut t = 0.0;
    for k in 1..=40 {
        t = k as f64 * DT;
        crate::model::discrete::em_integrate(&m, &mut x, &[], DT, 1e-3, &mut rng);
        let mut y = [0.0; 2];
        simulate_observation(&m, &x, &mut rng, &mut y);
        f.predict(t, &[]).unwrap();
        f.update(&Measurement::full(&y)).unwrap();
    }
    let healthy = f.ess_collapses().unwrap();
    f.predict(t + DT, &[]).unwrap();
    let b = f.belief();
    let y = [b.mean[0] + 2.0, b.mean[1] - 2.0];
    // The chain recovers (a flat-ish posterior on the states nearest y).
    let _ = f.update(&Measurement::full(&y));
    (healthy, f.ess_collapses().unwrap())
}

#[test]
fn batch_chain_filter_counts_a_tail_observation_only() {
    let mut cf = ChainFilter::new(ou2(), chain(1500), DT).unwrap();
    cf.reset(0.0, &prior());
    let (healthy, after) = healthy_then_tail(&mut cf);
    assert_eq!(healthy, 0);
    assert_eq!(after, 1);
    assert_eq!(cf.collapses(), 1);
}

#[test]
fn live_chain_filter_counts_a_tail_observation_only() {
    let m = ou2();
    let mut c = chain(1500);
    let mut eq = TimeEqualized::new(DT).unwrap();
    eq.fit(c.holding());
    let meta = SnapshotMeta {
        version: 1,
        lineage: 3,
        t_pub_ns: 0,
    };
    let snap = encode(&mut c, eq.delta(), meta);
    let ekf = Ekf::new(m.clone(), &EkfConfig::default(), &prior(), 0.0).unwrap();
    let mut lf: LiveChainFilter<LinearSde, Vec<u64>> =
        LiveChainFilter::new(m, Box::new(ekf), 5000, &prior(), 0.0);
    lf.offer(snap).unwrap();
    lf.advance(Duration::from_secs(5)).unwrap().unwrap();
    let (healthy, after) = healthy_then_tail(&mut lf);
    assert_eq!(healthy, 0);
    assert_eq!(after, 1);
    assert_eq!(lf.collapses(), 1);
    // With f = 0 only refused or re-spread updates would count.
    lf.set_collapse_fraction(0.0);
    let b = lf.belief();
    let y = [b.mean[0] - 2.0, b.mean[1] + 2.0];
    lf.predict(lf.time() + DT, &[]).unwrap();
    let _ = lf.update(&Measurement::full(&y));
    assert_eq!(lf.collapses(), 1 + lf.respreads());
}
