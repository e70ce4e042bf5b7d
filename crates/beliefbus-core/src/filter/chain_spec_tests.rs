use super::*;
use crate::model::linear::ou_1d;

fn ou_spec(period: f64) -> ChainFilterSpec {
    ChainFilterSpec {
        period,
        horizon: 10.0,
        seed: 4,
        ..ChainFilterSpec::default()
    }
}

#[test]
fn delta_is_the_largest_power_of_two_fraction_of_the_period_within_one_e_fold() {
    // dx = −25 x dt: ρ = 25 everywhere, so δ = 0.1/2^j with 25 δ ≤ 1:
    // 0.1 (2.5) and 0.05 (1.25) are too long, 0.025 (0.625) is the answer.
    let model = ou_1d(25.0, 2.0, 0.2, 5.0);
    let prior = Gaussian::diagonal(&[0.0], &[0.3]);
    let plan = ou_spec(0.1).plan(&model, &prior).unwrap();
    assert!((plan.delta - 0.025).abs() < 1e-15, "{}", plan.delta);
    // slow dynamics: δ is the period itself
    let slow = ou_1d(0.5, 0.3, 0.2, 5.0);
    let plan = ou_spec(0.1).plan(&slow, &prior).unwrap();
    assert_eq!(plan.delta, 0.1);
    // the integration step is the PF's bound, at most the period
    assert_eq!(
        plan.sim_dt,
        0.1f64.min(crate::filter::build::em_step_bound(&plan.scales))
    );
}

#[test]
fn pilot_spread_matches_the_kalman_posterior_after_an_update() {
    // OU dx = −a x dt + s dw observed every Δ = 0.1 s with σ = 0.2: the
    // posterior variance after an update follows the scalar Riccati
    // recursion P⁻ = e^{−2aΔ} P⁺ + s²(1 − e^{−2aΔ})/(2a),
    // P⁺ = P⁻σ²/(P⁻ + σ²) from the prior's variance. The pilot PF (1000
    // particles, 2 records of 100 updates) reports the RMS over the
    // updates of the posterior std; the exact RMS is computed here. PF
    // variance estimates of 1000 particles err by a few per cent.
    let (a, s, sigma, dt) = (1.0, 0.8, 0.2, 0.1);
    let model = ou_1d(a, s, sigma, 10.0);
    let prior = Gaussian::diagonal(&[0.0], &[0.5]);
    let plan = ou_spec(dt).plan(&model, &prior).unwrap();
    let (phi2, q) = (
        (-2.0 * a * dt).exp(),
        s * s * (1.0 - (-2.0 * a * dt).exp()) / (2.0 * a),
    );
    let mut p = 0.25;
    let mut sum = 0.0;
    for _ in 0..100 {
        let pm = phi2 * p + q;
        p = pm * sigma * sigma / (pm + sigma * sigma);
        sum += p;
    }
    let exact = (sum / 100.0).sqrt();
    let got = plan.posterior_std[0];
    assert!(
        (got - exact).abs() < 0.05 * exact,
        "pilot {got} vs Kalman {exact}"
    );
    // the budget counts cells of side s/RESOLUTION on a 1-D predictive
    // law; a finer resolution needs proportionally more cells
    let fine = ChainFilterSpec {
        resolution: 2.0 * RESOLUTION,
        ..ou_spec(dt)
    }
    .plan(&model, &prior)
    .unwrap();
    let ratio = fine.cells as f64 / plan.cells as f64;
    assert!(
        (1.7..2.3).contains(&ratio),
        "{} / {}",
        fine.cells,
        plan.cells
    );
}

#[test]
fn invalid_specs_are_refused_with_the_field_named() {
    let model = ou_1d(1.0, 0.5, 0.2, 4.0);
    let prior = Gaussian::diagonal(&[0.0], &[0.3]);
    for (spec, key) in [
        (ChainFilterSpec::new(0.0, 10.0), "period"),
        (ChainFilterSpec::new(0.1, -1.0), "horizon"),
        (
            ChainFilterSpec {
                obs_every: 0,
                ..ChainFilterSpec::default()
            },
            "obs_every",
        ),
        (
            ChainFilterSpec {
                uniform_fraction: 1.0,
                ..ChainFilterSpec::default()
            },
            "uniform_fraction",
        ),
    ] {
        match spec.plan(&model, &prior) {
            Err(SpecError::Config(e)) => assert_eq!(e.key, key),
            other => panic!("{key}: {other:?}"),
        }
    }
}
