//! The controller on the ship: config, validation, closed loop, budget.

use super::*;
use crate::control::cost::DiscBarrier;
use crate::model::affine::LinearAffine;
use crate::model::affine::PathStructure;

fn ship_cost() -> TrackingCost {
    TrackingCost::new(
        &[1.0, 1.0, 0.1, 0.1],
        &[5.0, 5.0, 1.0, 1.0],
        Some(DiscBarrier {
            axes: (0, 1),
            radius: 8.0,
            weight: 50.0,
        }),
    )
}

#[test]
fn config_round_trips_and_rejects_unknown_keys() {
    let cfg = PathIntegralConfig::default();
    let s = toml::to_string(&cfg).unwrap();
    let back: PathIntegralConfig = toml::from_str(&s).unwrap();
    assert_eq!(cfg, back);
    assert!(toml::from_str::<PathIntegralConfig>("samples = 4\nbogus = 1").is_err());
    let partial: PathIntegralConfig =
        toml::from_str("belief = \"sampled\"\nhorizon = \"shrinking\"\nfinal_time = 3.0").unwrap();
    assert_eq!(partial.belief, BeliefMode::Sampled);
    assert_eq!(partial.dt, 0.04);
    let bad = PathIntegralConfig {
        dt: 0.0,
        ..cfg.clone()
    };
    assert!(bad.validate().is_err());
    let bad = PathIntegralConfig {
        horizon: HorizonMode::Shrinking,
        ..cfg
    };
    assert!(bad.validate().is_err());
}

#[test]
fn rejects_models_violating_condition_8_and_bad_beliefs() {
    // Noise on a channel the control cannot reach.
    let m = LinearAffine {
        m: 2,
        p: 2,
        r: 2,
        a: vec![0.0; 4],
        g: vec![1.0, 0.0, 0.0, 1.0],
        q: vec![1.0, 0.0, 0.0, 3.0],
        structure: PathStructure::Full,
    };
    let cost = crate::control::implicit::DiagonalQuadraticCost::new(&[1.0, 1.0], &[1.0, 1.0]);
    let err = PathIntegralController::new(m, cost, PathIntegralConfig::default())
        .err()
        .unwrap();
    assert!(
        matches!(err, ControlError::Model(ref s) if s.contains("condition (8)")),
        "{err:?}"
    );
    let mut c = PathIntegralController::ship(
        ShipParams::paper(0.01),
        ship_cost(),
        PathIntegralConfig::default(),
    )
    .unwrap();
    let mut u = [0.0; 2];
    assert!(matches!(
        c.compute(0.0, &Gaussian::zeros(3), &mut u),
        Err(ControlError::Dimension { .. })
    ));
    let mut b = Gaussian::zeros(4);
    b.mean[0] = f64::NAN;
    assert_eq!(c.compute(0.0, &b, &mut u), Err(ControlError::NonFinite));
}

/// The ship controller drives the true (noisy) ship from rest to a goal
/// and holds it there.
#[test]
fn ship_reaches_a_goal_in_closed_loop() {
    let params = ShipParams::paper(0.01);
    let ship = Ship::new(params.clone()).unwrap();
    for belief in [BeliefMode::Mean, BeliefMode::Sampled] {
        let cfg = PathIntegralConfig {
            belief,
            budget_us: 0.0,
            ..PathIntegralConfig::default()
        };
        let mut c = PathIntegralController::ship(params.clone(), ship_cost(), cfg).unwrap();
        c.set_goal(&[4.0, -3.0, 0.0, 0.0]);
        let mut x = [-3.0, 2.0, 0.0, 0.0];
        let mut rng = crate::rng::stream(9, 1);
        let mut u = [0.0; 2];
        let dt = 0.02;
        let mut b = Gaussian::diagonal(&x, &[0.05, 0.05, 0.05, 0.05]);
        for step in 0..400 {
            b.mean_mut().copy_from_slice(&x);
            c.compute(step as f64 * dt, &b, &mut u).unwrap();
            let mut next = [0.0; 4];
            crate::model::em_step(&ship, &x, &u, dt, &mut rng, &mut next);
            x = next;
        }
        let d = (x[0] - 4.0).hypot(x[1] + 3.0);
        assert!(d < 0.6, "{belief:?}: final distance {d}, state {x:?}");
    }
}

/// Over budget, the controller steps down its ladder (fewer samples) and
/// still returns a control.
#[test]
fn degrades_gracefully_when_over_budget() {
    let cfg = PathIntegralConfig {
        samples: 32,
        belief: BeliefMode::Sampled,
        belief_samples: 8,
        budget_us: 1e-3, // impossible: every control is over budget
        ..PathIntegralConfig::default()
    };
    let mut c = PathIntegralController::ship(ShipParams::paper(0.01), ship_cost(), cfg).unwrap();
    c.set_goal(&[2.0, 0.0, 0.0, 0.0]);
    let b = Gaussian::diagonal(&[0.0, 0.0, 0.0, 0.0], &[0.1; 4]);
    let mut u = [0.0; 2];
    let mut levels = vec![];
    for i in 0..10 {
        c.compute(i as f64 * 0.01, &b, &mut u).unwrap();
        levels.push((c.stats().belief_samples, c.stats().samples));
        assert!(u[0] > 0.0, "pushes toward the goal");
    }
    assert_eq!(levels[0], (8, 32));
    assert_eq!(*levels.last().unwrap(), (1, 0));
    assert!(levels
        .windows(2)
        .all(|w| w[1].0 * (6 + w[1].1) <= w[0].0 * (6 + w[0].1)));
    assert_eq!(c.stats().over_budget, 10);
}
