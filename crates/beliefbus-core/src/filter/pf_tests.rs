use super::*;
use crate::filter::kalman::testmodels::oscillator;
use crate::filter::kalman::Kalman;
use crate::model::ship::{Ship, ShipParams};
use crate::model::ObsMask;

/// A seeded trajectory of the oscillator and its measurements: every
/// third one carries only component 0 with an overridden σ.
struct Data {
    times: Vec<f64>,
    ys: Vec<[f64; 2]>,
    us: Vec<f64>,
}

fn oscillator_data(steps: usize, dt: f64, seed: u64) -> Data {
    let model = oscillator([0.2, 0.3]);
    let mut rng = rng::stream(seed, 99);
    let mut x = [1.0, 0.0];
    let mut d = Data {
        times: vec![],
        ys: vec![],
        us: vec![],
    };
    for k in 1..=steps {
        let u = (0.7 * k as f64 * dt).sin();
        crate::model::discrete::em_integrate(&model, &mut x, &[u], dt, 1e-4, &mut rng);
        let mut y = [0.0; 2];
        crate::model::simulate_observation(&model, &x, &mut rng, &mut y);
        d.times.push(k as f64 * dt);
        d.ys.push(y);
        d.us.push(u);
    }
    d
}

fn run<F: BayesFilter>(f: &mut F, data: &Data) -> Vec<Gaussian> {
    let override_std = [0.5, 0.3];
    let mut out = vec![];
    for k in 0..data.times.len() {
        f.predict(data.times[k], &[data.us[k]]).unwrap();
        let meas = if k % 3 == 2 {
            Measurement {
                y: &data.ys[k],
                mask: ObsMask(0b01),
                std: Some(&override_std),
            }
        } else {
            Measurement::full(&data.ys[k])
        };
        f.update(&meas).unwrap();
        out.push(f.belief());
    }
    out
}

pub(crate) fn prior() -> Gaussian {
    let mut p = Gaussian::diagonal(&[0.8, 0.2], &[0.5, 0.4]);
    p.set_cov(0, 1, 0.05);
    p.set_cov(1, 0, 0.05);
    p
}

/// Over R seeded runs the PF's mean and covariance agree with the exact
/// Kalman filter: the average over runs is within 4.5 standard errors
/// (estimated from the runs) plus an allowance of 1 % of the posterior
/// std for the O(h) Euler–Maruyama and O(1/N) biases; and once the
/// informative first updates (ESS ≪ N) are forgotten, each run's spread
/// is of the Monte-Carlo order √(P/N) (≤ 3× for resampling).
#[test]
fn matches_the_kalman_filter_on_a_linear_gaussian_model() {
    let data = oscillator_data(20, 0.05, 5);
    let mut kf = Kalman::new(oscillator([0.2, 0.3]), &prior(), 0.0).unwrap();
    let exact = run(&mut kf, &data);
    let runs = 16;
    let n = 2000;
    let checkpoints = [4usize, 11, 19];
    // [checkpoint][run][m0, m1, p00, p01, p11]
    let mut stats = vec![vec![[0.0; 5]; runs]; checkpoints.len()];
    for r in 0..runs {
        let cfg = PfConfig {
            particles: n,
            max_dt: 0.001,
            seed: r as u64,
            ..PfConfig::default()
        };
        let mut pf = Pf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
        let beliefs = run(&mut pf, &data);
        for (c, &k) in checkpoints.iter().enumerate() {
            let b = &beliefs[k];
            stats[c][r] = [b.mean[0], b.mean[1], b.cov[0], b.cov[2], b.cov[3]];
        }
    }
    for (c, &k) in checkpoints.iter().enumerate() {
        let e = &exact[k];
        let want = [e.mean[0], e.mean[1], e.cov[0], e.cov[2], e.cov[3]];
        // Scale of each statistic: posterior std for means, variance
        // scale for covariance entries.
        let scale = [
            e.cov[0].sqrt(),
            e.cov[3].sqrt(),
            e.cov[0],
            (e.cov[0] * e.cov[3]).sqrt(),
            e.cov[3],
        ];
        for s in 0..5 {
            let vals: Vec<f64> = stats[c].iter().map(|v| v[s]).collect();
            let mean = vals.iter().sum::<f64>() / runs as f64;
            let sd =
                (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (runs - 1) as f64).sqrt();
            let se = sd / (runs as f64).sqrt();
            assert!(
                (mean - want[s]).abs() < 4.5 * se + 0.01 * scale[s],
                "step {k} stat {s}: PF {mean} ± {se} vs Kalman {}",
                want[s]
            );
            // Monte-Carlo spread of one run: √(Var/N) for a mean,
            // √(2/N)·scale for a (co)variance; resampling inflates it.
            let mc = if s < 2 {
                scale[s] / (n as f64).sqrt()
            } else {
                scale[s] * (2.0 / n as f64).sqrt()
            };
            if c == checkpoints.len() - 1 {
                assert!(sd < 3.0 * mc, "step {k} stat {s}: spread {sd} vs {mc}");
            }
        }
    }
}

