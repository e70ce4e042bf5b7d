use super::*;
use crate::solver::{solve, SolveOptions};
use beliefbus_core::belief::Gaussian;
use beliefbus_core::chain::{Chain, ChainConfig};
use beliefbus_core::filter::chain_filter::ChainFilter;
use beliefbus_core::filter::BayesFilter;
use beliefbus_core::model::linear::LinearSde;
use beliefbus_core::model::{Bounds, Measurement};
use beliefbus_core::rng::SimRng;
use nalgebra::DMatrix;
use rand::{RngExt, SeedableRng};
use std::time::Duration;

/// dx = (−x + u) dt + 0.1 dw, y = x + σ v on [−1, 1].
pub(super) fn lqg(obs_std: f64) -> LinearSde {
    LinearSde::new(
        "lqg1",
        DMatrix::from_element(1, 1, -1.0),
        DMatrix::from_element(1, 1, 1.0),
        DMatrix::from_element(1, 1, 0.1),
        DMatrix::from_element(1, 1, 1.0),
        vec![obs_std],
        Bounds::new_box(&[-1.0], &[1.0]).expect("box"),
    )
}

pub(super) fn chain(model: &LinearSde, n: usize, seed: u64) -> Chain {
    let mut rng = SimRng::seed_from_u64(seed);
    let pts: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    Chain::batch(model, ChainConfig::gaussian(1), &pts).expect("chain")
}

pub(super) fn spec(
    n: usize,
    controls: &[f64],
    delta_max: f64,
    decision_min: f64,
) -> ChainPomdpSpec {
    ChainPomdpSpec {
        controls: controls.iter().map(|&u| vec![u]).collect(),
        observations: (0..9).map(|j| vec![-1.0 + 0.25 * j as f64]).collect(),
        delta_max,
        decision_min,
        discount_rate: 0.1,
        start: vec![1.0 / n as f64; n],
        row_flush: 0.0,
        obs_flush: 0.0,
        match_mean: false,
        terminal: None,
    }
}

pub(super) fn quadratic(z: &[f64], u: &[f64]) -> f64 {
    z[0] * z[0] + u[0] * u[0]
}

#[test]
fn rows_sum_to_one_and_follow_the_chain_rates_times_delta() {
    let m = lqg(0.3);
    let ch = chain(&m, 60, 1);
    let obs = GaussianObservation {
        model: &m,
        std: vec![0.3],
    };
    let us = [0.0, 0.5, -0.5, 0.2];
    let cp = build(&ch, &m, &obs, &quadratic, &spec(60, &us, 1.0, 0.0)).expect("pomdp");
    assert_eq!(cp.steps, 1);
    let delta = cp.delta;
    for (a, &u) in us.iter().enumerate() {
        for i in 0..ch.len() {
            let (cols, vals) = cp.pomdp.trans[a].row(i);
            let sum: f64 = vals.iter().sum();
            assert!(
                (sum - 1.0).abs() < 1e-12,
                "row {i} action {a} sums to {sum}"
            );
            // Jump rate δ/Δt(z,u) with Δt(z,u) = r²/(σ² + r|f(z,u)|)
            // recomputed here from the chain's radius (1-D: ‖FFᵀ‖ = σ²).
            let z = ch.state(i)[0];
            let r = ch.radius()[i];
            let dt = r * r / (0.01 + r * (u - z).abs());
            let stay = cp.pomdp.trans[a].get(i, i);
            assert!(
                (1.0 - stay - delta / dt).abs() < 1e-12,
                "state {i} u {u}: jump probability {} vs δ/Δt {}",
                1.0 - stay,
                delta / dt
            );
            assert!(delta <= dt * (1.0 + 1e-12));
            if u == 0.0 {
                // u = u₀: the chain's own jump probabilities, scaled.
                let (ccols, cprobs) = ch.row(i);
                for (&j, &p) in ccols.iter().zip(cprobs) {
                    let got = cp.pomdp.trans[a].get(i, j as usize);
                    assert!((got - delta / dt * p).abs() < 1e-12);
                }
                assert_eq!(cols.len(), ccols.len() + 1);
            }
        }
    }
}

