use super::*;

fn setting() -> Setting {
    Setting {
        sigma: 0.1,
        eps: 0.1,
        rate: 0.1,
    }
}

#[test]
fn one_d_policy_goes_to_the_light_before_the_goal() {
    let cp = one_d(&setting()).expect("1-D POMDP");
    let sol = solve(&cp.pomdp, &solve_opts(5.0, None), |_| {}).expect("solve");
    let mut light_first = 0;
    let seeds = 20;
    for seed in 0..seeds {
        let traj = trajectory(&cp, &sol.policy, seed, 200);
        if plot::visits_light_before_goal(&cp, &traj) {
            light_first += 1;
        }
    }
    // b₀ is uniform: without the light the agent cannot tell where it is,
    // so a policy that declares in the goal must have localised first.
    assert!(
        light_first >= 16,
        "{light_first}/{seeds} runs visited the light and then declared in the goal"
    );
    let (m, se) = expected_reward(&cp, &sol.policy, 400, 5).expect("simulate");
    assert!(m > 0.0, "expected reward {m} ± {se}");
}

#[test]
fn observation_likelihood_is_sharp_in_the_light_and_flat_in_the_dark() {
    let obs = LightDarkObs {
        light: Boxes(vec![(vec![0.9], 0.1)]),
        eps: 0.1,
    };
    let ll = |z: f64, y: f64| obs.log_likelihood(&[z], &[y]);
    // Light: σ = 0.1, a 0.2 miss costs 2 nats.
    assert!((ll(0.9, 0.9) - ll(0.9, 1.1) - 2.0).abs() < 1e-12);
    // Dark: σ = 10, the same miss costs 2e-4 nats.
    assert!((ll(0.0, 0.0) - ll(0.0, 0.2) - 2e-4).abs() < 1e-12);
}
