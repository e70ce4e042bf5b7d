//! The live chain filter against the batch filter on one snapshot, the
//! controlled Kalman filter, version remaps and chunked preparation.

use super::*;
use crate::chain::snapshot::{encode, SnapshotMeta};
use crate::chain::snapshot::{SnapshotError, SnapshotView};
use crate::chain::{Chain, ChainConfig, Sampler, TimeEqualized};
use crate::filter::chain_filter::ChainFilter;
use crate::filter::ekf::{Ekf, EkfConfig};
use crate::model::linear::LinearSde;
use crate::model::{simulate_observation, Bounds};
use nalgebra::DMatrix;
use std::time::Duration;

/// dx = (A x + B u) dt + 0.5 dw, y = x + 0.2 v: constant B and F, so the
/// tilt at the belief mean is the per-state tilt of `ChainFilter`.
fn model() -> LinearSde {
    LinearSde::new(
        "ctl2",
        DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.5, -1.0]),
        DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
        DMatrix::from_row_slice(2, 2, &[0.5, 0.0, 0.0, 0.5]),
        DMatrix::identity(2, 2),
        vec![0.2, 0.2],
        Bounds::new_box(&[-2.5, -2.5], &[2.5, 2.5]).unwrap(),
    )
}

fn meta(version: u64, lineage: u64) -> SnapshotMeta {
    SnapshotMeta {
        version,
        lineage,
        t_pub_ns: 0,
    }
}

fn live(m: &LinearSde, prior: &Gaussian) -> LiveChainFilter<LinearSde, Vec<u64>> {
    let ekf = Ekf::new(m.clone(), &EkfConfig::default(), prior, 0.0).unwrap();
    LiveChainFilter::new(m.clone(), Box::new(ekf), 5000, prior, 0.0)
}

fn chain(m: &LinearSde, n: usize, seed: u64) -> Chain {
    let mut c = Chain::new(m, ChainConfig::moment_matched(2)).unwrap();
    let mut t = vec![];
    c.grow(
        m,
        &Sampler::Uniform,
        n,
        &mut crate::rng::stream(seed, 1),
        &mut t,
    )
    .unwrap();
    c
}

#[test]
fn on_one_snapshot_it_is_the_offline_chain_filter_and_its_control_helps_against_kalman() {
    let m = model();
    let dt = 0.05;
    let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
    let mut c = chain(&m, 1500, 3);
    let mut eq = TimeEqualized::new(dt).unwrap();
    eq.fit(c.holding());
    let snap = encode(&mut c, eq.delta(), meta(1, 7));
    let mut off = ChainFilter::new(m.clone(), c, dt).unwrap();
    off.reset(0.0, &prior);
    let mut lf = live(&m, &prior);
    lf.offer(snap).unwrap();
    let info = lf.advance(Duration::from_secs(1)).unwrap().unwrap();
    assert!(info.from_gaussian && info.mass_lost == 0.0);
    assert_eq!(info.states, 1500);
    let mut kf = crate::filter::kalman::Kalman::new(m.clone(), &prior, 0.0).unwrap();
    let mut k0 = crate::filter::kalman::Kalman::new(m.clone(), &prior, 0.0).unwrap();
    let mut rng = crate::rng::stream(3, 0);
    let mut x = [0.8, -0.4];
    let mut worst: f64 = 0.0;
    let (mut gap, mut gap0) = (0.0f64, 0.0f64);
    for k in 1..=60 {
        let t = k as f64 * dt;
        let u = [if k > 20 { 1.5 } else { 0.0 }];
        crate::model::discrete::em_integrate(&m, &mut x, &u, dt, 1e-3, &mut rng);
        let mut y = [0.0; 2];
        simulate_observation(&m, &x, &mut rng, &mut y);
        lf.predict(t, &u).unwrap();
        kf.predict(t, &u).unwrap();
        k0.predict(t, &[0.0]).unwrap();
        let b = lf.update(&Measurement::full(&y)).unwrap();
        kf.update(&Measurement::full(&y)).unwrap();
        k0.update(&Measurement::full(&y)).unwrap();
        if k <= 20 {
            // u = u₀: the same recursion as the offline filter.
            off.predict(t, &u).unwrap();
            let a = off.update(&Measurement::full(&y)).unwrap();
            assert!((a.log_evidence - b.log_evidence).abs() < 1e-6);
            let (ga, gb) = (off.belief(), lf.belief());
            for i in 0..2 {
                worst = worst.max((ga.mean[i] - gb.mean[i]).abs());
            }
            for i in 0..4 {
                worst = worst.max((ga.cov[i] - gb.cov[i]).abs());
            }
        } else {
            let (g, gk, g0) = (lf.belief(), kf.belief(), k0.belief());
            gap = gap.max((g.mean[1] - gk.mean[1]).abs());
            gap0 = gap0.max((g0.mean[1] - gk.mean[1]).abs());
        }
    }
    assert!(worst < 1e-9, "live vs offline: {worst}");
    // With u = 1.5 held (mild: B u δ well inside the Near radius) the
    // control's transport must bring the estimate closer to the
    // controlled Kalman filter than ignoring the control does. Measured:
    // 0.094 vs 0.104 (the former exponential tilt: 0.072 here, but 1.39
    // Kalman std off under the strong control of the next test, where
    // the transport stays within 1.25 std). The chain's own error with
    // both states observed dominates this mild case.
    eprintln!("live chain vs Kalman {gap:.4}, uncontrolled Kalman vs Kalman {gap0:.4}");
    assert!(gap0 > 0.08, "control must matter: {gap0}");
    assert!(
        gap < gap0,
        "live chain vs Kalman {gap} (uncontrolled {gap0})"
    );
}

