//! Every experiment runs on a tiny setting and returns the project's JSON
//! shape (rows with `method`, numeric metrics with their `_se`), the
//! paper's rows, and refuses unknown or malformed parameters with a typed
//! error instead of running.

use beliefbus_changepoint::experiments::{all, find};
use beliefbus_changepoint::ChangepointError;

fn small(name: &str) -> Vec<(String, String)> {
    let kv = |k: &str, v: &str| (k.to_string(), v.to_string());
    match name {
        "changepoint-cv2" => vec![kv("n", "400"), kv("bounds", "0,1,inf"), kv("exact", "true")],
        "changepoint-tilt" => vec![kv("n", "400"), kv("ratios", "1,5")],
        "changepoint-unknown-rho" => vec![kv("n", "400"), kv("bounds", "1,2")],
        "arx-identify" => vec![
            kv("n", "600"),
            kv("windows", "50"),
            kv("forgetting", "0.98"),
        ],
        "arx-control" => vec![
            kv("n", "300"),
            kv("windows", "50"),
            kv("forgetting", "0.98"),
        ],
        _ => vec![kv("n", "300"), kv("particles", "20")],
    }
}

#[test]
fn every_experiment_returns_rows_beside_the_papers() {
    for e in all() {
        let rep =
            (e.run)(Some(2), 3, &small(e.name)).unwrap_or_else(|err| panic!("{}: {err}", e.name));
        assert_eq!(rep.experiment, e.name);
        assert!(!rep.results.is_empty(), "{}", e.name);
        for row in &rep.results {
            assert!(!row.method.is_empty());
            for (k, v) in &row.metrics {
                if let Some(base) = k.strip_suffix("_se") {
                    assert!(
                        row.metrics.contains_key(base),
                        "{}: {k} without {base}",
                        e.name
                    );
                }
                if let Some(x) = v.as_f64() {
                    assert!(x.is_finite(), "{}: {k} = {x}", e.name);
                }
            }
        }
        if e.name != "changepoint-step-cost" {
            assert!(!rep.paper.is_empty(), "{}: no paper rows", e.name);
        }
        let json = serde_json::to_value(&rep).unwrap();
        assert!(json["results"][0]["method"].is_string());
        assert!(rep.render().contains("-- ours --"));
    }
}

#[test]
fn bad_parameters_are_refused() {
    let exp = find("changepoint-cv2").unwrap();
    let unknown = vec![("nope".to_string(), "1".to_string())];
    assert!(matches!(
        (exp.run)(Some(1), 1, &unknown),
        Err(ChangepointError::Param { .. })
    ));
    let bad = vec![("bounds".to_string(), "1,x".to_string())];
    assert!(matches!(
        (exp.run)(Some(1), 1, &bad),
        Err(ChangepointError::Param { .. })
    ));
    let negative = vec![("bounds".to_string(), "-1".to_string())];
    assert!((exp.run)(Some(1), 1, &negative).is_err());
    assert!(matches!(
        (exp.run)(Some(0), 1, &[]),
        Err(ChangepointError::TooSmall { .. })
    ));
    let rho = vec![("rho".to_string(), "1.5".to_string())];
    assert!(matches!(
        (exp.run)(Some(1), 1, &rho),
        Err(ChangepointError::Probability { .. })
    ));
}
