//! The batch chain filter against the exact Kalman filter (control tilt,
//! convergence in n), the flush's bound, the fused update and the sparse
//! prediction.

use super::*;
use crate::chain::ChainConfig;
use crate::filter::kalman::Kalman;
use crate::filter::live_chain::mass::HALF_LOG_2PI;
use crate::model::linear::LinearSde;
use crate::model::{simulate_observation, Bounds};
use nalgebra::DMatrix;

fn ou2() -> LinearSde {
    // dx = A x dt + F dw, y = x + v, σ = 0.2 each.
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

/// RMS over steps of (mean error, cov error) of the chain filter against
/// the exact Kalman filter on the same observation record.
fn gap_to_kalman(n: usize, seed: u64) -> (f64, f64) {
    gap_to_kalman_with(n, seed, ChainConfig::moment_matched(2))
}

fn gap_to_kalman_with(n: usize, seed: u64, cfg: ChainConfig) -> (f64, f64) {
    let model = ou2();
    let dt = 0.05;
    let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
    let mut rng = crate::rng::stream(seed, 0);
    let mut kf = Kalman::new(model.clone(), &prior, 0.0).unwrap();
    let mut cf = ChainFilter::from_samples(
        model.clone(),
        cfg,
        &Sampler::Uniform,
        n,
        dt,
        &mut crate::rng::stream(seed, 1),
    )
    .unwrap();
    cf.reset(0.0, &prior);
    let mut x = [0.8, -0.4];
    let (mut em, mut ec) = (0.0, 0.0);
    let steps = 40;
    for k in 1..=steps {
        let t = k as f64 * dt;
        crate::model::discrete::em_integrate(&model, &mut x, &[], dt, 1e-3, &mut rng);
        let mut y = [0.0; 2];
        simulate_observation(&model, &x, &mut rng, &mut y);
        for f in [&mut kf as &mut dyn BayesFilter, &mut cf] {
            f.predict(t, &[]).unwrap();
            f.update(&Measurement::full(&y)).unwrap();
        }
        let (a, b) = (kf.belief(), cf.belief());
        em += (0..2).map(|i| (a.mean[i] - b.mean[i]).powi(2)).sum::<f64>();
        ec += (0..4).map(|i| (a.cov[i] - b.cov[i]).powi(2)).sum::<f64>();
    }
    ((em / steps as f64).sqrt(), (ec / steps as f64).sqrt())
}

#[test]
fn control_tilt_follows_the_controlled_kalman_answer() {
    // dx = (−x + u) dt + 0.5 dw, y = x + 0.2 v; chain built for u₀ = 0,
    // filtered with u = 1.5 held: the tilted kernel must carry the
    // control's drift (the uncontrolled answer is ≈ 1.5 away).
    let model = LinearSde::new(
        "ctl",
        DMatrix::from_element(1, 1, -1.0),
        DMatrix::from_element(1, 1, 1.0),
        DMatrix::from_element(1, 1, 0.5),
        DMatrix::from_element(1, 1, 1.0),
        vec![0.5],
        Bounds::new_box(&[-4.0], &[4.0]).unwrap(),
    );
    let dt = 0.05;
    let prior = Gaussian::diagonal(&[0.0], &[0.3]);
    let mut cf = ChainFilter::from_samples(
        model.clone(),
        ChainConfig::moment_matched(1),
        &Sampler::Uniform,
        1500,
        dt,
        &mut crate::rng::stream(3, 1),
    )
    .unwrap();
    cf.reset(0.0, &prior);
    let mut kf = Kalman::new(model.clone(), &prior, 0.0).unwrap();
    let mut k0 = Kalman::new(model.clone(), &prior, 0.0).unwrap();
    let mut rng = crate::rng::stream(3, 0);
    let mut x = [0.0];
    let u = [1.5];
    let (mut gap, mut gap0) = (0.0f64, 0.0f64);
    for k in 1..=60 {
        let t = k as f64 * dt;
        crate::model::discrete::em_integrate(&model, &mut x, &u, dt, 1e-3, &mut rng);
        let mut y = [0.0];
        simulate_observation(&model, &x, &mut rng, &mut y);
        cf.predict(t, &u).unwrap();
        kf.predict(t, &u).unwrap();
        k0.predict(t, &[0.0]).unwrap();
        for f in [&mut cf as &mut dyn BayesFilter, &mut kf, &mut k0] {
            f.update(&Measurement::full(&y)).unwrap();
        }
        gap = gap.max((cf.belief().mean[0] - kf.belief().mean[0]).abs());
        gap0 = gap0.max((k0.belief().mean[0] - kf.belief().mean[0]).abs());
    }
    eprintln!("tilted chain vs Kalman {gap:.4}, uncontrolled Kalman vs Kalman {gap0:.4}");
    assert!(gap0 > 0.2, "control must matter: {gap0}");
    assert!(
        gap < 0.25 * gap0,
        "tilted chain vs Kalman: {gap} (uncontrolled {gap0})"
    );
    // back to u₀: the untilted kernel is restored
    cf.predict(3.1, &[0.0]).unwrap();
}

#[test]
fn flush_discards_at_most_eps_and_moves_the_mean_within_its_bound() {
    // Two filters on the same chain and observations: `full` keeps
    // every mass, `cut` the default mass-bounded flush. Before each
    // update `cut` gets `full`'s predicted φ, so each update is compared
    // on the same input: the discarded mass D must be ≤ ε, and the mean
    // may move by at most 2D·max_z‖z − x̂‖ (total variation D).
    let model = ou2();
    let dt = 0.05;
    let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
    let make = || {
        ChainFilter::from_samples(
            model.clone(),
            ChainConfig::moment_matched(2),
            &Sampler::Uniform,
            3000,
            dt,
            &mut crate::rng::stream(21, 1),
        )
        .unwrap()
    };
    let (mut full, mut cut) = (make(), make());
    assert_eq!(cut.flush(), Flush::Mass(FLUSH_MASS));
    full.set_flush(0.0);
    full.reset(0.0, &prior);
    let mut rng = crate::rng::stream(21, 0);
    let mut x = [0.8, -0.4];
    let (mut acted, mut total) = (0, 0.0);
    for k in 1..=40 {
        let t = k as f64 * dt;
        crate::model::discrete::em_integrate(&model, &mut x, &[], dt, 1e-3, &mut rng);
        let mut y = [0.0; 2];
        simulate_observation(&model, &x, &mut rng, &mut y);
        full.predict(t, &[]).unwrap();
        cut.set_weights(full.weights());
        cut.t = t;
        let support_before = cut.support();
        full.update(&Measurement::full(&y)).unwrap();
        cut.update(&Measurement::full(&y)).unwrap();
        let dm = cut.last_discarded();
        assert!(dm <= FLUSH_MASS * (1.0 + 1e-9), "step {k}: dropped {dm}");
        let kept: f64 = cut.weights().iter().sum();
        assert!((kept - (1.0 - dm)).abs() < 1e-12, "{kept} vs 1 − {dm}");
        let (a, b) = (full.belief(), cut.belief());
        let radius = (0..cut.chain().len())
            .map(|i| {
                let z = cut.chain().state(i);
                ((z[0] - a.mean[0]).powi(2) + (z[1] - a.mean[1]).powi(2)).sqrt()
            })
            .fold(0.0, f64::max);
        let gap = ((a.mean[0] - b.mean[0]).powi(2) + (a.mean[1] - b.mean[1]).powi(2)).sqrt();
        assert!(
            gap <= 2.0 * dm * radius * (1.0 + 1e-6) + 1e-15,
            "step {k}: mean moved {gap}, bound {}",
            2.0 * dm * radius
        );
        if dm > 0.0 && cut.support() < support_before {
            acted += 1;
        }
        total += dm;
    }
    // the flush does act: it removes states in (nearly) every update
    assert!(acted >= 30, "flush acted in {acted} of 40 updates");
    assert!((cut.discarded_total() - total).abs() < 1e-18);
    assert!(
        cut.support() < full.support() / 2,
        "{} vs {}",
        cut.support(),
        full.support()
    );
}

#[test]
fn update_belief_and_evidence_match_direct_sums() {
    // The fused update (unshifted weights, and the max-shifted pass when
    // every likelihood underflows) against direct sums over the slots:
    // the cached belief equals `moments` bit for bit, and the log
    // evidence equals log Σ_z φ⁻(z) N(y; g(z), σ²I) by log-sum-exp.
    let model = ou2();
    let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
    let make = || {
        ChainFilter::from_samples(
            model.clone(),
            ChainConfig::moment_matched(2),
            &Sampler::Uniform,
            2000,
            0.05,
            &mut crate::rng::stream(5, 1),
        )
        .unwrap()
    };
    let mut cf = make();
    cf.set_flush(0.0);
    cf.reset(0.0, &prior);
    // the same updates under the default mass-bounded flush
    let mut cm = make();
    cm.reset(0.0, &prior);
    // y near the prior, then y ≈ 60σ away (every exp(l) underflows)
    for (k, y) in [[0.7, -0.3], [0.9, -0.5], [12.0, -12.0]].iter().enumerate() {
        cf.predict(0.05 * (k + 1) as f64, &[]).unwrap();
        let phi = cf.weights().to_vec();
        let mut lse = f64::NEG_INFINITY;
        let mut terms = vec![];
        for (i, &p) in phi.iter().enumerate() {
            if p > 0.0 {
                let z = cf.chain().state(i);
                let q: f64 = (0..2).map(|a| ((y[a] - z[a]) / 0.2).powi(2)).sum();
                let l = p.ln() - 0.5 * q - 2.0 * (0.2f64.ln() + HALF_LOG_2PI);
                terms.push(l);
                lse = lse.max(l);
            }
        }
        let direct = lse + terms.iter().map(|t| (t - lse).exp()).sum::<f64>().ln();
        cm.set_weights(&phi);
        cm.t = cf.t;
        let im = cm.update(&Measurement::full(y)).unwrap();
        assert!((im.log_evidence - direct).abs() < 1e-9 * direct.abs().max(1.0));
        assert!(cm.last_discarded() <= FLUSH_MASS * (1.0 + 1e-9));
        let info = cf.update(&Measurement::full(y)).unwrap();
        assert!(
            (info.log_evidence - direct).abs() < 1e-9 * direct.abs().max(1.0),
            "step {k}: {} vs {direct}",
            info.log_evidence
        );
        let (cached, fresh) = (cf.belief(), cf.moments());
        assert_eq!(cached.mean, fresh.mean, "step {k}");
        assert_eq!(cached.cov, fresh.cov, "step {k}");
    }
}

#[test]
fn sparse_prediction_equals_the_dense_map() {
    // Once the flush has shrunk the support below n/4, predict runs the
    // sparse push over the support; it must give what the dense
    // gather (P^δ)ᵀ applied Δ/δ times gives to the same φ, for the
    // thesis chain (several δ steps per Δ) and the advected chain (one).
    let model = ou2();
    let dt = 0.05;
    let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
    for cfg in [
        ChainConfig::moment_matched(2),
        ChainConfig::moment_matched(2).with_step(dt),
    ] {
        let mut cf = ChainFilter::from_samples(
            model.clone(),
            cfg,
            &Sampler::Uniform,
            4000,
            dt,
            &mut crate::rng::stream(8, 1),
        )
        .unwrap();
        cf.set_flush_mass(1e-6);
        cf.reset(0.0, &prior);
        let n = cf.chain().len();
        let mut sparse_steps = 0;
        for (k, y) in [[0.8, -0.4], [0.7, -0.3], [0.75, -0.35], [0.6, -0.3]]
            .iter()
            .enumerate()
        {
            cf.update(&Measurement::full(y)).unwrap();
            let before = cf.weights().to_vec();
            let support = cf.support();
            assert_eq!(
                support,
                before.iter().filter(|&&w| w != 0.0).count(),
                "support lists exactly the slots with mass"
            );
            let t = dt * (k + 1) as f64;
            let steps0 = cf.substeps();
            cf.predict(t, &[]).unwrap();
            let steps = (cf.substeps() - steps0) as usize;
            assert!(steps >= 1);
            let mut dense = before.clone();
            let mut tmp = vec![0.0; n];
            for _ in 0..steps {
                cf.kernel().forward(&dense, &mut tmp);
                std::mem::swap(&mut dense, &mut tmp);
            }
            let got = cf.weights();
            for z in 0..n {
                assert!(
                    // rounding only: the two sum in different orders
                    (got[z] - dense[z]).abs() <= 1e-15 * steps as f64,
                    "slot {z}: {} vs {}",
                    got[z],
                    dense[z]
                );
            }
            assert_eq!(
                cf.support(),
                got.iter().filter(|&&w| w != 0.0).count(),
                "support after predict"
            );
            if support * 4 < n {
                sparse_steps += 1;
            }
        }
        assert!(sparse_steps >= 3, "sparse path ran {sparse_steps} times");
    }
}

#[test]
fn converges_to_kalman_as_n_grows() {
    let mut last = (f64::INFINITY, f64::INFINITY);
    for n in [300usize, 3000, 30000] {
        // average over 3 seeds to keep the comparison about n, not luck
        let mut g = (0.0, 0.0);
        for s in 0..3 {
            let e = gap_to_kalman(n, 10 + s);
            g.0 += e.0 / 3.0;
            g.1 += e.1 / 3.0;
        }
        eprintln!("n={n}: mean gap {:.4}, cov gap {:.5}", g.0, g.1);
        assert!(g.0 < last.0 && g.1 < last.1, "n={n}: {g:?} vs {last:?}");
        last = g;
    }
    // At 30,000 states the posterior mean is within a few percent of the
    // posterior std (≈ 0.13) of the exact answer.
    assert!(last.0 < 0.02, "{last:?}");
}

#[test]
fn advected_chain_filter_converges_to_kalman_as_n_grows() {
    // The advected construction (Δt = δ = τ = the observation period):
    // same Kalman–Bucy check as above.
    let mut last = (f64::INFINITY, f64::INFINITY);
    for n in [300usize, 3000, 30000] {
        let mut g = (0.0, 0.0);
        for s in 0..3 {
            let cfg = ChainConfig::moment_matched(2).with_step(0.05);
            let e = gap_to_kalman_with(n, 10 + s, cfg);
            g.0 += e.0 / 3.0;
            g.1 += e.1 / 3.0;
        }
        eprintln!("advected n={n}: mean gap {:.4}, cov gap {:.5}", g.0, g.1);
        assert!(g.0 < last.0 && g.1 < last.1, "n={n}: {g:?} vs {last:?}");
        last = g;
    }
    assert!(last.0 < 0.02, "{last:?}");
}
