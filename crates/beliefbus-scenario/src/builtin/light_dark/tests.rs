use super::control::PomdpController;
use super::encoding::{read_chain, EVENT_GOAL, EVENT_NONE, U_DECLARE, U_VERSION};
use super::flat::FlatPolicy;
use super::model::LightObs;
use super::*;
use crate::metrics::{ControlView, RunMetrics, TruthView};
use crate::rng::SimRng;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::model::Measurement;
use beliefbus_pomdp::AlphaPolicy;
use rand::{RngExt, SeedableRng};
use std::path::PathBuf;

fn system(f: impl FnOnce(&mut LightDarkParams)) -> LightDarkSystem {
    let mut p = LightDarkParams::default();
    f(&mut p);
    LightDarkSystem::new(p).expect("valid parameters")
}

fn fctx() -> FilterContext {
    FilterContext {
        seed: 1,
        sample_dt: 0.005,
        start: Gaussian::zeros(encoding::STATE),
        resumed: false,
        t0: 0.0,
    }
}

fn solved(sys: &LightDarkSystem, secs: f64) -> (AlphaPolicy, f64) {
    let sol = beliefbus_pomdp::solve(
        &sys.pomdp.pomdp,
        &sys.solve_options(secs, 1, Vec::new()),
        |_| {},
    )
    .expect("solve");
    (sol.policy, sol.lower)
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("bb-light-dark-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join("policy.alpha")
}

#[test]
fn the_pomdp_is_the_experiments_one_d_problem() {
    let sys = system(|_| {});
    let cp = &sys.pomdp;
    assert_eq!(cp.n_chain(), 20);
    // ⌊5 ln 20⌋ = 14 controls and the terminal action.
    assert_eq!(cp.controls.len(), 14);
    assert_eq!(cp.pomdp.n_actions(), 15);
    assert!((cp.state(0)[0] + 1.9).abs() < 1e-12 && (cp.state(19)[0] - 1.9).abs() < 1e-12);
    // u = ±1 moves one cell per period (the strongest controls jump
    // with probability δ/Δt = 1).
    let (cols, vals) = cp.pomdp.trans[cp.offset + 2].row(10);
    assert_eq!((cols, vals), (&[11u32][..], &[1.0][..]));
    // Only the goal's cell declares with +R.
    let r = &cp.pomdp.reward[0];
    let wins: Vec<usize> = (0..20).filter(|&i| r[i] > 0.0).collect();
    assert_eq!(wins, vec![5]);
    assert!((cp.state(5)[0] + 0.9).abs() < 1e-12);
}

#[test]
fn the_filter_is_the_chain_pomdps_belief_update() {
    let sys = system(|_| {});
    let cp = sys.pomdp.clone();
    let obs = sys.params.obs();
    let mut f = filter::ChainBeliefFilter::new(&sys, &fctx());
    let mut rng = SimRng::seed_from_u64(3);
    // Reference: the pomdp crate's (allocating) predict-then-update.
    let mut b = cp.pomdp.start.clone();
    let mut out = vec![0.0; b.len()];
    for k in 0..60 {
        let c = rng.random_range(0..cp.controls.len());
        let v = cp.controls[c][0];
        let y = rng.random_range(-2.5..2.5);
        let first = if k == 0 { 1.0 } else { 0.0 };
        let meas = [y, v, first];
        f.update(&Measurement::full(&meas)).expect("update");
        if k == 0 {
            // First sample: b₀ updated with y only.
            let mut w: Vec<f64> = (0..20)
                .map(|i| b[i] * obs.log_lik(cp.state(i)[0], y).exp())
                .collect();
            let t: f64 = w.iter().sum();
            w.iter_mut().for_each(|x| *x /= t);
            b[..20].copy_from_slice(&w);
        } else {
            assert!(cp.update(&b, cp.offset + c, &[y], &obs, &mut out));
            b.copy_from_slice(&out);
        }
        let got = f.chain_belief();
        for i in 0..20 {
            assert!((got[i] - b[i]).abs() < 1e-12, "step {k} state {i}");
        }
        // The message carries the same distribution, and its mean.
        let g = f.belief();
        assert_eq!(read_chain(&g), Some(got));
        let m: f64 = (0..20).map(|i| b[i] * cp.state(i)[0]).sum();
        assert!((g.mean[0] - m).abs() < 1e-12);
    }
}

#[test]
fn the_flat_lookup_picks_the_policys_best_vector() {
    let sys = system(|_| {});
    let (pol, lower) = solved(&sys, 1.0);
    let flat = FlatPolicy::new(&pol, 20, lower);
    let mut rng = SimRng::seed_from_u64(5);
    let mut b = vec![0.0; 21];
    for _ in 0..500 {
        b[..20]
            .iter_mut()
            .for_each(|v| *v = rng.random::<f64>().powi(4));
        let t: f64 = b.iter().sum();
        b.iter_mut().for_each(|v| *v /= t);
        // The same maximum as the plain sum over all 21 entries (up to
        // the last bits of a differently ordered sum), and an action of a
        // vector that attains it.
        let (_, v) = flat.best(&b[..20]);
        let v_ref = pol.value(&b);
        let tol = 1e-9 * v_ref.abs().max(1.0);
        assert!((v - v_ref).abs() <= tol, "{v} vs {v_ref}");
        let a = flat.act(&b[..20]);
        assert!(pol.vectors.iter().zip(&pol.actions).any(|(alpha, &act)| {
            act == a && (alpha.iter().zip(&b).map(|(x, p)| x * p).sum::<f64>() - v_ref).abs() <= tol
        }));
    }
    // Only dominated vectors were dropped.
    assert!(flat.len() <= pol.vectors.len());
}

#[test]
fn a_missing_or_stale_policy_is_refused_naming_the_command() {
    let path = tmp("stale");
    let set = |p: &mut LightDarkParams| p.policy.path = path.display().to_string();
    let sys = system(set);
    let err = PomdpController::new(&sys).err().expect("no file yet");
    assert!(err.contains("no policy file"), "{err}");
    assert!(
        err.contains(&format!(
            "`beliefbus solve light-dark --out {}`",
            path.display()
        )),
        "{err}"
    );
    let (pol, lower) = solved(&sys, 0.5);
    std::fs::write(&path, sys.policy_text(&pol, lower, 1e3, 0.5)).unwrap();
    let (back, lo) = sys.load_policy().expect("current");
    assert_eq!((back, lo), (pol, lower));
    // Another noise: another chain, a stale file.
    let other = system(|p| {
        set(p);
        p.noise = 0.2;
    });
    let err = PomdpController::new(&other).err().expect("stale");
    assert!(err.contains("stale"), "{err}");
    assert!(
        err.contains(&format!(
            "`beliefbus solve light-dark --set light-dark.noise=0.2 --out {}`",
            path.display()
        )),
        "{err}"
    );
    // Settings that do not change the problem keep it current.
    let same = system(|p| {
        set(p);
        p.plant = "sde".into();
        p.policy.solve_s = 99.0;
    });
    assert!(same.load_policy().is_ok());
    let _ = std::fs::remove_dir_all(path.parent().unwrap());
}

/// Plant, filter and controller in one loop (the stages' order, no IPC):
/// (episodes, goals).
fn closed_loop(sys: &LightDarkSystem, ctl: &mut PomdpController, episodes: u64) -> (u64, u64) {
    let mut plant = sys.plant(&[0.0; 3], 7, 0.01).unwrap();
    let mut f = filter::ChainBeliefFilter::new(sys, &fctx());
    let (mut n, mut goals) = (0, 0);
    let mut y = [0.0; 3];
    let mut u = [0.0; 4];
    while n < episodes {
        plant.step();
        let e = plant.state()[2];
        if e != EVENT_NONE {
            n += 1;
            goals += u64::from(e == EVENT_GOAL);
        }
        plant.measure(&mut y);
        f.update(&Measurement::full(&y)).expect("update");
        ctl.compute(0.0, &f.belief(), &mut u).expect("control");
        plant.set_control(&u);
    }
    (n, goals)
}

#[test]
fn the_solved_policy_reaches_the_goal_in_most_episodes() {
    let sys = system(|p| p.policy.refine_round_s = 0.0);
    let (pol, lower) = solved(&sys, 5.0);
    let mut ctl = PomdpController::with_policy(&sys, FlatPolicy::new(&pol, 20, lower));
    let (n, goals) = closed_loop(&sys, &mut ctl, 300);
    // V̲(b₀) ≤ γ^T R (2 P(goal) − 1) bounds the goal probability below by
    // (1 + V̲/R)/2 for a policy that declares within T steps; with the
    // time discount it is a loose bound, so ask for a fixed 70 % with the
    // 95 % Wilson interval.
    let (lo, _) = metrics::wilson(goals, n);
    assert!(
        lo > 0.7,
        "{goals}/{n} episodes reached the goal (V̲ = {lower})"
    );
}

#[test]
fn the_bounded_table_acts_as_the_full_set_at_the_beliefs_it_was_built_for() {
    let sys = system(|p| p.policy.refine_round_s = 0.0);
    let (pol, lower) = solved(&sys, 2.0);
    let full = FlatPolicy::new(&pol, 20, lower);
    let beliefs = prune::sample_beliefs(&sys, &full, 200, 3);
    assert!(beliefs.len() >= 200 * 20);
    // Unbounded: every maximiser kept, the same action and value bit for
    // bit, and far fewer vectors than the solver's set.
    let (table, maximisers, loss) = prune::select(&full, &beliefs, usize::MAX);
    assert_eq!((table.len(), loss), (maximisers, 0.0));
    assert!(
        2 * table.len() < full.len(),
        "{} of {}",
        table.len(),
        full.len()
    );
    for b in beliefs.chunks_exact(20) {
        assert_eq!(table.act(b), full.act(b));
        assert_eq!(table.best(b).1, full.best(b).1);
    }
    // Half the capacity: the loss reported is the largest value lost at
    // these beliefs, and no belief loses more.
    let cap = (maximisers / 2).max(1);
    let (small, m, loss) = prune::select(&full, &beliefs, cap);
    assert_eq!((small.len(), m), (cap, maximisers));
    let mut worst = 0.0f64;
    for b in beliefs.chunks_exact(20) {
        let d = full.best(b).1 - small.best(b).1;
        assert!(d >= 0.0 && d <= loss, "{d} vs {loss}");
        worst = worst.max(d);
    }
    assert!(loss > 0.0);
    assert_eq!(worst, loss);
}

#[test]
fn the_bounded_tables_loss_elsewhere_is_within_its_lipschitz_bound() {
    let sys = system(|p| p.policy.refine_round_s = 0.0);
    let (pol, lower) = solved(&sys, 2.0);
    let full = FlatPolicy::new(&pol, 20, lower);
    // A capacity below the maximisers' count, so the loss is not zero.
    let (table, rep) = prune::bounded_table(&sys, &full, 6, 60, 11);
    assert_eq!(table.len(), 6);
    assert!(rep.maximisers > 6 && rep.loss > 0.0);
    let sampled = prune::sample_beliefs(&sys, &full, 60, 11);
    // Beliefs of another seed: V_full − V_table ≤ loss + 2 L ‖b − b′‖₁
    // at the nearest belief b′ of the first pass (a subset of B).
    let fresh = prune::sample_beliefs(&sys, &full, 10, 99);
    for b in fresh.chunks_exact(20).take(300) {
        let d = full.best(b).1 - table.best(b).1;
        let near = sampled
            .chunks_exact(20)
            .map(|c| c.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>())
            .fold(f64::INFINITY, f64::min);
        let bound = rep.loss + 2.0 * rep.slope * near;
        assert!(d >= 0.0 && d <= bound * (1.0 + 1e-12), "{d} > {bound}");
    }
}

#[test]
fn the_bounded_table_reaches_the_goal_as_the_full_set_does() {
    let sys = system(|p| p.policy.refine_round_s = 0.0);
    let (pol, lower) = solved(&sys, 5.0);
    let full = FlatPolicy::new(&pol, 20, lower);
    let mut ctl = PomdpController::bounded(&sys, full.clone());
    let table = ctl.policy().0.len();
    assert!(table <= sys.params.policy.lookup_capacity && table < full.len());
    let (n, goals) = closed_loop(&sys, &mut ctl, 300);
    let mut all = PomdpController::with_policy(&sys, full);
    let (n_all, goals_all) = closed_loop(&sys, &mut all, 300);
    // Same plant seed: 95 % Wilson intervals overlap, and above 70 %.
    let (lo, hi) = metrics::wilson(goals, n);
    let (lo_all, hi_all) = metrics::wilson(goals_all, n_all);
    assert!(lo > 0.7, "{goals}/{n} with {table} vectors");
    assert!(
        lo <= hi_all && lo_all <= hi,
        "{goals}/{n} vs {goals_all}/{n_all}"
    );
}

/// Nice levels of this process's threads named `pomdp-solve`
/// (`/proc/self/task/*/stat`, field 19).
fn solver_thread_nices() -> Vec<i64> {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return vec![];
    };
    tasks
        .flatten()
        .filter_map(|t| {
            let stat = std::fs::read_to_string(t.path().join("stat")).ok()?;
            // "tid (comm) state ...": fields after the comm's closing paren.
            let (head, rest) = stat.rsplit_once(") ")?;
            head.ends_with("(pomdp-solve").then_some(())?;
            rest.split_whitespace().nth(16)?.parse().ok()
        })
        .collect()
}