/// Strong known control on a linear SDE: the filter's mean must follow
/// the controlled Kalman–Bucy filter (exact for this model), measured
/// as max |mean − Kalman mean| in units of Kalman's largest std, next to
/// the chain's own error without control and to a Kalman filter that
/// ignores the control. Two sensors: both states observed, and only x₁
/// (the controlled x₂ is then known through the dynamics only, so the
/// control's transport decides the estimate).
#[test]
fn under_a_strong_control_the_mean_tracks_the_controlled_kalman_filter() {
    let lin = |c: DMatrix<f64>, std: Vec<f64>| {
        LinearSde::new(
            "ctl2wide",
            DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.5, -1.0]),
            DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
            DMatrix::from_row_slice(2, 2, &[0.5, 0.0, 0.0, 0.5]),
            c,
            std,
            Bounds::new_box(&[-3.5, -3.5], &[3.5, 3.5]).unwrap(),
        )
    };
    let full = lin(DMatrix::identity(2, 2), vec![0.2, 0.2]);
    let part = lin(DMatrix::from_row_slice(1, 2, &[1.0, 0.0]), vec![0.2]);
    let dt = 0.05;
    let prior = Gaussian::diagonal(&[0.0, 0.0], &[0.3, 0.3]);
    let mut c = Chain::new(&full, ChainConfig::moment_matched(2)).unwrap();
    c.grow(
        &full,
        &Sampler::Uniform,
        2500,
        &mut crate::rng::stream(21, 1),
        &mut vec![],
    )
    .unwrap();
    let mut eq = TimeEqualized::new(dt).unwrap();
    eq.fit(c.holding());
    let snap = encode(&mut c, eq.delta(), meta(1, 7));
    // (max |Δmean| live chain vs Kalman, same for a Kalman filter that
    // ignores the control, Kalman's largest std).
    let run = |m: &LinearSde, amp: f64| {
        let ekf = Ekf::new(m.clone(), &EkfConfig::default(), &prior, 0.0).unwrap();
        let mut lf: LiveChainFilter<LinearSde, Vec<u64>> =
            LiveChainFilter::new(m.clone(), Box::new(ekf), 5000, &prior, 0.0);
        lf.offer(snap.clone()).unwrap();
        lf.advance(Duration::from_secs(1)).unwrap().unwrap();
        let mut kf = crate::filter::kalman::Kalman::new(m.clone(), &prior, 0.0).unwrap();
        let mut k0 = crate::filter::kalman::Kalman::new(m.clone(), &prior, 0.0).unwrap();
        let mut rng = crate::rng::stream(21, 0);
        let mut x = [0.0, 0.0];
        let (mut gap, mut gap0, mut sd) = (0.0f64, 0.0f64, 0.0f64);
        let mut y = vec![0.0; m.dims().obs];
        // Piecewise constant: ±amp switching every second.
        for k in 1..=120 {
            let t = k as f64 * dt;
            let u = [if (k - 1) / 20 % 2 == 0 { amp } else { -amp }];
            crate::model::discrete::em_integrate(m, &mut x, &u, dt, 1e-3, &mut rng);
            simulate_observation(m, &x, &mut rng, &mut y);
            lf.predict(t, &u).unwrap();
            kf.predict(t, &u).unwrap();
            k0.predict(t, &[0.0]).unwrap();
            lf.update(&Measurement::full(&y)).unwrap();
            kf.update(&Measurement::full(&y)).unwrap();
            k0.update(&Measurement::full(&y)).unwrap();
            let (g, gk, g0) = (lf.belief(), kf.belief(), k0.belief());
            for i in 0..2 {
                gap = gap.max((g.mean[i] - gk.mean[i]).abs());
                gap0 = gap0.max((g0.mean[i] - gk.mean[i]).abs());
                sd = sd.max(gk.cov_at(i, i).sqrt());
            }
        }
        (gap, gap0, sd)
    };
    for (name, m) in [("full", &full), ("x1 only", &part)] {
        let (floor, _, _) = run(m, 0.0);
        let (gap, gap0, sd) = run(m, 2.5);
        eprintln!(
            "{name}: live chain vs controlled Kalman max |Δmean| {gap:.4} = {:.2} std (u = 0: {floor:.4}); control ignored {gap0:.4}; Kalman std {sd:.4}",
            gap / sd
        );
        assert!(
            gap0 > sd,
            "{name}: the control must matter: {gap0} vs std {sd}"
        );
        assert!(
            gap < 1.25 * sd,
            "{name}: live chain vs Kalman {gap} (std {sd}, u = 0 {floor}, uncontrolled {gap0})"
        );
    }
}

