use super::*;
use crate::chain_pomdp::tests::{lqg, quadratic, spec};
use crate::chain_pomdp::{build_with, GaussianObservation, Rows, Terminal};
use beliefbus_core::chain::{Chain, ChainConfig};
use beliefbus_core::rng::SimRng;
use rand::{RngExt, SeedableRng};

/// Φ(x) from erfc.
fn phi(x: f64) -> f64 {
    0.5 * ln_erfc(-x * FRAC_1_SQRT_2).exp()
}

/// A standard normal draw (Box–Muller).
fn normal(rng: &mut SimRng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[test]
fn without_drift_the_passage_probability_is_twice_the_gaussian_tail() {
    // Reflection principle: P(max_{s≤h} σW_s ≥ a) = 2 Φ(−a/(σ√h)).
    for &(a, sigma, h) in &[
        (0.05, 0.1, 0.5),
        (0.2, 0.1, 0.5),
        (1.0, 0.3, 2.0),
        (0.5, 0.1, 0.5),
    ] {
        let exact = 2.0 * phi(-a / (sigma * f64::sqrt(h)));
        let got = pass_prob(a, 0.0, sigma, h);
        assert!(
            (got - exact).abs() <= 1e-12 * exact.max(1e-300) + 1e-300,
            "a {a}: {got} vs {exact}"
        );
    }
    assert_eq!(pass_prob(0.0, -1.0, 0.1, 0.5), 1.0);
    assert_eq!(pass_prob(-0.1, 0.0, 0.1, 0.5), 1.0);
}

#[test]
fn with_drift_the_passage_probability_matches_bridged_monte_carlo() {
    // Paths of μs + σW_s on a grid; between grid points the probability
    // that the Brownian bridge from x₀ to x₁ (both below a) reaches a is
    // exp(−2(a − x₀)(a − x₁)/(σ²δ)): exact for the continuous path.
    let (sigma, h, steps, runs) = (0.1, 0.5, 20, 40_000);
    let de = h / steps as f64;
    let mut rng = SimRng::seed_from_u64(17);
    for &(a, mu) in &[(0.1, 0.2), (0.1, -0.2), (0.4, 1.0), (0.05, -1.0)] {
        let mut hit = 0usize;
        for _ in 0..runs {
            let mut x: f64 = 0.0;
            for _ in 0..steps {
                let next = x + mu * de + sigma * de.sqrt() * normal(&mut rng);
                let bridge = (-2.0 * (a - x) * (a - next) / (sigma * sigma * de)).exp();
                if next >= a || rng.random::<f64>() < bridge {
                    hit += 1;
                    break;
                }
                x = next;
            }
        }
        let mc = hit as f64 / runs as f64;
        let p = pass_prob(a, mu, sigma, h);
        let se = (p * (1.0 - p) / runs as f64).sqrt().max(1e-4);
        assert!((mc - p).abs() < 4.0 * se, "a {a}, μ {mu}: {mc} vs {p}");
    }
}

#[test]
fn in_the_far_tail_the_passage_stays_between_its_elementary_bounds() {
    // P(X_h ≥ a) ≤ P(max ≥ a), and for μ ≥ 0, a ≥ μh: max_s (μs + σW_s) ≤
    // μh + max σW, so P(max ≥ a) ≤ 2Φ((μh − a)/(σ√h)); for μ < 0 the
    // drift only lowers the path: P ≤ 2Φ(−a/(σ√h)). At σ = 0.01 the
    // factor e^{2μa/σ²} = e^{20000} overflows and Φ(·) underflows; their
    // product must still be a probability inside the bounds.
    let h = 0.5;
    for &sigma in &[0.1, 0.03, 0.01] {
        let s = sigma * f64::sqrt(h);
        for &(a, mu) in &[(1.0, 0.5), (1.0, 1.0), (0.6, 1.0), (1.0, -1.0), (0.3, -0.2)] {
            let p = pass_prob(a, mu, sigma, h);
            let z = (mu * h - a) / s;
            let lo = phi(z);
            let hi = 2.0 * if mu >= 0.0 { phi(z) } else { phi(-a / s) };
            assert!(p.is_finite(), "σ {sigma}, a {a}, μ {mu}: {p}");
            assert!(
                p >= lo * (1.0 - 1e-9) && p <= hi * (1.0 + 1e-9),
                "σ {sigma}, a {a}, μ {mu}: {p} outside [{lo}, {hi}]"
            );
        }
    }
    // Drift straight at a barrier 0.05 away over 0.5 s: almost surely.
    assert!(pass_prob(0.05, 1.0, 0.1, 0.5) > 1.0 - 1e-9);
}

#[test]
fn cliff_rows_send_the_leaving_mass_to_the_end_and_charge_it() {
    let m = lqg(0.3);
    let mut rng = SimRng::seed_from_u64(4);
    let mut pts: Vec<f64> = vec![-1.0, 1.0];
    pts.extend((0..38).map(|_| rng.random_range(-1.0..1.0)));
    let ch = Chain::batch(&m, ChainConfig::gaussian(1), &pts).expect("chain");
    let n = ch.len();
    let obs = GaussianObservation {
        model: &m,
        std: vec![0.3],
    };
    let us = [0.0, 1.0, -1.0];
    let mut sp = spec(n, &us, 0.5, 0.2);
    sp.terminal = Some(Terminal {
        reward: (0..n).map(|i| ch.state(i)[0]).collect(),
    });
    let plain = build_with(&ch, &m, &obs, &quadratic, &sp, Rows::Moment).expect("pomdp");
    let mut cp = plain.clone();
    let drift = |z: &[f64], u: &[f64], f: &mut [f64]| f[0] = -z[0] + u[0];
    let c = 1000.0;
    let worst = make_cliff(&mut cp, &drift, &[0.1], &[-1.0], &[1.0], c).expect("cliff");
    // The states on the edge leave at once.
    assert_eq!(worst, 1.0);
    let h = cp.period;
    for a in 0..cp.pomdp.n_actions() {
        let Some(u) = cp.control(a) else {
            assert_eq!(cp.pomdp.reward[a], plain.pomdp.reward[a]);
            assert_eq!(cp.pomdp.trans[a].row(3), plain.pomdp.trans[a].row(3));
            continue;
        };
        for s in 0..n {
            let z = cp.state(s)[0];
            let p_out = leave_prob(&[z], &[-z + u[0]], &[0.1], h, &[-1.0], &[1.0]);
            let (cols, vals) = cp.pomdp.trans[a].row(s);
            let sum: f64 = vals.iter().sum();
            assert!((sum - 1.0).abs() < 1e-12, "row {s} sums to {sum}");
            let end: f64 = cols
                .iter()
                .zip(vals)
                .filter(|&(&j, _)| j as usize == n)
                .map(|(_, &v)| v)
                .sum();
            assert!((end - p_out).abs() < 1e-12, "state {z}: {end} vs {p_out}");
            // Each surviving entry is the plain row's, scaled.
            let (pc, pv) = plain.pomdp.trans[a].row(s);
            for (&j, &v) in pc.iter().zip(pv) {
                let got = cp.pomdp.trans[a].get(s, j as usize);
                if (j as usize) < n && p_out < 1.0 {
                    assert!((got - v * (1.0 - p_out)).abs() < 1e-12);
                }
            }
            let dr = cp.pomdp.reward[a][s] - plain.pomdp.reward[a][s];
            assert!((dr + c * p_out).abs() < 1e-9, "{dr} vs {}", -c * p_out);
            if z.abs() == 1.0 {
                assert_eq!(p_out, 1.0);
            }
            // Deep inside, at rest: σ√h = 0.045 against ≥ 0.5 to go.
            if z.abs() < 0.5 && u[0] == 0.0 {
                assert!(p_out < 1e-20, "{z}: {p_out}");
            }
        }
    }
    // Without the terminal action there is no absorbing state to leave to.
    let mut no_end = build_with(
        &ch,
        &m,
        &obs,
        &quadratic,
        &spec(n, &us, 0.5, 0.2),
        Rows::Moment,
    )
    .expect("pomdp");
    assert!(make_cliff(&mut no_end, &drift, &[0.1], &[-1.0], &[1.0], c).is_err());
}