#[test]
fn impossible_measurement_is_degenerate_and_keeps_particles() {
    let cfg = PfConfig {
        particles: 200,
        ..PfConfig::default()
    };
    let mut pf = Pf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
    pf.predict(0.1, &[0.0]).unwrap();
    let before = (pf.particles().to_vec(), pf.weights().to_vec());
    let e = pf.update(&Measurement::full(&[1e200, 0.0]));
    assert_eq!(e, Err(FilterError::Degenerate));
    assert_eq!(pf.particles(), &before.0[..]);
    assert_eq!(pf.weights(), &before.1[..]);
    // And it keeps working.
    pf.update(&Measurement::full(&[0.8, 0.1])).unwrap();
}

#[test]
fn resampling_follows_the_ess_threshold() {
    let data = oscillator_data(10, 0.05, 1);
    for (thr, expect_any, expect_all) in [(0.0, false, false), (1.0, true, true)] {
        let cfg = PfConfig {
            particles: 300,
            resample_threshold: thr,
            ..PfConfig::default()
        };
        let mut pf = Pf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
        let mut flags = vec![];
        let mut min_ess = f64::INFINITY;
        for k in 0..10 {
            pf.predict(data.times[k], &[data.us[k]]).unwrap();
            let info = pf.update(&Measurement::full(&data.ys[k])).unwrap();
            min_ess = min_ess.min(info.ess);
            assert!(
                (info.ess - crate::math::weights::ess_from_linear(pf.weights())).abs() < 1e-6
                    || info.resampled
            );
            flags.push(info.resampled);
        }
        assert_eq!(flags.iter().any(|&f| f), expect_any);
        assert_eq!(flags.iter().all(|&f| f), expect_all);
        // The measurements are informative: weights degenerate somewhat.
        assert!(min_ess < 0.5 * 300.0, "min ESS {min_ess}");
    }
}

/// A bearing-only update of a ship prior centred on the negative x-axis,
/// where bearings jump from π to −π: the posterior straddles the cut.
/// With wrapped residuals the posterior lateral offset equals that of
/// the same problem rotated by −90° (no cut) and the linearised answer;
/// subtracting raw angles would kill the particles across the cut and
/// bias it by ≈ 0.04 m.
#[test]
fn ship_bearing_residuals_wrap() {
    let params = ShipParams {
        range_std: 0.05,
        bearing_std: 0.01,
        ..ShipParams::paper(0.01)
    };
    let bearing_only = ObsMask(0b10);
    let cfg = PfConfig {
        particles: 20_000,
        resample_threshold: 0.0,
        seed: 3,
        ..PfConfig::default()
    };
    let std = [0.3, 0.3, 0.1, 0.1];
    // Truth at (−6, 0.006): bearing π − 0.001.
    let y_a = [6.0, std::f64::consts::PI - 0.001];
    let prior_a = Gaussian::diagonal(&[-6.0, 0.0, 0.0, 0.0], &std);
    let mut a = Pf::new(Ship::new(params.clone()).unwrap(), &cfg, &prior_a, 0.0).unwrap();
    a.update(&Measurement {
        y: &y_a,
        mask: bearing_only,
        std: None,
    })
    .unwrap();
    // Rotated by −90°: (x, y) ↦ (y, −x), truth at (0.006, 6).
    let y_b = [6.0, std::f64::consts::FRAC_PI_2 - 0.001];
    let prior_b = Gaussian::diagonal(&[0.0, 6.0, 0.0, 0.0], &std);
    let mut b = Pf::new(Ship::new(params).unwrap(), &cfg, &prior_b, 0.0).unwrap();
    b.update(&Measurement {
        y: &y_b,
        mask: bearing_only,
        std: None,
    })
    .unwrap();
    let lat_a = a.belief().mean[1];
    let lat_b = b.belief().mean[0];
    // Linearised: lateral prior σ 0.3 m ≙ 0.05 rad, bearing σ 0.01 rad.
    let lin = 0.006 * 0.05f64.powi(2) / (0.05f64.powi(2) + 0.01f64.powi(2));
    assert!((lat_a - lat_b).abs() < 0.01, "{lat_a} vs rotated {lat_b}");
    assert!((lat_a - lin).abs() < 0.01, "{lat_a} vs linearised {lin}");
}

#[test]
fn config_parses_with_defaults_and_rejects_bad_values() {
    let c: PfConfig = toml::from_str("particles = 500\nresampling = \"residual\"").unwrap();
    assert_eq!(c.particles, 500);
    assert_eq!(c.resampling, Scheme::Residual);
    assert_eq!(c.resample_threshold, 0.5);
    assert!(toml::from_str::<PfConfig>("particle = 5").is_err());
    assert!(toml::from_str::<PfConfig>("resampling = \"bogus\"").is_err());
    for (bad, key) in [
        (
            PfConfig {
                particles: 0,
                ..Default::default()
            },
            "particles",
        ),
        (
            PfConfig {
                resample_threshold: 1.5,
                ..Default::default()
            },
            "resample_threshold",
        ),
        (
            PfConfig {
                max_dt: 0.0,
                ..Default::default()
            },
            "max_dt",
        ),
    ] {
        assert_eq!(bad.validate().unwrap_err().key, key);
        assert!(Pf::new(oscillator([0.2, 0.3]), &bad, &prior(), 0.0).is_err());
    }
}

#[test]
fn same_seed_same_result() {
    let data = oscillator_data(5, 0.05, 2);
    let cfg = PfConfig {
        particles: 100,
        seed: 9,
        ..Default::default()
    };
    let mut a = Pf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
    let mut b = Pf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
    assert_eq!(run(&mut a, &data), run(&mut b, &data));
}
