//! MPPI on a double integrator: closed loop, limits, determinism, validation.

use super::*;
use crate::model::linear::LinearSde;
use crate::model::Bounds;
use nalgebra::DMatrix;

/// Double integrator p̈ = u + s ẇ.
fn double_integrator(s: f64) -> LinearSde {
    LinearSde::new(
        "di",
        DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]),
        DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
        DMatrix::from_row_slice(2, 1, &[0.0, s]),
        DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
        vec![0.1],
        Bounds::new_box(&[-10.0, -10.0], &[10.0, 10.0]).unwrap(),
    )
}

fn di_config() -> MppiConfig {
    MppiConfig {
        samples: 256,
        horizon_steps: 40,
        dt: 0.05,
        temperature: 0.1,
        noise_std: vec![1.0],
        u_min: vec![-2.0],
        u_max: vec![2.0],
        control_weight: 0.01,
        smoothing: true,
        seed: 1,
    }
}

fn di_cost() -> TrackingCost {
    TrackingCost::new(&[10.0, 1.0], &[20.0, 5.0], None)
}

#[test]
fn savitzky_golay_is_exact_on_quadratics() {
    let steps = 9;
    let src: Vec<f64> = (0..steps)
        .flat_map(|t| {
            let t = t as f64;
            [1.0 - 0.5 * t + 0.25 * t * t, 3.0 * t]
        })
        .collect();
    let mut dst = vec![0.0; src.len()];
    savitzky_golay(&src, &mut dst, steps, 2);
    for (a, b) in src.iter().zip(&dst) {
        assert!((a - b).abs() < 1e-12, "{a} vs {b}");
    }
    // And it damps an alternating (noise-like) sequence.
    let alt: Vec<f64> = (0..steps)
        .map(|t| if t % 2 == 0 { 1.0 } else { -1.0 })
        .collect();
    let mut out = vec![0.0; steps];
    savitzky_golay(&alt, &mut out, steps, 1);
    assert!(out[2..steps - 2].iter().all(|v| v.abs() < 0.5));
}

/// Closed loop on a double integrator with process noise (s = 0.05),
/// driven from rest at p = 0 to the goal p = 1, 50 Hz control, four
/// seeds: within 2 s the position is within 0.05 of the goal, and over
/// the last second (t ∈ [4, 5] s) it stays within 0.05 with speed within
/// 0.2 (the plant's velocity noise has σ = 0.05 over one second).
#[test]
fn closed_loop_reaches_and_holds_a_goal() {
    for seed in 0..4 {
        let plant = double_integrator(0.05);
        let cfg = MppiConfig {
            seed,
            ..di_config()
        };
        let mut mppi = Mppi::new(double_integrator(0.0), di_cost(), &cfg).unwrap();
        mppi.set_goal(&[1.0, 0.0]);
        let mut rng = rng::stream(seed, 77);
        let mut x = [0.0, 0.0];
        let mut u = [0.0];
        let period = 0.02;
        let mut reached = None;
        let mut worst_late: (f64, f64) = (0.0, 0.0);
        for i in 0..250 {
            let t = i as f64 * period;
            let b = Gaussian::diagonal(&x, &[0.01, 0.01]);
            mppi.compute(t, &b, &mut u).unwrap();
            mppi.prepare();
            crate::model::discrete::em_integrate(&plant, &mut x, &u, period, 1e-3, &mut rng);
            let t = t + period;
            if reached.is_none() && (x[0] - 1.0).abs() < 0.05 {
                reached = Some(t);
            }
            if t >= 4.0 {
                worst_late.0 = worst_late.0.max((x[0] - 1.0).abs());
                worst_late.1 = worst_late.1.max(x[1].abs());
            }
        }
        assert!(
            reached.is_some_and(|t| t < 2.0),
            "seed {seed}: reached at {reached:?}"
        );
        assert!(
            worst_late.0 < 0.05,
            "seed {seed}: position error {}",
            worst_late.0
        );
        assert!(
            worst_late.1 < 0.2,
            "seed {seed}: speed error {}",
            worst_late.1
        );
    }
}

#[test]
fn control_limits_are_always_respected() {
    let cfg = MppiConfig {
        noise_std: vec![5.0],
        u_min: vec![-0.5],
        u_max: vec![1.5],
        ..di_config()
    };
    let mut mppi = Mppi::new(double_integrator(0.0), di_cost(), &cfg).unwrap();
    let mut rng = rng::stream(5, 0);
    let mut u = [0.0];
    for i in 0..200 {
        let x = [rng.random_range(-8.0..8.0), rng.random_range(-4.0..4.0)];
        if i % 7 == 0 {
            mppi.set_goal(&[rng.random_range(-8.0..8.0), 0.0]);
        }
        mppi.compute(
            i as f64 * 0.013,
            &Gaussian::diagonal(&x, &[0.1, 0.1]),
            &mut u,
        )
        .unwrap();
        assert!((-0.5..=1.5).contains(&u[0]), "u = {}", u[0]);
        assert!(mppi.nominal().iter().all(|v| (-0.5..=1.5).contains(v)));
    }
    // Saturating goals drive the control to the limits.
    mppi.reset();
    mppi.set_goal(&[100.0, 0.0]);
    mppi.compute(0.0, &Gaussian::diagonal(&[0.0, 0.0], &[0.1, 0.1]), &mut u)
        .unwrap();
    assert!(u[0] > 1.0, "u = {}", u[0]);
}

