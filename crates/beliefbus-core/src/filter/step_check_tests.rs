//! The integration-step checks of the filter configs' `build`
//! ([`super::build::check_step`]) against models whose rates are known.

use super::build::{em_step_bound, BuildError, EM_BIAS, EM_RATE_STEP, RK4_RATE_STEP};
use super::ekf::EkfConfig;
use super::pf::PfConfig;
use super::ukf::UkfConfig;
use crate::belief::Gaussian;
use crate::model::linear::ou_1d;
use crate::model::lorenz::{Lorenz, LorenzParams};
use crate::model::scale::TimeScales;

fn rejected_key<T>(r: Result<T, BuildError>) -> Option<(&'static str, String)> {
    match r {
        Err(BuildError::Config(e)) => Some((e.key, e.problem)),
        _ => None,
    }
}

#[test]
fn pf_step_is_checked_against_the_exact_rate_of_a_linear_model() {
    // dx = −50 x dt + 5 dw from near stationarity: the Jacobian is −50
    // everywhere, ρ = 50, so the rate bound allows 0.2/50 = 4 ms; the
    // drift-error bound 0.6√(qρ)/ā, ā = ρ² mean|x| ≈ 2500·0.5, allows ≈ 17 ms.
    let model = ou_1d(50.0, 5.0, 0.1, 10.0);
    let prior = Gaussian::diagonal(&[0.0], &[0.5]);
    let cfg = |max_dt| PfConfig {
        particles: 10,
        max_dt,
        ..PfConfig::default()
    };
    let (key, problem) = rejected_key(cfg(0.01).build(model.clone(), &prior, 0.0)).unwrap();
    assert_eq!(key, "max_dt");
    assert!(problem.contains("4.000e-3"), "{problem}");
    assert!(cfg(0.0041).build(model.clone(), &prior, 0.0).is_err());
    assert!(cfg(0.0039).build(model.clone(), &prior, 0.0).is_ok());
    // `new` is the same construction
    assert!(super::pf::Pf::new(model.clone(), &cfg(0.01), &prior, 0.0).is_err());
    let derived = cfg(0.01).with_derived_step(&model, &prior).unwrap();
    assert!((derived.max_dt - EM_RATE_STEP / 50.0).abs() < 1e-12);
    assert!(derived.build(model.clone(), &prior, 0.0).is_ok());
    // a step already fine is kept
    assert_eq!(
        cfg(1e-3).with_derived_step(&model, &prior).unwrap().max_dt,
        1e-3
    );
}

#[test]
fn gaussian_filters_check_their_rk4_step() {
    // ρ = 50: RK4 substeps up to 0.5/50 = 10 ms are accepted.
    let model = ou_1d(50.0, 5.0, 0.1, 10.0);
    let prior = Gaussian::diagonal(&[0.0], &[0.5]);
    let limit = RK4_RATE_STEP / 50.0;
    for (dt, ok) in [(0.9 * limit, true), (1.1 * limit, false)] {
        let e = EkfConfig { max_dt: dt }.build(model.clone(), &prior, 0.0);
        let u = UkfConfig {
            max_dt: dt,
            ..UkfConfig::default()
        }
        .build(model.clone(), &prior, 0.0);
        assert_eq!(e.is_ok(), ok, "ekf at {dt}");
        assert_eq!(u.is_ok(), ok, "ukf at {dt}");
    }
}

#[test]
fn the_default_pf_step_is_refused_on_lorenz_and_the_derived_one_accepted() {
    // Lorenz-63 observed in x: the PfConfig default 10 ms EM step moves
    // the particle cloud by about its own spread per time constant (PF-300's
    // error 7.0 against 1.34 at 2 ms in the `chain-defaults` experiment),
    // so build refuses it, names the step that passes (≈ 2.6 ms), and that
    // step builds.
    let model = Lorenz::new(LorenzParams::default()).unwrap();
    let prior = Gaussian::diagonal(&[-6.0, -6.0, 25.0], &[1.0, 1.0, 1.0]);
    let cfg = PfConfig {
        particles: 50,
        ..PfConfig::default()
    };
    let (key, _) = rejected_key(cfg.build(model.clone(), &prior, 0.0)).unwrap();
    assert_eq!(key, "max_dt");
    let fine = cfg.clone().with_derived_step(&model, &prior).unwrap();
    assert!(fine.max_dt < 4e-3 && fine.max_dt > 1e-3, "{}", fine.max_dt);
    assert!(fine.build(model, &prior, 0.0).is_ok());
}

#[test]
fn em_bound_is_the_smaller_of_the_rate_and_drift_error_bounds() {
    let scales = |rho: f64, q: f64, a: f64| TimeScales {
        rate_median: rho / 2.0,
        rate_p99: rho,
        diffusion_median: q,
        speed_median: 1.0,
        accel_p99: 10.0 * a,
        accel_mean: a,
        horizon: 1.0,
        points: 1,
    };
    // ρ₉₉ = 10 (ρ₅₀ = 5), q = 0.8, ā = 1: rate 0.02, drift error 0.6·√4 = 1.2
    let h = em_step_bound(&scales(10.0, 0.8, 1.0));
    assert!((h - EM_RATE_STEP / 10.0).abs() < 1e-15, "{h}");
    // ā = 1000: drift error 2·EM_BIAS·√4/1000 binds, where R = ā h/(2√(qρ₅₀)) = EM_BIAS
    let h = em_step_bound(&scales(10.0, 0.8, 1000.0));
    assert!((h - EM_BIAS * 4e-3).abs() < 1e-15, "{h}");
    assert!((1000.0 * h / (2.0 * (0.8f64 * 5.0).sqrt()) - EM_BIAS).abs() < 1e-12);
    // no diffusion: only the rate bound; no drift: no bound
    assert_eq!(
        em_step_bound(&scales(10.0, 0.0, 1000.0)),
        EM_RATE_STEP / 10.0
    );
    assert_eq!(em_step_bound(&scales(0.0, 0.4, 0.0)), f64::INFINITY);
}
