use super::*;
use beliefbus_pomdp::chain_pomdp::ObservationModel;

fn setting() -> Setting {
    Setting {
        sigma: 0.1,
        eps: 0.1,
        rate: 0.1,
        match_mean: false,
        period: 0.0,
        kappa_drift: 1.0,
        rows: Rows::Kernel,
        cell_goal: false,
        goal_cross: false,
        cliff: false,
        trial_gap: 0.5,
        follow_lower: 0,
        states_1d: 20,
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

fn two_d_75(s: &Setting) -> ChainPomdp {
    let mut built = None;
    two_d(&[75], &[0.2], s, 3, true, |z| {
        built = Some(z.cp.clone());
        Ok(())
    })
    .expect("75-state problem");
    built.expect("one size")
}

/// One vector with action `a`: the policy acts `a` at every belief.
fn constant_policy(cp: &ChainPomdp, a: usize) -> AlphaPolicy {
    let ns = cp.pomdp.n_states();
    AlphaPolicy {
        n_states: ns,
        n_actions: cp.pomdp.n_actions(),
        vectors: vec![vec![0.0; ns]],
        actions: vec![a],
    }
}

#[test]
fn declaring_at_once_in_continuous_space_earns_the_gaussian_goal_probability() {
    let s = setting();
    let cp = two_d_75(&s);
    let (goal, light) = (goal_2d(), light_2d());
    let obs = LightDarkObs { light, eps: s.eps };
    let std = 0.15;
    let p = continuous::Problem {
        sigma: s.sigma,
        obs: &obs,
        goal: &goal,
        start: continuous::Start::Gaussian {
            mean: vec![1.5, -1.5],
            std,
        },
        truth: WALLS,
    };
    let runs = 4000;
    let out = continuous::evaluate(&cp, &constant_policy(&cp, 0), &p, runs, 50, 7);
    // x₀ ~ N(goal centre, std² I); each coordinate within ±0.2 with
    // probability erf(0.2 / (std √2)).
    let z = 0.2 / (std * std::f64::consts::SQRT_2);
    let p1 = 0.5 * beliefbus_core::math::truncnorm::ln_erf_diff(-z, z).exp();
    let pg = p1 * p1;
    let exact = 1000.0 * (2.0 * pg - 1.0);
    assert!(
        (out.mean - exact).abs() < 4.0 * out.std_err,
        "simulated {} ± {}, exact {exact}",
        out.mean,
        out.std_err
    );
    let se_frac = (pg * (1.0 - pg) / runs as f64).sqrt();
    assert!((out.goal_frac - pg).abs() < 4.0 * se_frac);
    assert_eq!(out.declared_frac, 1.0);
}

#[test]
fn never_declaring_costs_exactly_the_discounted_control_cost() {
    let s = setting();
    let cp = two_d_75(&s);
    let a = cp.offset + 2;
    assert_eq!(cp.control(a), Some(&[1.0, -1.0][..]));
    let (goal, light) = (goal_2d(), light_2d());
    let obs = LightDarkObs { light, eps: s.eps };
    let p = continuous::Problem {
        sigma: s.sigma,
        obs: &obs,
        goal: &goal,
        start: continuous::Start::Uniform { lo: -2.0, hi: 2.0 },
        truth: WALLS,
    };
    let horizon = 37;
    let out = continuous::evaluate(&cp, &constant_policy(&cp, a), &p, 20, horizon, 1);
    let (h, g) = (cp.period, cp.pomdp.discount);
    let exact: f64 = (0..horizon).map(|k| -2.0 * h * g.powi(k as i32)).sum();
    assert!(
        (out.mean - exact).abs() < 1e-9 * exact.abs(),
        "{out:?} vs {exact}"
    );
    assert_eq!((out.std_err, out.declared_frac), (0.0, 0.0));
}

#[test]
fn one_d_policy_on_a_tracked_belief_overshoots_the_goal_as_the_live_sde_plant_does() {
    let s = setting();
    let cp = one_d(&s).expect("1-D POMDP");
    let sol = solve(&cp.pomdp, &solve_opts(5.0, None), |_| {}).expect("solve");
    // On its own chain the policy reaches the goal (the live `chain`
    // plant: ≥ 98 % of episodes), here it must be told apart from the
    // continuous system: the live `sde` plant (an independent
    // Euler–Maruyama plant feeding the `chain-pomdp` filter and the
    // α-vector controller) reached the goal in 0 of 69 episodes, because
    // at |u| = 1 the agent moves 0.29 per period where the chain moves one
    // 0.2 cell, and dead reckoning from the light overshoots ±0.1. The
    // evaluator must agree: 0/69 puts the goal fraction below 4.3 % at
    // 95 %, and 400 runs here have s.e. ≤ 1.5 %.
    let out = continuous_value(&cp, &sol.policy, &s, 1, 400, 5, WALLS);
    assert!(out.goal_frac < 0.1, "{out:?}");
    // The agent still localises and declares (it does not wander off):
    // nearly every episode ends with the terminal action.
    assert!(out.declared_frac > 0.95, "{out:?}");
    let (chain_value, _) = expected_reward(&cp, &sol.policy, 400, 5).expect("simulate");
    assert!(
        chain_value > 0.0 && out.mean < 0.0,
        "{chain_value} vs {out:?}"
    );
    // The same filter and lookup with the chain as the truth (the live
    // `chain` plant: ≥ 98 % of episodes in the goal): the loss above is
    // the system's, not the evaluator's.
    let on_chain = continuous_value(&cp, &sol.policy, &s, 1, 400, 5, Truth::Chain);
    assert!(
        on_chain.goal_frac >= 0.9 && on_chain.mean > 0.0,
        "{on_chain:?}"
    );
}

#[test]
fn sde_period_without_walls_has_the_exact_gaussian_moments_and_with_walls_stays_in_the_box() {
    // Free: x_T = x₀ + u T + σ √T ξ exactly, whatever the step count.
    let (sigma, de, steps) = (0.3, 0.05, 8);
    let t = de * steps as f64;
    let (x0, u) = ([1.9, -0.5], [1.0, -0.25]);
    let runs = 20_000;
    let mut rng = crate::rng::stream(9, 0);
    let (mut sum, mut sq) = ([0.0; 2], [0.0; 2]);
    let mut left = 0;
    for _ in 0..runs {
        let mut x = x0;
        let touched = continuous::sde_period(&mut x, &u, sigma, de, steps, Edge::Open, &mut rng);
        // Free, the last step's value is x itself: outside means touched.
        assert!(touched || x.iter().all(|v| v.abs() < 2.0), "{x:?}");
        left += usize::from(touched);
        for i in 0..2 {
            sum[i] += x[i];
            sq[i] += x[i] * x[i];
        }
    }
    let var = sigma * sigma * t;
    for i in 0..2 {
        let mean = sum[i] / runs as f64;
        let v = sq[i] / runs as f64 - mean * mean;
        let exact = x0[i] + u[i] * t;
        assert!(
            (mean - exact).abs() < 4.0 * (var / runs as f64).sqrt(),
            "axis {i}: mean {mean} vs {exact}"
        );
        // s.e. of a normal sample variance: var √(2/n).
        assert!((v - var).abs() < 4.0 * var * (2.0 / runs as f64).sqrt());
    }
    // x₁ starts 0.1 from the edge and drifts out at 1/s for 0.4 s: it
    // ends outside with probability Φ(0.3/0.19) ≈ 0.94, and leaves at
    // some step at least as often.
    assert!(left as f64 > 0.9 * runs as f64, "{left}");
    // Walls: every coordinate ends inside, and the touch is reported.
    let mut x = x0;
    assert!(continuous::sde_period(
        &mut x,
        &u,
        sigma,
        de,
        steps,
        Edge::Wall,
        &mut rng
    ));
    assert!(x.iter().all(|v| v.abs() <= 2.0), "{x:?}");
    // Far from the edge with u = 0 and σ√T = 0.19 nothing comes within 1.
    let mut x = [0.0, 0.5];
    assert!(!continuous::sde_period(
        &mut x,
        &[0.0, 0.0],
        sigma,
        de,
        steps,
        Edge::Wall,
        &mut rng
    ));
}

#[test]
fn wall_fraction_counts_the_episodes_that_reach_the_edge_and_open_truth_leaves_the_box() {
    let s = setting();
    let cp = two_d_75(&s);
    let a = cp.offset + 2;
    assert_eq!(cp.control(a), Some(&[1.0, -1.0][..]));
    let (goal, light) = (goal_2d(), light_2d());
    let obs = LightDarkObs { light, eps: s.eps };
    let problem = |truth| continuous::Problem {
        sigma: s.sigma,
        obs: &obs,
        goal: &goal,
        start: continuous::Start::Uniform { lo: -1.0, hi: 1.0 },
        truth,
    };
    // From |x| < 1 at (1, −1) per second the edge is reached within 3 s
    // (σ = 0.1): 40 periods are far longer.
    let h = cp.period;
    let horizon = (3.0 / h).ceil() as usize + 40;
    for edge in [Edge::Wall, Edge::Open] {
        let out = continuous::evaluate(
            &cp,
            &constant_policy(&cp, a),
            &problem(Truth::Sde(edge)),
            50,
            horizon,
            3,
        );
        assert_eq!(out.wall_frac, 1.0, "{edge:?}: {out:?}");
    }
    // Standing still for 2 periods (σ √(2h) ≤ 0.1) never comes within 1.
    let out = continuous::evaluate(
        &cp,
        &constant_policy(&cp, cp.offset),
        &problem(WALLS),
        50,
        2,
        3,
    );
    assert_eq!(cp.control(cp.offset), Some(&[0.0, 0.0][..]));
    assert_eq!(out.wall_frac, 0.0, "{out:?}");
}

#[test]
fn paired_difference_is_the_mean_and_standard_error_of_the_episode_differences() {
    let mk = |r: Vec<f64>| continuous::Outcome {
        mean: 0.0,
        std_err: 0.0,
        goal_frac: 0.0,
        declared_frac: 0.0,
        declare_dist: 0.0,
        belief_err: 0.0,
        lit_frac: 0.0,
        wall_frac: 0.0,
        crash_frac: 0.0,
        returns: r,
        ends: Vec::new(),
    };
    let a = mk(vec![5.0, 1.0, 10.0, 4.0]);
    let b = mk(vec![4.0, 1.0, 7.0, 4.0]);
    // Differences 1, 0, 3, 0: mean 1, sample variance (0 + 1 + 4 + 1)/3 = 2.
    let (d, se) = a.paired_diff(&b).expect("same length");
    assert_eq!(d, 1.0);
    assert!((se - (2.0f64 / 4.0).sqrt()).abs() < 1e-15);
    assert_eq!(a.paired_diff(&mk(vec![1.0; 3])), None);
}

#[test]
fn falling_off_the_cliff_in_one_period_has_the_chain_rows_first_passage_probability() {
    // The truth's bridged Euler steps and the chain's closed form
    // (chain_pomdp::cliff) must agree on P(reach the edge within h).
    let (sigma, h) = (0.1, 0.5);
    let de = h / continuous::EULER_STEPS as f64;
    let runs = 40_000;
    let mut rng = crate::rng::stream(21, 0);
    for (x0, u) in [
        ([1.9, 0.0], [0.0, 0.0]),
        ([1.8, -1.85], [0.2, 0.1]),
        ([0.0, 1.95], [0.5, -0.2]),
    ] {
        let mut fell = 0usize;
        for _ in 0..runs {
            let mut x = x0;
            fell += usize::from(continuous::sde_period(
                &mut x,
                &u,
                sigma,
                de,
                continuous::EULER_STEPS,
                Edge::Cliff,
                &mut rng,
            ));
        }
        let p = cliff::leave_prob(&x0, &u, &[sigma; 2], h, &[-2.0; 2], &[2.0; 2]);
        let mc = fell as f64 / runs as f64;
        let se = (p * (1.0 - p) / runs as f64).sqrt();
        assert!((mc - p).abs() < 4.0 * se + 1e-4, "x0 {x0:?}: {mc} vs {p}");
    }
}

#[test]
fn one_d_grid_is_regular_on_its_interval_with_a_uniform_start() {
    for n in [20, 40] {
        let s = Setting {
            states_1d: n,
            ..setting()
        };
        let cp = one_d(&s).expect("1-D POMDP");
        assert_eq!(cp.n_chain(), n);
        let step = 3.8 / (n - 1) as f64;
        for i in 0..n {
            assert!((cp.state(i)[0] - (-1.9 + step * i as f64)).abs() < 1e-12);
            assert!((cp.pomdp.start[i] - 1.0 / n as f64).abs() < 1e-15);
        }
    }
    let one = Setting {
        states_1d: 1,
        ..setting()
    };
    assert!(one_d(&one).is_err());
}

#[test]
fn per_solve_evaluation_seeds_change_the_simulations_and_nothing_else() {
    let s = Setting {
        rows: Rows::Moment,
        period: 0.5,
        ..setting()
    };
    let mut rep = ExperimentReport::new("t");
    let per_solve = vec![("eval_seed".to_string(), "per_solve".to_string())];
    let args = |params| ExperimentArgs {
        params,
        ..ExperimentArgs::default()
    };
    let common = params::eval_seeds(&args(vec![]), &mut rep).unwrap();
    let own = params::eval_seeds(&args(per_solve), &mut rep).unwrap();
    let key = |r: &Row, k: &str| r.get(k).unwrap_or_else(|| panic!("column {k}"));
    // Two sizes of one solve, each evaluated as solve 0 and as solve 2
    // under both choices, from the same solved policies.
    let mut rows = Vec::new();
    two_d(&[20, 40], &[1.0], &s, 5, false, |z| {
        let mut out = Vec::new();
        for (pick, r) in [(common, 0), (own, 0), (common, 2), (own, 2)] {
            let e = size_row::Eval {
                runs: 60,
                seed: pick(1, r),
                open: false,
                solve: r,
                trace: None,
            };
            out.push(size_row::size_row(z, &s, &e, &mut None)?);
        }
        rows.push(out);
        Ok(())
    })
    .expect("two sizes");
    for out in &rows {
        // The solve is the same object: its bounds are read, not re-made.
        for r in &out[1..] {
            for k in ["lower_b0", "upper_b0", "trials"] {
                assert_eq!(key(r, k), key(&out[0], k), "{k}");
            }
        }
        // Solve 0 keeps the common seed under either choice: identical rows.
        for k in ["reward", "reward_se", "continuous", "chain_truth"] {
            assert_eq!(key(&out[0], k), key(&out[1], k), "{k}");
            assert_eq!(key(&out[0], k), key(&out[2], k), "{k}");
        }
        // Solve 2 under per_solve: other random numbers in every
        // simulation (the chain's, the continuous truth's, the chain truth's).
        for k in ["reward", "continuous", "chain_truth"] {
            assert_ne!(key(&out[3], k), key(&out[2], k), "{k}");
        }
    }
    assert_eq!(rows.len(), 2);
}

/// The terminal reward R(s, u_goal) of the 2-D chain state nearest the
/// goal's centre, for chains from `seeds` at `n` states.
fn centre_rewards(s: &Setting, n: usize, seeds: std::ops::Range<u64>) -> Vec<f64> {
    let g = [1.5, -1.5];
    seeds
        .map(|seed| {
            let mut r = f64::NAN;
            two_d(&[n], &[0.05], s, seed, true, |z| {
                let i = (0..z.cp.n_chain())
                    .min_by(|&a, &b| {
                        let d = |i: usize| {
                            let x = z.cp.state(i);
                            (x[0] - g[0]).hypot(x[1] - g[1])
                        };
                        d(a).total_cmp(&d(b))
                    })
                    .unwrap();
                assert_eq!(z.cp.state(i), &g[..], "the goal's centre is a state");
                r = z.cp.pomdp.reward[0][i];
                Ok(())
            })
            .unwrap();
            r
        })
        .collect()
}

/// With the goal's four axis border points as states the centre's Voronoi
/// cell lies within |x − g|∞ ≤ 0.1 < 0.2, so its cell-averaged reward is
/// the full +1000 on every chain; with the centre alone it depends on
/// where the uniform samples fell (less on some of these chains).
#[test]
fn the_goal_cross_gives_the_centre_state_the_full_cell_reward() {
    let base = Setting {
        cell_goal: true,
        rows: Rows::Moment,
        period: 0.5,
        ..setting()
    };
    let cross = Setting {
        goal_cross: true,
        ..base
    };
    for r in centre_rewards(&cross, 150, 1..5) {
        assert_eq!(r, 1000.0);
    }
    let alone = centre_rewards(&base, 150, 1..5);
    assert!(alone.iter().any(|&r| r < 990.0), "{alone:?}");
}

/// `dump=DIR` creates DIR (a long run must not fail at its first policy)
/// and `load=DIR` re-evaluates exactly what was dumped: the same chain
/// reward and continuous value from the same seeds, without solving.
#[test]
fn dumped_policies_load_back_to_the_same_evaluation() {
    let dir = std::env::temp_dir().join(format!("beliefbus-ld-dump-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let nested = dir.join("a/b");
    let kv = |k: &str, v: &str| (k.to_string(), v.to_string());
    let common = [
        kv("states", "40"),
        kv("solve_s", "0.3"),
        kv("rows", "moment"),
        kv("period_s", "0.5"),
        kv("goal_reward", "cell"),
        kv("goal_states", "cross"),
        kv("solve_1d_s", "0.05"),
        kv("anytime_s", "0.05"),
        kv("anytime_states", "40"),
    ];
    let args = |extra: (String, String)| ExperimentArgs {
        runs: Some(40),
        seed: 3,
        params: common.iter().cloned().chain([extra]).collect(),
        ..ExperimentArgs::default()
    };
    let path = nested.display().to_string();
    let solved = run(&args(kv("dump", &path))).unwrap();
    let loaded = run(&args(kv("load", &path))).unwrap();
    let two_d_rows = |r: &ExperimentReport| -> Vec<(f64, f64)> {
        r.results
            .iter()
            .filter(|x| x.method == "chain-pomdp" && x.metrics["problem"] == "2-D")
            .map(|x| (x.get("reward").unwrap(), x.get("continuous").unwrap()))
            .collect()
    };
    let (a, b) = (two_d_rows(&solved), two_d_rows(&loaded));
    assert_eq!(a.len(), 1);
    assert_eq!(a, b);
    std::fs::remove_dir_all(&dir).unwrap();
}