/// With one sample and zero noise the only candidate is the nominal
/// sequence: MPPI returns it unchanged, and the warm start shifts it by
/// the elapsed time (whole and fractional steps).
#[test]
fn one_noiseless_sample_reproduces_the_nominal_sequence() {
    let cfg = MppiConfig {
        samples: 1,
        noise_std: vec![0.0],
        ..di_config()
    };
    let mut mppi = Mppi::new(double_integrator(0.0), di_cost(), &cfg).unwrap();
    let seq: Vec<f64> = (0..cfg.horizon_steps)
        .map(|t| 1.5 * (0.3 * t as f64).sin())
        .collect();
    mppi.set_nominal(&seq).unwrap();
    let b = Gaussian::diagonal(&[0.3, -0.2], &[0.1, 0.1]);
    let mut u = [0.0];
    let info = mppi.compute(1.0, &b, &mut u).unwrap();
    assert_eq!(u[0], seq[0]);
    assert_eq!(mppi.nominal(), &seq[..]);
    assert_eq!(info.ess, 1.0);
    // One step later: the sequence shifted by one.
    mppi.compute(1.0 + cfg.dt, &b, &mut u).unwrap();
    assert!((u[0] - seq[1]).abs() < 1e-12);
    // Half a step later: halfway between seq[1] and seq[2].
    mppi.compute(1.0 + 1.5 * cfg.dt, &b, &mut u).unwrap();
    assert!((u[0] - 0.5 * (seq[1] + seq[2])).abs() < 1e-12);
    let n = mppi.nominal();
    assert!((n[cfg.horizon_steps - 1] - seq[cfg.horizon_steps - 1]).abs() < 1e-12);
}

/// The weighted update improves the plan: starting from a zero nominal,
/// the cost of the returned nominal sequence (one noiseless rollout)
/// decreases over repeated calls at the same state.
#[test]
fn iterations_reduce_the_nominal_cost() {
    let cfg = di_config();
    let mut mppi = Mppi::new(double_integrator(0.0), di_cost(), &cfg).unwrap();
    mppi.set_goal(&[1.0, 0.0]);
    let b = Gaussian::diagonal(&[0.0, 0.0], &[0.1, 0.1]);
    let nominal_cost = |m: &Mppi<LinearSde>| {
        let probe_cfg = MppiConfig {
            samples: 1,
            noise_std: vec![0.0],
            ..m.config().clone()
        };
        let mut probe = Mppi::new(double_integrator(0.0), *m.cost(), &probe_cfg).unwrap();
        probe.set_nominal(m.nominal()).unwrap();
        let mut u = [0.0];
        probe.compute(0.0, &b, &mut u).unwrap().cost
    };
    let c0 = nominal_cost(&mppi);
    let mut u = [0.0];
    for _ in 0..20 {
        mppi.compute(0.0, &b, &mut u).unwrap();
    }
    let c20 = nominal_cost(&mppi);
    assert!(c20 < 0.5 * c0, "cost {c0} -> {c20}");
}

#[test]
fn same_seed_same_controls_and_prepare_is_equivalent() {
    let run = |use_prepare: bool| {
        let mut m = Mppi::new(double_integrator(0.0), di_cost(), &di_config()).unwrap();
        m.set_goal(&[1.0, 0.0]);
        let mut out = vec![];
        let mut u = [0.0];
        for i in 0..5 {
            let b = Gaussian::diagonal(&[0.1 * i as f64, 0.0], &[0.1, 0.1]);
            m.compute(0.02 * i as f64, &b, &mut u).unwrap();
            if use_prepare {
                m.prepare();
            }
            out.push(u[0]);
        }
        out
    };
    assert_eq!(run(true), run(true));
    // Drawing the noise in prepare() or inside compute() consumes the
    // same stream in the same order.
    assert_eq!(run(true), run(false));
}

#[test]
fn config_and_inputs_are_validated() {
    let ok = di_config();
    assert!(ok.validate(1).is_ok());
    assert_eq!(ok.validate(2).unwrap_err().key, "noise_std");
    for (cfg, key) in [
        (
            MppiConfig {
                samples: 0,
                ..di_config()
            },
            "samples",
        ),
        (
            MppiConfig {
                temperature: 0.0,
                ..di_config()
            },
            "temperature",
        ),
        (
            MppiConfig {
                u_min: vec![3.0],
                ..di_config()
            },
            "u_min",
        ),
        (
            MppiConfig {
                noise_std: vec![-1.0],
                ..di_config()
            },
            "noise_std",
        ),
    ] {
        assert_eq!(
            Mppi::new(double_integrator(0.0), di_cost(), &cfg)
                .err()
                .unwrap()
                .key,
            key
        );
    }
    let parsed: MppiConfig = toml::from_str("samples = 64\nnoise_std = [0.5]").unwrap();
    assert_eq!(parsed.samples, 64);
    assert!(toml::from_str::<MppiConfig>("sample = 64").is_err());
    let mut m = Mppi::new(double_integrator(0.0), di_cost(), &ok).unwrap();
    let mut u = [0.0];
    assert!(matches!(
        m.compute(0.0, &Gaussian::zeros(3), &mut u),
        Err(ControlError::Dimension { .. })
    ));
    assert!(matches!(
        m.compute(
            0.0,
            &Gaussian::diagonal(&[f64::NAN, 0.0], &[1.0, 1.0]),
            &mut u
        ),
        Err(ControlError::NonFinite)
    ));
}