#[test]
fn remap_keeps_mass_on_kept_ids_and_reports_what_retired_states_held() {
    let m = model();
    let prior = Gaussian::diagonal(&[0.5, 0.0], &[0.4, 0.4]);
    let mut c = chain(&m, 800, 4);
    let delta = 0.01;
    let mut lf = live(&m, &prior);
    lf.offer(encode(&mut c, delta, meta(1, 7))).unwrap();
    lf.advance(Duration::from_secs(1)).unwrap().unwrap();
    let mut rng = crate::rng::stream(4, 0);
    for k in 1..=5 {
        lf.predict(k as f64 * 0.05, &[0.0]).unwrap();
        lf.update(&Measurement::full(&[0.5, 0.1])).unwrap();
    }
    let before = lf.belief();
    // v2: 200 more states (no retirement): nothing lost, belief barely
    // moves (new states take their neighbours' density).
    let mut t = vec![];
    c.grow(&m, &Sampler::Uniform, 200, &mut rng, &mut t)
        .unwrap();
    lf.offer(encode(&mut c, delta, meta(2, 7))).unwrap();
    let info = lf.advance(Duration::from_secs(1)).unwrap().unwrap();
    assert!(!info.from_gaussian);
    assert_eq!((info.version, info.states, info.mass_lost), (2, 1000, 0.0));
    let after = lf.belief();
    for i in 0..2 {
        assert!(
            (before.mean[i] - after.mean[i]).abs() < 0.05,
            "{before:?} {after:?}"
        );
    }
    // v3: retire every state with x₀ > 0.4; the lost mass is what they held.
    let phi = lf.masses().to_vec();
    let keep: Vec<bool> = (0..c.len()).map(|i| c.state(i)[0] <= 0.4).collect();
    let expect: f64 = (0..c.len()).filter(|&i| !keep[i]).map(|i| phi[i]).sum();
    assert!(expect > 0.05, "the test must retire real mass: {expect}");
    let mut touched = vec![];
    let mut r = crate::chain::retire::retire(&m, &mut c, &keep, &mut touched).unwrap();
    lf.offer(encode(&mut r, delta, meta(3, 7))).unwrap();
    let info = lf.advance(Duration::from_secs(1)).unwrap().unwrap();
    assert!(
        (info.mass_lost - expect).abs() < 1e-12,
        "{} vs {expect}",
        info.mass_lost
    );
    assert!((lf.masses().iter().sum::<f64>() - 1.0).abs() < 1e-9);
    // A new lineage starts from the Gaussian belief.
    let g = lf.belief();
    let mut other = chain(&m, 600, 5);
    lf.offer(encode(&mut other, delta, meta(1, 8))).unwrap();
    let info = lf.advance(Duration::from_secs(1)).unwrap().unwrap();
    assert!(info.from_gaussian);
    let h = lf.belief();
    assert!((g.mean[0] - h.mean[0]).abs() < 0.1, "{g:?} {h:?}");
    assert_eq!(lf.versions(), 4);
}

#[test]
fn preparation_is_spread_over_calls_and_bad_snapshots_are_refused() {
    let m = model();
    let prior = Gaussian::diagonal(&[0.0, 0.0], &[0.5, 0.5]);
    let mut lf = live(&m, &prior);
    let mut c = chain(&m, 1200, 6);
    let snap = encode(&mut c, 0.01, meta(1, 1));
    // Before any snapshot the fallback (EKF) answers.
    lf.predict(0.01, &[0.0]).unwrap();
    lf.update(&Measurement::full(&[0.1, 0.1])).unwrap();
    assert!(lf.active_info().is_none());
    lf.offer(snap.clone()).unwrap();
    let mut calls = 0;
    loop {
        calls += 1;
        if lf.advance(Duration::ZERO).unwrap().is_some() {
            break;
        }
    }
    // Phase 1 (g(z)) in chunks of CHUNK states, phase 2 (the control's
    // transport rates) in pieces of 16.
    assert_eq!(calls, 1200usize.div_ceil(CHUNK) + 1200usize.div_ceil(16));
    assert_eq!(lf.active_info().map(|a| a.1), Some(1200));
    let mut bad = snap.clone();
    bad[0] = 0;
    assert_eq!(lf.offer(bad), Err(SnapshotError::Magic));
    let mut bad = snap;
    let n = 1200;
    // Corrupt the first incoming source index (after every f64 section
    // and the ids/offsets/cols u32 sections).
    let v = SnapshotView::parse(&bad).unwrap();
    let off = (v.in_src.as_ptr() as usize - bad.as_ptr() as usize) / 8;
    bad[off] = u64::MAX;
    lf.offer(bad).unwrap();
    assert!(matches!(
        lf.advance(Duration::from_secs(1)),
        Err(SnapshotError::Index(_))
    ));
    assert!(!lf.has_pending());
    // Still filtering on the last good version.
    assert_eq!(lf.active_info().map(|a| a.1), Some(n));
    lf.predict(0.02, &[0.0]).unwrap();
    lf.update(&Measurement::full(&[0.1, 0.1])).unwrap();
}