#[test]
fn k_step_rows_are_the_power_of_the_one_step_rows() {
    let m = lqg(0.3);
    let ch = chain(&m, 30, 2);
    let obs = GaussianObservation {
        model: &m,
        std: vec![0.3],
    };
    let one = build(&ch, &m, &obs, &quadratic, &spec(30, &[0.3], 1.0, 0.0)).expect("one");
    let four = build(
        &ch,
        &m,
        &obs,
        &quadratic,
        &spec(30, &[0.3], 1.0, 3.5 * one.delta),
    )
    .expect("four");
    assert_eq!(four.steps, 4);
    let n = ch.len();
    for i in 0..n {
        let mut b = vec![0.0; n];
        b[i] = 1.0;
        let mut next = vec![0.0; n];
        for _ in 0..4 {
            one.predict(&b, 0, &mut next);
            std::mem::swap(&mut b, &mut next);
        }
        for (j, &bj) in b.iter().enumerate() {
            assert!((four.pomdp.trans[0].get(i, j) - bj).abs() < 1e-12);
        }
    }
}

#[test]
fn belief_update_over_chain_states_equals_the_chain_filters() {
    let sigma = 0.3;
    let m = lqg(sigma);
    let ch = chain(&m, 80, 3);
    let obs = GaussianObservation {
        model: &m,
        std: vec![sigma],
    };
    // δ_max below every holding time: both take δ = δ_max.
    let delta_max = 1e-3;
    let cp = build(
        &ch,
        &m,
        &obs,
        &quadratic,
        &spec(80, &[0.0, 0.4, -0.4], delta_max, 0.0),
    )
    .expect("pomdp");
    assert_eq!(cp.delta, delta_max);
    let mut filt = ChainFilter::new(m.clone(), ch.clone(), delta_max).expect("filter");
    assert_eq!(filt.delta(), delta_max);
    filt.set_flush(0.0);
    filt.set_collapse_fraction(0.0);
    filt.reset(0.0, &Gaussian::diagonal(&[0.6], &[0.2]));
    let mut b = filt.weights().to_vec();
    let mut next = vec![0.0; b.len()];
    let mut rng = SimRng::seed_from_u64(9);
    for k in 1..=40 {
        let y = [rng.random_range(-1.0..1.0)];
        assert!(cp.update(&b, 0, &y, &obs, &mut next));
        std::mem::swap(&mut b, &mut next);
        filt.predict(k as f64 * delta_max, &[0.0]).expect("predict");
        filt.update(&Measurement::full(&y)).expect("update");
        let diff = b
            .iter()
            .zip(filt.weights())
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(diff < 1e-10, "step {k}: beliefs differ by {diff}");
    }
}

