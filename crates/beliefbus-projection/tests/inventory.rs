//! The inventory model, its policies, the projected-belief MDP and the
//! policy file against closed forms and known answers.

use beliefbus_projection::experiments::inventory::{scan_threshold, Protocol, Settings};
use beliefbus_projection::experiments::ExperimentArgs;
use beliefbus_projection::inventory::policies::{
    BeliefRule, BootstrapController, Controller, Observation,
};
use beliefbus_projection::inventory::Inventory;
use beliefbus_projection::policy::{Criterion, GridPolicy, PolicyError};
use beliefbus_projection::rng::stream;
use beliefbus_projection::solve::{solve_policy, SolveOptions};
use beliefbus_projection::{Gaussian, ParamGrid};

#[test]
fn expected_cost_matches_monte_carlo() {
    let m = Inventory::paper(1.0).unwrap();
    let mut rng = stream(4, 4);
    let n = 400_000;
    let demands: Vec<f64> = (0..n).map(|_| m.sample_demand(&mut rng)).collect();
    for &(x, a) in &[
        (0.0, 0),
        (3.0, 0),
        (7.7, 0),
        (7.7, 1),
        (-1.0, 1),
        (-2.0, 0),
        (14.0, 1),
    ] {
        let c: Vec<f64> = demands.iter().map(|&u| m.cost(x, a, u)).collect();
        let mean = c.iter().sum::<f64>() / n as f64;
        let sd = (c.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
        let exact = m.expected_cost(x, a);
        assert!(
            (mean - exact).abs() < 4.5 * sd / (n as f64).sqrt(),
            "x={x} a={a}: MC {mean} vs {exact}"
        );
    }
}

#[test]
fn greedy_orders_below_its_closed_form_threshold() {
    // E[g(x+Q)] = E[g(x)] at e^{−x/β} = Qh / ((h+s) β (1 − e^{−Q/β})):
    // x ≈ 7.80 for the paper's parameters, next to L* ≈ 7.7.
    let m = Inventory::paper(0.1).unwrap();
    let b = m.demand_mean;
    let x_star = -b * (m.q * m.h / ((m.h + m.s) * b * (1.0 - (-m.q / b).exp()))).ln();
    assert!((x_star - 7.80).abs() < 0.01, "{x_star}");
    let mut rng = stream(1, 1);
    for &(x, want) in &[(x_star - 0.05, 1), (x_star + 0.05, 0)] {
        // A filter started at x knows x exactly (all particles at x0).
        let m = Inventory::new(1.0, 10.0, 10.0, 5.0, 0.1, x).unwrap();
        let mut g = BootstrapController::new(50, BeliefRule::Greedy).unwrap();
        g.reset(&m, &mut rng).unwrap();
        let a = g
            .act(&m, Observation { y: x, x_true: x }, None, &mut rng)
            .unwrap();
        assert_eq!(a, want, "greedy at x = {x}");
    }
}

#[test]
fn threshold_scan_finds_the_full_observation_optimum() {
    // The notes' independent scan: minimum between 7.5 and 8.1.
    let args = ExperimentArgs {
        runs: Some(1),
        seed: 3,
        params: vec![("scan_steps".into(), "400000".into())],
    };
    let set = Settings::from_args(Protocol::Average, &args).unwrap();
    let (l, curve) = scan_threshold(&set, &Inventory::paper(1.0).unwrap()).unwrap();
    assert!((7.4..=8.2).contains(&l), "L* = {l}");
    let at = |x: f64| curve.iter().find(|c| (c.0 - x).abs() < 1e-9).unwrap().1;
    assert!(
        at(5.0) > at(l) + 0.3 && at(10.5) > at(l) + 0.3,
        "not convex around the optimum"
    );
}

#[test]
fn projected_mdp_policy_at_small_noise_is_the_full_observation_threshold() {
    // At σ = 0.1 the belief is nearly a point mass: on the std = 0 column
    // of the grid the solved policy must order below the threshold region
    // and not above it (L* ≈ 7.7–8.0; the grid's means step by 0.5).
    let m = Inventory::paper(0.1).unwrap();
    let grid = ParamGrid::inventory_paper();
    let fam = Gaussian::new(1).unwrap();
    let opts = SolveOptions::new(200, 5000, 7, 0);
    for crit in [Criterion::Discounted { gamma: 0.9 }, Criterion::Average] {
        let pol = solve_policy(&m, &fam, &grid, crit.clone(), &opts, m.key()).unwrap();
        for i in 0..31 {
            let mean = 0.5 * i as f64;
            let a = pol.act(&[mean, 0.0]).unwrap();
            if mean <= 6.5 {
                assert_eq!(a, 1, "{crit:?}: no order at mean {mean}");
            }
            if mean >= 9.0 {
                assert_eq!(a, 0, "{crit:?}: order at mean {mean}");
            }
        }
    }
}

#[test]
fn policy_files_round_trip_and_stale_ones_are_refused() {
    let m = Inventory::paper(0.5).unwrap();
    let grid = ParamGrid::new(vec![
        beliefbus_projection::Axis::range(0.0, 2.0, 14.0).unwrap(),
        beliefbus_projection::Axis::range(0.0, 1.0, 3.0).unwrap(),
    ])
    .unwrap();
    let fam = Gaussian::new(1).unwrap();
    let opts = SolveOptions::new(40, 200, 1, 1);
    let crit = Criterion::Discounted { gamma: 0.9 };
    let pol = solve_policy(&m, &fam, &grid, crit.clone(), &opts, m.key()).unwrap();
    let dir = std::env::temp_dir().join(format!("bbproj-policy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("p.json");
    pol.save(&path).unwrap();
    let back = GridPolicy::load_checked(&path, &pol.key).unwrap();
    assert_eq!(back, pol);
    // The same problem at another σ: the file is stale, and says why.
    let other = Inventory::paper(0.7).unwrap();
    let key = opts
        .key_fields(other.key(), &crit)
        .text("family", "gaussian")
        .text("grid", &serde_json::to_string(&grid).unwrap());
    match GridPolicy::load_checked(&path, &key) {
        Err(PolicyError::Stale {
            field,
            found,
            expected,
            ..
        }) => {
            assert_eq!(
                (field.as_str(), found.as_str(), expected.as_str()),
                ("sigma", "0.5", "0.7")
            );
        }
        other => panic!("expected a stale-policy error, got {other:?}"),
    }
    assert!(matches!(
        GridPolicy::load(&dir.join("none.json")),
        Err(PolicyError::Missing { .. })
    ));
    std::fs::write(&path, "{\"format\": 1}").unwrap();
    assert!(matches!(
        GridPolicy::load(&path),
        Err(PolicyError::Parse { .. })
    ));
    std::fs::remove_dir_all(&dir).unwrap();
}