#[test]
fn the_background_solve_publishes_better_policies_the_controller_swaps_in() {
    let sys = system(|p| {
        p.policy.refine_round_s = 0.5;
        p.policy.refine_rounds = 4;
        p.policy.refine_nice = 7;
    });
    let (pol, lower) = solved(&sys, 0.3);
    let mut ctl = PomdpController::with_policy(&sys, FlatPolicy::new(&pol, 20, lower));
    assert_eq!(ctl.policy().1, 0);
    ctl.start_background();
    let started = std::time::Instant::now();
    // The solver thread runs at the configured nice level (no other test
    // uses 7; threads of other tests in this process may be named alike).
    while !solver_thread_nices().contains(&7) && started.elapsed().as_secs() < 10 {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    assert!(
        solver_thread_nices().contains(&7),
        "{:?}",
        solver_thread_nices()
    );
    // A 0.3 s policy is far from converged: the first 0.5 s round improves
    // it (wait up to a minute on a loaded machine).
    while !ctl.try_swap() && started.elapsed().as_secs() < 60 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let (p, version) = ctl.policy();
    assert!(version >= 1);
    assert!(p.lower_b0 > lower, "{} vs {lower}", p.lower_b0);
    // The swapped policy acts and reports its version.
    let mut f = filter::ChainBeliefFilter::new(&sys, &fctx());
    f.update(&Measurement::full(&[0.9, 0.0, 1.0])).unwrap();
    let mut u = [0.0; 4];
    ctl.compute(0.0, &f.belief(), &mut u).unwrap();
    assert_eq!(u[U_VERSION], version as f64);
}

#[test]
fn a_belief_without_a_chain_distribution_is_a_control_error() {
    let sys = system(|_| {});
    let (pol, lower) = solved(&sys, 0.2);
    let mut ctl = PomdpController::with_policy(&sys, FlatPolicy::new(&pol, 20, lower));
    let mut u = [0.0; 4];
    assert!(ctl.compute(0.0, &Gaussian::zeros(3), &mut u).is_err());
}

#[test]
fn the_metrics_count_episodes_goals_and_swaps() {
    let mut m = metrics::LightDarkMetrics::new();
    // seq: (counted, reward, event). Episode 0 is before the warm-up.
    let rows = [
        (false, 0.0, 0.0),
        (false, -0.29, 0.0),
        (true, 1000.0, 1.0), // ends episode 0 (not counted), starts 1
        (true, -0.29, 0.0),
        (true, -0.29, 0.0),
        (true, 1000.0, 1.0), // ends 1: 1000 − 0.58
        (true, -0.29, 0.0),
        (true, -1000.0, -1.0), // ends 2: −1000.29
        (true, 0.0, -2.0),     // ends 3 (timeout, no moves)
    ];
    let (u, y) = ([0.0; 4], [0.0; 3]);
    for (seq, &(counted, r, e)) in rows.iter().enumerate() {
        let x = [0.0, r, e];
        m.truth(&TruthView {
            seq: seq as u64,
            channel: 0,
            t_ns: 0,
            counted,
            x: &x,
            u: &u,
            y: &y,
        });
    }
    for (v, ns, declare) in [
        (0.0, 900.0, 0.0),
        (0.0, 1100.0, 1.0),
        (1.0, 1000.0, 0.0),
        (3.0, 2000.0, 0.0),
    ] {
        let mut c = [0.0; 4];
        c[U_VERSION] = v;
        c[encoding::U_LOOKUP_NS] = ns;
        c[U_DECLARE] = declare;
        m.control(&ControlView {
            sensor_seq: 0,
            sensor_channel: 0,
            u: &c,
            ok: true,
        });
    }
    let r = m.report();
    assert_eq!(r["episodes"], 3);
    assert_eq!(r["goal_reached"], 1);
    assert_eq!(r["declared_outside"], 1);
    assert_eq!(r["timeouts"], 1);
    let mean = (1000.0 - 0.58 - 1000.29 + 0.0) / 3.0;
    assert!((r["reward_per_episode"].as_f64().unwrap() - mean).abs() < 1e-9);
    assert_eq!(r["policy_swaps"], 3);
    assert_eq!(r["declarations"], 1);
    assert_eq!(r["lookup_us_p50"], 1.0);
    assert_eq!(r["lookup_us_max"], 2.0);
}

#[test]
fn bad_parameters_are_refused_naming_the_key() {
    let bad = |f: fn(&mut LightDarkParams)| {
        let mut p = LightDarkParams::default();
        f(&mut p);
        LightDarkSystem::new(p).expect_err("refused")
    };
    assert!(bad(|p| p.states = 60).contains("states"));
    assert!(bad(|p| p.epsilon = 0.0).contains("epsilon"));
    assert!(bad(|p| p.plant = "ode".into()).contains("plant"));
    assert!(bad(|p| p.goal = 2.5).contains("goal"));
    assert!(bad(|p| p.policy.refine_nice = 20).contains("refine_nice"));
    assert!(bad(|p| p.policy.refine_nice = -1).contains("refine_nice"));
}

#[test]
fn the_light_is_sharp_and_the_dark_is_flat() {
    let o = LightObs {
        light: 0.9,
        light_width: 0.1,
        eps: 0.1,
    };
    // Light: σ = 0.1, a 0.2 miss costs 2 nats; dark: σ = 10, 2e-4 nats.
    assert!((o.log_lik(0.9, 0.9) - o.log_lik(0.9, 1.1) - 2.0).abs() < 1e-12);
    assert!((o.log_lik(0.0, 0.0) - o.log_lik(0.0, 0.2) - 2e-4).abs() < 1e-12);
}
