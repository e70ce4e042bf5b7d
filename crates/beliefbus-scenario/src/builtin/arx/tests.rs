//! The `arx` scenario against independent answers: the plant's jump rate
//! and noise, the published belief against the filter's own predictive
//! (21) and change-point probabilities, the controller against rule (20)
//! on that predictive, and the report's oracle shadow against a plant the
//! oracle itself drives (ratio exactly 1).

use super::control::predictive;
use super::filter::ArxRbpfFilter;
use super::metrics::ArxMetrics;
use super::*;
use crate::backends::{ControlContext, FilterContext};
use crate::metrics::{BeliefView, ControlView, TruthView};
use beliefbus_changepoint::arx::control::uncertainty_adjusted;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::model::{Measurement, ObsMask};

fn system(p: ArxParams) -> ArxSystem {
    let (scheme, rule) = p.validate().unwrap();
    ArxSystem {
        params: p,
        scheme,
        rule,
        sample_dt: 1e-3,
    }
}

fn fctx(sys: &ArxSystem) -> FilterContext {
    FilterContext {
        seed: 7,
        sample_dt: sys.sample_dt,
        start: Gaussian::zeros(STATE),
        resumed: false,
        t0: 0.0,
    }
}

/// Jumps at rate ρ after t₀ (Poisson count within 4 s.d.), every θ in
/// the stability region, and y_t − θ_tᵀφ_t ~ N(0, 1) (mean and variance
/// within 4 s.e.); the measurement is (y_t, the input applied).
#[test]
fn the_plant_jumps_at_rate_rho_with_unit_noise() {
    let sys = system(ArxParams {
        rho: 0.01,
        ..ArxParams::default()
    });
    let mut p = plant::ArxLivePlant::new(&sys, &sys.initial_state(), 3).unwrap();
    let n = 40_000;
    let (mut jumps, mut s1, mut s2) = (0u64, 0.0, 0.0);
    let (mut y1, mut y2) = (0.0, 0.0);
    let mut y = [0.0; 2];
    for t in 0..n {
        let u = (t as f64 * 0.37).sin();
        p.set_control(&[u]);
        p.step();
        p.measure(&mut y);
        let x = p.state();
        assert_eq!(y, [x[3], u]);
        assert!(x[0].abs() + x[1].abs() < 1.0 || t < 3);
        if x[RUN_LENGTH] == 0.0 && t > 0 {
            jumps += 1;
        }
        let e = x[3] - (x[0] * -y1 + x[1] * -y2 + x[2] * u);
        s1 += e;
        s2 += e * e;
        (y2, y1) = (y1, x[3]);
    }
    let expect = 0.01 * (n as f64 - 3.0);
    assert!(
        (jumps as f64 - expect).abs() < 4.0 * expect.sqrt(),
        "{jumps} jumps, expected {expect}"
    );
    let nf = n as f64;
    let (m, v) = (s1 / nf, s2 / nf - (s1 / nf).powi(2));
    assert!(m.abs() < 4.0 / nf.sqrt(), "noise mean {m}");
    assert!(
        (v - 1.0).abs() < 4.0 * (2.0 / nf).sqrt(),
        "noise variance {v}"
    );
}

/// Run the backend on a plant; at every step check the published belief
/// against the underlying filter.
#[test]
fn the_belief_carries_the_filters_predictive_and_change_probabilities() {
    let sys = system(ArxParams {
        rho: 0.01,
        ..ArxParams::default()
    });
    let mut p = plant::ArxLivePlant::new(&sys, &sys.initial_state(), 5).unwrap();
    let mut f = ArxRbpfFilter::new(&sys, &fctx(&sys)).unwrap();
    let mut y = [0.0; 2];
    let prior = sys.theta_prior();
    for t in 1..=3000u64 {
        p.set_control(&[(t as f64 * 0.21).cos()]);
        p.step();
        p.measure(&mut y);
        f.predict(t as f64 * 1e-3, &[0.0]).unwrap();
        f.update(&Measurement {
            y: &y,
            mask: ObsMask(0b11),
            std: None,
        })
        .unwrap();
        let g = f.belief();
        assert_eq!((g.mean[3], g.mean[4]), (y[0], p.state()[4]));
        if t < T0 {
            continue;
        }
        // The θ block's first two moments are the predictive (21)'s.
        let (mean, second) = predictive(&g, sys.params.rho, &prior);
        let want = f.online().predictive();
        for a in 0..3 {
            assert!((mean[a] - want.mean[a]).abs() < 1e-9, "step {t}");
            for b in 0..3 {
                assert!((second[a][b] - want.second[a][b]).abs() < 1e-9, "step {t}");
            }
        }
        // r̂ is the median run length: a change in [t − r̂, t] has
        // posterior probability > ½, in [t − r̂ + 1, t] at most ½.
        let r = (g.mean[RUN_LENGTH] / sys.sample_dt).round() as u64;
        let since = t - r;
        if since > 1 {
            assert!(f.online().prob_change_since(since) > 0.5, "step {t}");
        }
        assert!(
            f.online().prob_change_since(since + 1) <= 0.5 + 1e-12,
            "step {t}"
        );
    }
}