#[test]
fn carried_solution_is_a_lower_bound_on_the_refined_problem() {
    let m = lqg(0.3);
    let obs = GaussianObservation {
        model: &m,
        std: vec![0.3],
    };
    let us = [0.0, 0.5, -0.5];
    let mut opts = SolveOptions {
        precision: 1e-4,
        time_limit: Some(Duration::from_millis(300)),
        threads: 1,
        ..Default::default()
    };
    let c1 = chain(&m, 20, 4);
    let p1 = build(&c1, &m, &obs, &quadratic, &spec(20, &us, 1.0, 0.2)).expect("p1");
    let s1 = solve(&p1.pomdp, &opts, |_| {}).expect("solve 1");
    let c2 = chain(&m, 40, 5);
    let p2 = build(&c2, &m, &obs, &quadratic, &spec(40, &us, 1.0, 0.2)).expect("p2");
    let cold = solve(&p2.pomdp, &opts, |_| {}).expect("cold");
    let carried = warm::carry(&p1, &s1.policy, &p2, Duration::from_secs(2), 1e-9);
    assert!(!carried.is_empty());
    let b0 = &p2.pomdp.start;
    let v0 = carried
        .iter()
        .map(|(a, _)| a.iter().zip(b0).map(|(x, y)| x * y).sum::<f64>())
        .fold(f64::NEG_INFINITY, f64::max);
    // A lower bound: never above the cold solve's upper bound at b₀.
    assert!(
        v0 <= cold.upper + 1e-9,
        "carried {v0} above upper {}",
        cold.upper
    );
    // Far better than the worst case min R/(1−γ).
    let (lo, _) = p2.pomdp.reward_range();
    assert!(v0 > 0.5 * lo / (1.0 - p2.pomdp.discount));
    // The carried set alone, used greedily, earns at least what it claims
    // at b₀ (the controller is evaluated with a fixed successor map; with
    // a map re-chosen per iteration the claim can exceed the earnings).
    let carried_policy = crate::AlphaPolicy {
        n_states: p2.pomdp.n_states(),
        n_actions: p2.pomdp.n_actions(),
        vectors: carried.iter().map(|c| c.0.clone()).collect(),
        actions: carried.iter().map(|c| c.1).collect(),
    };
    let sim_opts = crate::SimulateOptions {
        runs: 2000,
        seed: 9,
        precision: 1e-4,
        threads: 1,
    };
    let r = crate::simulate(&p2.pomdp, &carried_policy, &sim_opts).expect("simulate");
    assert!(
        r.mean >= v0 - 3.0 * r.std_err,
        "carried policy earns {} ± {} below its claim {v0}",
        r.mean,
        r.std_err
    );
    opts.initial_lower = carried;
    let warm = solve(&p2.pomdp, &opts, |_| {}).expect("warm");
    assert!(warm.lower >= v0 - 1e-12);
    assert!(warm.lower <= warm.upper + 1e-9);
    // The warm-started policy earns its lower bound, and never less than
    // the cold start's lower bound allows (both within the simulation's
    // error).
    let rw = crate::simulate(&p2.pomdp, &warm.policy, &sim_opts).expect("simulate");
    assert!(
        rw.mean >= warm.lower - 3.0 * rw.std_err,
        "warm policy earns {} ± {} below its bound {}",
        rw.mean,
        rw.std_err,
        warm.lower
    );
    assert!(
        rw.mean >= cold.lower.min(warm.lower) - 3.0 * rw.std_err,
        "warm policy earns {} ± {} below the cold lower bound {}",
        rw.mean,
        rw.std_err,
        cold.lower
    );
}

#[test]
fn solver_drops_supplied_vectors_that_no_plan_can_have() {
    let m = lqg(0.3);
    let obs = GaussianObservation {
        model: &m,
        std: vec![0.3],
    };
    let c = chain(&m, 20, 4);
    let p = build(
        &c,
        &m,
        &obs,
        &quadratic,
        &spec(20, &[0.0, 0.5, -0.5], 1.0, 0.2),
    )
    .expect("p");
    let opts = SolveOptions {
        precision: 1e-3,
        time_limit: Some(Duration::from_millis(300)),
        threads: 1,
        ..Default::default()
    };
    let honest = solve(&p.pomdp, &opts, |_| {}).expect("solve");
    // Rewards are costs (≤ 0): a vector of zeros is above every plan's
    // value, and would end the solve at once with a false lower bound.
    let false_bound = SolveOptions {
        initial_lower: vec![(vec![0.0; p.pomdp.n_states()], 0)],
        ..opts.clone()
    };
    let sol = solve(&p.pomdp, &false_bound, |_| {}).expect("solve");
    assert!(sol.lower <= sol.upper + 1e-9);
    assert!(
        sol.lower < -1e-3,
        "lower bound {} kept the false vector",
        sol.lower
    );
    assert!(
        sol.lower <= honest.upper + 1e-9,
        "lower {} above the honest upper bound {}",
        sol.lower,
        honest.upper
    );
}
