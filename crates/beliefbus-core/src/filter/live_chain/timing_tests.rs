//! Time per filter step (predict + update) of the live and the batch chain
//! filter on the same 2-D chain and observation record. Ignored by default
//! (a measurement, not a check): `cargo test -p beliefbus-core --release
//! --lib step_timing -- --ignored --nocapture`.

use std::time::{Duration, Instant};

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

#[test]
#[ignore]
fn step_timing() {
    let m = LinearSde::new(
        "ctl2",
        DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.5, -1.0]),
        DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
        DMatrix::from_row_slice(2, 2, &[0.5, 0.0, 0.0, 0.5]),
        DMatrix::identity(2, 2),
        vec![0.2, 0.2],
        Bounds::new_box(&[-2.5, -2.5], &[2.5, 2.5]).unwrap(),
    );
    let dt = 0.05;
    let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
    let mut c = Chain::new(&m, ChainConfig::moment_matched(2)).unwrap();
    c.grow(
        &m,
        &Sampler::Uniform,
        5000,
        &mut crate::rng::stream(3, 1),
        &mut vec![],
    )
    .unwrap();
    let mut eq = TimeEqualized::new(dt).unwrap();
    eq.fit(c.holding());
    let meta = SnapshotMeta {
        version: 1,
        lineage: 1,
        t_pub_ns: 0,
    };
    let snap = encode(&mut c, eq.delta(), meta);
    let steps = 400;
    let mut rng = crate::rng::stream(3, 0);
    let mut x = [0.8, -0.4];
    let mut ys = vec![];
    for _ in 0..steps {
        crate::model::discrete::em_integrate(&m, &mut x, &[0.0], dt, 1e-3, &mut rng);
        let mut y = [0.0; 2];
        simulate_observation(&m, &x, &mut rng, &mut y);
        ys.push(y);
    }
    let time = |f: &mut dyn BayesFilter, u: f64| {
        let t0 = Instant::now();
        let mut s = 0.0;
        for (k, y) in ys.iter().enumerate() {
            f.predict((k + 1) as f64 * dt, &[u]).unwrap();
            f.update(&Measurement::full(y)).unwrap();
            s += f.belief().mean[0];
        }
        (t0.elapsed().as_nanos() as f64 / steps as f64, s)
    };
    for u in [0.0, 1.5] {
        let ekf = Ekf::new(m.clone(), &EkfConfig::default(), &prior, 0.0).unwrap();
        let mut lf: LiveChainFilter<LinearSde, Vec<u64>> =
            LiveChainFilter::new(m.clone(), Box::new(ekf), 6000, &prior, 0.0);
        lf.offer(snap.clone()).unwrap();
        lf.advance(Duration::from_secs(10)).unwrap().unwrap();
        let (live_ns, ls) = time(&mut lf, u);
        let mut off = ChainFilter::new(m.clone(), c.clone(), dt).unwrap();
        off.reset(0.0, &prior);
        let (batch_ns, bs) = time(&mut off, u);
        eprintln!(
            "u = {u}: live {live_ns:.0} ns/step (Σx̂₀ {ls:.12}), batch {batch_ns:.0} ns/step (Σx̂₀ {bs:.12}), 5000 states"
        );
    }
}