/// Rule (20) from the belief is the experiment's rule (20) on the filter's
/// own predictive; rule (18) uses its mean; both aim at y*_{t+1}.
#[test]
fn the_controller_applies_the_rules_to_the_predictive() {
    for rule in [18, 20] {
        let mut params = ArxParams::default();
        params.control.rule = rule;
        params.control.delta = 0.0;
        let sys = system(params);
        let mut c = control::ArxAdaptive::new(
            &sys,
            &ControlContext {
                seed: 1,
                sample_dt: 1e-3,
            },
        )
        .unwrap();
        let mut g = Gaussian::zeros(STATE);
        g.mean[..5].copy_from_slice(&[0.3, -0.2, 0.9, 1.4, -0.6]);
        for (i, v) in [0.1, 0.05, 0.2].iter().enumerate() {
            g.set_cov(i, i, *v);
        }
        g.set_cov(0, 2, 0.02);
        g.set_cov(2, 0, 0.02);
        let k = 140; // step 141, target y*_142
        c.set_step(k);
        let mut u = [0.0];
        c.compute(0.0, &g, &mut u).unwrap();
        let (mean, second) = predictive(&g, sys.params.rho, &sys.theta_prior());
        let target = sys.params.reference(k + 2);
        let psi = [-1.4, 0.6, 0.0];
        let want = if rule == 20 {
            uncertainty_adjusted(&mean, &second, &psi, B1, target, 0.0, 0.0)
        } else {
            (target - mean[0] * psi[0] - mean[1] * psi[1]) / mean[2]
        };
        assert!(
            (u[0] - want).abs() < 1e-12,
            "rule {rule}: {} vs {want}",
            u[0]
        );
    }
}

fn feed(m: &mut ArxMetrics, seq: u64, x: &[f64; STATE], u: f64, counted: bool) {
    m.truth(&TruthView {
        seq,
        channel: 0,
        t_ns: seq,
        counted,
        x,
        u: &[u],
        y: &[x[3], u],
    });
}

/// A plant driven by the oracle's own rule: the shadow replays it exactly
/// (ratio 1); every step is controlled by the previous step's control; a
/// belief whose median run length reaches back to a change detects it.
#[test]
fn the_report_replays_the_oracle_and_times_detections() {
    let sys = system(ArxParams {
        rho: 0.005,
        ..ArxParams::default()
    });
    let mut m = ArxMetrics::new(&sys);
    let mut p = plant::ArxLivePlant::new(&sys, &sys.initial_state(), 9).unwrap();
    let prior = sys.theta_prior();
    let mut u = 0.0;
    let mut changes = Vec::new();
    for seq in 0..5000u64 {
        p.set_control(&[u]);
        p.step();
        let x: [f64; STATE] = p.state().try_into().unwrap();
        let step = seq + 1;
        if step > T0 && x[RUN_LENGTH] == 0.0 {
            changes.push(step);
        }
        feed(&mut m, seq, &x, u, true);
        // The oracle's input for the next step, published as a control.
        let target = sys.params.reference(step + 1);
        u = if step < T0 {
            target
        } else {
            let mut g = Gaussian::zeros(3);
            g.mean[..3].copy_from_slice(&x[..3]);
            let (mean, second) = predictive(&g, sys.params.rho, &prior);
            uncertainty_adjusted(&mean, &second, &[-x[3], -x[4], 0.0], B1, target, 0.0, 0.0)
        };
        m.control(&ControlView {
            sensor_seq: seq,
            sensor_channel: 0,
            u: &[u],
            ok: true,
        });
        // A belief that sees each change 4 steps late.
        let mut b = [0.0; STATE];
        let last = changes.last().copied().filter(|&c| step >= c + 4);
        b[RUN_LENGTH] = (step - last.unwrap_or(1)) as f64 * sys.sample_dt;
        m.belief(
            &BeliefView {
                sensor_seq: seq,
                sensor_channel: 0,
                ess: 0.0,
                filter_ns: 0,
                mean: &b,
                cov: &[0.0; STATE * STATE],
            },
            &TruthView {
                seq,
                channel: 0,
                t_ns: seq,
                counted: true,
                x: &x,
                u: &[u],
                y: &[x[3], u],
            },
        );
    }
    let r = m.report();
    assert!(
        (r["oracle_ratio"].as_f64().unwrap() - 1.0).abs() < 1e-9,
        "{r}"
    );
    // Seq 0 has no previous control.
    assert_eq!(r["controlled_fraction"].as_f64().unwrap(), 4999.0 / 5000.0);
    assert_eq!(r["change_points"].as_u64().unwrap() as usize, changes.len());
    assert!(!changes.is_empty());
    for d in r["detection_delays"].as_array().unwrap() {
        let close = changes
            .iter()
            .any(|&c| c > d["step"].as_u64().unwrap() && c < d["step"].as_u64().unwrap() + 4);
        // A change followed by another within 4 steps is detected with it.
        if !close && d["step"].as_u64().unwrap() + 4 <= 5000 {
            assert_eq!(d["delay"], 4, "{d}");
        }
    }
    assert_eq!(r["truth_gaps"], 0);
}
