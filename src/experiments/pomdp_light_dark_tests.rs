use super::*;

fn setting() -> Setting {
    Setting {
        sigma: 0.1,
        eps: 0.1,
        rate: 0.1,
        match_mean: false,
        period: 0.0,
        kappa_drift: 1.0,
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

#[test]
fn continuous_simulation_of_a_blind_plan_matches_the_gaussian_answer() {
    let s = setting();
    let mut built = None;
    two_d(&[75], &[0.2], &s, 3, true, |z| {
        built = Some(z.cp.clone());
        Ok(())
    })
    .expect("75-state problem");
    let cp = built.expect("one size");
    let a = cp.offset + 2;
    assert_eq!(cp.control(a), Some(&[1.0, -1.0][..]));
    // Move along (1, −1) for `steps` decisions, then declare.
    let steps = 6;
    let no = cp.pomdp.n_obs();
    let mut action = vec![a; steps];
    action.push(0);
    let next: Vec<u32> = (0..=steps)
        .flat_map(|k| std::iter::repeat_n((k + 1).min(steps) as u32, no))
        .collect();
    let fsc = carry::Fsc {
        action,
        next,
        n_obs: no,
    };
    let (h, g) = (cp.period, cp.pomdp.discount);
    let travel = steps as f64 * h;
    let (goal, light) = (goal_2d(), light_2d());
    let obs = LightDarkObs { light, eps: s.eps };
    let c = carry::Continuous {
        sigma: s.sigma,
        obs: &obs,
        goal: &goal,
        start_mean: [1.5 - travel, -1.5 + travel],
        start_std: 0.05,
    };
    let (m, se) = carry::simulate_continuous(&cp, &fsc, &c, 4000, 100, 11);
    // x_T ~ N(goal centre, (0.05² + σ² T h) I): each coordinate within
    // ±0.2 with probability erf(0.2 / (sd √2)).
    let sd = (0.05f64.powi(2) + s.sigma.powi(2) * travel).sqrt();
    let z = 0.2 / (sd * std::f64::consts::SQRT_2);
    let p1 = 0.5 * beliefbus_core::math::truncnorm::ln_erf_diff(-z, z).exp();
    let p = p1 * p1;
    let cost: f64 = (0..steps).map(|k| -2.0 * h * g.powi(k as i32)).sum();
    let exact = cost + g.powi(steps as i32) * 1000.0 * (2.0 * p - 1.0);
    assert!(
        (m - exact).abs() < 4.0 * se,
        "simulated {m} ± {se}, exact {exact} (P(goal) = {p})"
    );
}
