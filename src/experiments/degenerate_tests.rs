//! Tests of the degenerate-diffusion experiment.

use super::*;

/// A short seeded run: the chain filter (steady placement, 500 states)
/// loses no flight and its mean stays within a fraction of the Kalman
/// posterior's position std (0.027 m) of the exact Kalman mean, like
/// the 300-particle PF's; the Kalman row's gap is zero by definition.
#[test]
fn the_chain_filter_tracks_the_kalman_mean_on_the_attitude_held_quadrotor() {
    let args = ExperimentArgs {
        runs: Some(3),
        seed: 5,
        progress: false,
        params: vec![
            ("states".into(), "500".into()),
            ("particles".into(), "300".into()),
            ("horizon_s".into(), "2".into()),
        ],
        doc: &[],
    };
    let rep = run(&args).unwrap();
    let v = serde_json::to_value(&rep.results).unwrap();
    let get = |m: &str| {
        v.as_array()
            .unwrap()
            .iter()
            .find(|r| r["method"] == m)
            .unwrap_or_else(|| panic!("no {m} row in {v}"))
            .clone()
    };
    let f = |r: &serde_json::Value, k: &str| r[k].as_f64().unwrap();
    let (chain, kalman, pf) = (get("chain-steady"), get("kalman"), get("pf"));
    assert_eq!(f(&chain, "lost"), 0.0, "{chain}");
    assert_eq!(f(&kalman, "lost"), 0.0, "{kalman}");
    let gap = f(&chain, "gap_kalman");
    assert!(gap < 0.5 * 0.027, "chain gap to Kalman {gap}");
    assert!(gap < 2.0 * f(&pf, "gap_kalman"), "chain {gap} vs {pf}");
    let (ce, ke) = (f(&chain, "rmse"), f(&kalman, "rmse"));
    assert!(ce < 1.3 * ke, "chain rmse {ce} vs Kalman {ke}");
}

/// The 6-D option: three seeded 3 s flights, 1000 states around the
/// data-free P∞; the chain filter keeps the attitude (no flight lost)
/// and its position error stays within 1.5× the EKF's.
#[test]
fn the_six_dimensional_option_tracks_the_full_quadrotor() {
    let args = ExperimentArgs {
        runs: Some(3),
        seed: 2,
        progress: false,
        params: vec![
            ("model".into(), "6d".into()),
            ("states".into(), "1000".into()),
            ("particles".into(), "300".into()),
            ("horizon_s".into(), "3".into()),
        ],
        doc: &[],
    };
    let rep = run(&args).unwrap();
    let get = |m: &str| rep.results.iter().find(|r| r.method == m).unwrap();
    let (chain, ekf) = (get("chain-steady"), get("ekf"));
    assert_eq!(chain.get("lost"), Some(0.0));
    let (ce, ee) = (chain.get("rmse").unwrap(), ekf.get("rmse").unwrap());
    assert!(ce < 1.5 * ee, "chain {ce} vs EKF {ee}");
    assert!(chain.get("gap_kalman").is_none());
}

/// Re-installing the 6-D version at every step (100 Hz) compounds the
/// install's loss: the flights are lost within 3 s, and the report
/// names each lost run with the time its error passed the threshold,
/// which lies inside the flight.
#[test]
fn re_installing_every_step_loses_six_dimensional_flights_and_names_them() {
    let args = ExperimentArgs {
        runs: Some(2),
        seed: 1,
        progress: false,
        params: vec![
            ("model".into(), "6d".into()),
            ("states".into(), "500".into()),
            ("particles".into(), "100".into()),
            ("horizon_s".into(), "3".into()),
            ("recenter_hz".into(), "100".into()),
        ],
        doc: &[],
    };
    let rep = run(&args).unwrap();
    let chain = rep
        .results
        .iter()
        .find(|r| r.method == "chain-steady")
        .unwrap();
    let lost = chain.get("lost").unwrap();
    assert!(lost >= 1.0, "{:?}", rep.notes);
    let named: Vec<&String> = rep
        .notes
        .iter()
        .filter(|n| n.contains("chain-steady-500 lost run"))
        .collect();
    assert_eq!(named.len() as f64, lost, "{:?}", rep.notes);
    for n in named {
        let t: f64 = n
            .split("at t = ")
            .nth(1)
            .and_then(|s| s.split(' ').next())
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("no time in {n}"));
        assert!(t > 0.0 && t <= 3.0, "{n}");
    }
}
