use super::*;
use crate::control::path_integral::BeliefMode;
use crate::model::ship::ShipParams;
use crate::model::SdeModel;

const BASE: &str = r#"
[run]
scenario = "ship"
instance = "t"

[plant]
sensor_rate_hz = 100.0
integration_dt = 1e-4
initial_state = [3.0, 0.0, 0.0, 0.0]

[filter]
backend = "pf"
prior_mean = [3.0, 0.0, 0.0, 0.0]
prior_std = [0.5, 0.5, 0.3, 0.3]

[filter.pf]
particles = 200

[control]
backend = "none"

[stages.filter]
budget_us = 2000
"#;

fn err(text: &str, sets: &[&str]) -> ConfigError {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    load_str(text, &sets).unwrap_err()
}

#[test]
fn a_valid_config_loads_with_defaults_filled_in() {
    let c = load_str(BASE, &[]).unwrap();
    assert_eq!(c.run.scenario, "ship");
    assert_eq!(c.filter.pf.particles, 200);
    assert_eq!(c.stages.filter.budget_ns(), 2_000_000);
    assert_eq!(c.run.seed, 1);
    // No [ship] section: the scenario's defaults, the paper's at 100 Hz.
    assert_eq!(c.scenario_params::<ShipParams>().unwrap(), None);
    let ship = c.model().unwrap();
    let mut std = [0.0; 2];
    ship.obs_std(&mut std);
    assert_eq!(std[0], ShipParams::paper(0.01).range_std);
    assert_eq!(c.channels(2)[0].components, vec![0, 1]);
}

#[test]
fn unknown_keys_are_named_with_their_path() {
    let e = err(
        &format!("{BASE}\n[refine]\nperiod_ms = 5\nbogus = 1\n"),
        &[],
    );
    assert_eq!(e.key, "refine.bogus", "{e}");
    assert!(e.problem.contains("unknown field"), "{e}");
    let e = err(BASE, &["filter.pf.particlez=3"]);
    assert_eq!(e.key, "filter.pf.particlez", "{e}");
}

#[test]
fn wrong_types_are_named_with_their_path() {
    let e = err(BASE, &["filter.pf.particles=\"many\""]);
    assert_eq!(e.key, "filter.pf.particles", "{e}");
    assert!(e.problem.contains("invalid type"), "{e}");
    let e = err(BASE, &["plant.sensor_rate_hz=fast"]);
    assert_eq!(e.key, "plant.sensor_rate_hz", "{e}");
}

#[test]
fn every_error_is_one_line() {
    for e in [
        err(BASE, &["filter.pf.particles=\"many\""]),
        err("[run\nx=1", &[]),
        err(BASE, &["stages.filter.core=99"]),
        err(BASE, &["filter.backend=kalmanx"]),
    ] {
        let s = e.to_string();
        assert!(!s.contains('\n'), "multi-line: {s}");
        assert!(s.starts_with("config: "), "{s}");
    }
}

#[test]
fn overrides_are_validated_like_the_file() {
    let c = load_str(BASE, &["filter.backend=ekf".into(), "run.seed=9".into()]).unwrap();
    assert_eq!(c.filter.backend, FilterBackend::Ekf);
    assert_eq!(c.run.seed, 9);
    let e = err(BASE, &["plant.initial_state=[1.0, 2.0]"]);
    assert_eq!(e.key, "plant.initial_state");
    assert!(e.problem.contains("needs 4 entries"), "{e}");
    let e = err(BASE, &["filter.pf.particles=0"]);
    assert_eq!(e.key, "filter.pf.particles");
    let e = err(BASE, &["run.scenario.x=1"]);
    assert_eq!(e.key, "run.scenario");
    let e = err(BASE, &["novalue"]);
    assert!(e.problem.contains("KEY=VALUE"));
}

#[test]
fn semantic_checks_name_the_key() {
    let e = err(BASE, &["stages.control.core=64"]);
    assert_eq!(e.key, "stages.control.core");
    let e = err(BASE, &["plant.integration_dt=0.5"]);
    assert_eq!(e.key, "plant.integration_dt");
    let e = err(BASE, &["run.instance=\"a/b\""]);
    assert_eq!(e.key, "run.instance");
    let e = err(BASE, &["filter.prior_std=[1.0, 0.0, 1.0, 1.0]"]);
    assert_eq!(e.key, "filter.prior_std");
    let e = err(BASE, &["run.scenario=vanderpol"]);
    assert_eq!(e.key, "plant.initial_state", "{e}");
}

#[test]
fn syntax_errors_name_the_line() {
    let e = err("[run]\nscenario = \"ship\"\ninstance = \n", &[]);
    assert_eq!(e.key, "");
    assert!(e.problem.starts_with("line 3"), "{e}");
}

#[test]
fn the_default_config_runs_the_implicit_controller_and_mppi_stays_selectable() {
    let text = include_str!("../../../../configs/default.toml");
    let c = load_str(text, &[]).unwrap();
    assert_eq!(c.control.backend, ControlBackend::Implicit);
    assert_eq!(c.control.backend.name(), "implicit");
    assert_eq!(c.control.implicit.horizon_steps, 50);
    assert!(c.control.implicit.budget_us > 0.0);
    let c = load_str(text, &["control.backend=\"mppi\"".into()]).unwrap();
    assert_eq!(c.control.backend, ControlBackend::Mppi);
    let c = load_str(text, &["control.implicit.belief=\"sampled\"".into()]).unwrap();
    assert_eq!(c.control.implicit.belief, BeliefMode::Sampled);
    // Bad implicit keys are named with their path.
    let e = err(text, &["control.implicit.dt=0.0"]);
    assert_eq!(e.key, "control.implicit.dt", "{e}");
    let e = err(text, &["control.implicit.horizon=\"shrinking\""]);
    assert_eq!(e.key, "control.implicit.final_time", "{e}");
    let e = err(text, &["control.implicit.bogus=1"]);
    assert_eq!(e.key, "control.implicit.bogus", "{e}");
}

/// Hostile `--set` values that used to be accepted and then aborted,
/// wedged or exhausted the machine after the stages started: each is
/// refused at validation, naming its key.
#[test]
fn values_that_size_memory_work_or_time_are_bounded() {
    for (set, key) in [
        ("filter.pf.particles=1000000000000", "filter.pf.particles"),
        ("filter.pf.particles=1e12", "filter.pf.particles"),
        ("filter.pf.max_dt=1e-12", "filter.pf.max_dt"),
        ("filter.ekf.max_dt=1e-12", "filter.ekf.max_dt"),
        ("refine.knn_c=1e9", "refine.knn_c"),
        (
            "refine.reference_control=[1, 2, 3, 4, 5, 6, 7, 8, 9]",
            "refine.reference_control",
        ),
        ("refine.max_states=1000000", "refine.max_states"),
        ("run.duration_s=1e300", "run.duration_s"),
        ("run.warmup_s=1e300", "run.warmup_s"),
        ("run.stats_period_s=1e300", "run.stats_period_s"),
        (
            "filter.chain.prepare_budget_us=1e300",
            "filter.chain.prepare_budget_us",
        ),
        ("filter.max_obs_age_us=1e300", "filter.max_obs_age_us"),
        ("plant.integration_dt=1e-12", "plant.integration_dt"),
        ("plant.sensor_rate_hz=1e12", "plant.sensor_rate_hz"),
        ("control.mppi.samples=10000000000", "control.mppi.samples"),
        (
            "control.implicit.samples=100000000000",
            "control.implicit.samples",
        ),
        (
            "control.implicit.budget_us=1e300",
            "control.implicit.budget_us",
        ),
        ("stages.filter.budget_us=1e300", "stages.filter.budget_us"),
        (
            "stages.filter.spin_us=100000000000",
            "stages.filter.spin_us",
        ),
        (
            "stages.filter.restart.heartbeat_timeout_ms=1e300",
            "stages.filter.restart.heartbeat_timeout_ms",
        ),
        (
            "stages.filter.restart.reset_after_s=1e300",
            "stages.filter.restart.reset_after_s",
        ),
        ("refine.publish_period_ms=1e300", "refine.publish_period_ms"),
        ("control.belief_queue=0", "control.belief_queue"),
        ("control.belief_queue=257", "control.belief_queue"),
        ("plant.catch_up_periods=0", "plant.catch_up_periods"),
        ("plant.catch_up_periods=201", "plant.catch_up_periods"),
        ("plant.catch_up_periods=-1", "plant.catch_up_periods"),
    ] {
        let e = err(BASE, &[set]);
        assert_eq!(e.key, key, "{set}: {e}");
        assert_eq!(e.to_string().lines().count(), 1, "{e}");
    }
}

#[test]
fn memory_limits_follow_the_machine() {
    use super::limits::{chain_bytes, memory_cap};
    let cap = memory_cap() as f64;
    // 10⁷ particles of the 4-state ship take (2·4 + 4)·8 B each = 960 MB:
    // refused exactly when that is above this machine's share.
    let r = load_str(BASE, &["filter.pf.particles=10000000".into()]);
    assert_eq!(r.is_err(), 1e7 * 96.0 > cap, "{r:?}");
    // 200 000 chain states at the default k-NN constant: refused where the
    // snapshot channel's shared memory would not fit.
    let r = load_str(BASE, &["refine.max_states=200000".into()]);
    assert_eq!(r.is_err(), chain_bytes(4, 200_000, 1.5) > cap, "{r:?}");
    // What the shipped configs use is far inside.
    assert!(chain_bytes(4, 4000, 1.5) < 64e6);
}

#[test]
fn durations_at_the_limit_are_valid_durations() {
    use super::limits::{seconds, MAX_DURATION_S};
    assert!(seconds("k", MAX_DURATION_S, MAX_DURATION_S).is_ok());
    for bad in [f64::NAN, f64::INFINITY, -1.0, 1e300] {
        assert_eq!(seconds("k", bad, MAX_DURATION_S).unwrap_err().key, "k");
    }
    let c = load_str(BASE, &["run.duration_s=31536000".into()]).unwrap();
    assert_eq!(c.run.duration_s, MAX_DURATION_S);
}

#[test]
fn an_integration_step_too_coarse_for_the_model_is_refused_at_validation() {
    let text = include_str!("../../../../configs/vanderpol.toml");
    // Van der Pol's drift reaches ρ ≈ 8 /s: Euler–Maruyama at 50 ms would
    // bias the particle filter, RK4 at 100 ms the Kalman filters.
    let e = err(text, &["filter.pf.max_dt=0.05"]);
    assert_eq!(e.key, "filter.pf.max_dt", "{e}");
    assert!(e.problem.contains("too coarse"), "{e}");
    let e = err(text, &["filter.backend=ukf", "filter.ukf.max_dt=0.1"]);
    assert_eq!(e.key, "filter.ukf.max_dt", "{e}");
    assert!(load_str(text, &["filter.pf.max_dt=0.005".into()]).is_ok());
}

#[test]
fn backend_names_are_the_serde_names_and_parse_back() {
    let serde_name = |v: serde_json::Value| v.as_str().unwrap().to_string();
    for b in [
        FilterBackend::Pf,
        FilterBackend::Ekf,
        FilterBackend::Ukf,
        FilterBackend::Chain,
        FilterBackend::ProjectionPf,
        FilterBackend::Scenario("rbpf-changepoint".into()),
    ] {
        assert_eq!(serde_name(serde_json::to_value(&b).unwrap()), b.name());
        assert_eq!(b.to_string(), b.name());
        assert_eq!(b.name().parse::<FilterBackend>().unwrap(), b);
    }
    for b in [
        ControlBackend::Mppi,
        ControlBackend::Implicit,
        ControlBackend::None,
        ControlBackend::Scenario("arx-adaptive".into()),
    ] {
        assert_eq!(serde_name(serde_json::to_value(&b).unwrap()), b.name());
        assert_eq!(b.name().parse::<ControlBackend>().unwrap(), b);
    }
    // The names users write in configs and read in reports.
    assert_eq!(
        FilterBackend::BUILTIN,
        ["pf", "ekf", "ukf", "chain", "projection-pf"]
    );
    assert_eq!(ControlBackend::BUILTIN, ["mppi", "implicit", "none"]);
    // Any other name is a scenario's, refused at validation when the
    // scenario does not offer it, naming what it offers.
    assert_eq!(
        "PF".parse::<FilterBackend>().unwrap(),
        FilterBackend::Scenario("PF".into())
    );
    let e = err(BASE, &["filter.backend=PF"]);
    assert_eq!(e.key, "filter.backend");
    assert!(
        e.problem
            .contains("scenario ship offers: chain, pf, ekf, ukf"),
        "{e}"
    );
    let e = err(BASE, &["control.backend=arx-adaptive"]);
    assert_eq!(e.key, "control.backend");
    assert!(e.problem.contains("implicit, mppi, none"), "{e}");
}

#[test]
fn a_discrete_time_scenario_runs_only_its_own_backends() {
    let registry = crate::scenario::Registry::builtin();
    let arx = registry.get("arx").unwrap().config;
    let c = load_str(arx, &[]).unwrap();
    assert_eq!(
        c.filter.backend,
        FilterBackend::Scenario("rbpf-changepoint".into())
    );
    assert_eq!(
        c.control.backend,
        ControlBackend::Scenario("arx-adaptive".into())
    );
    assert!(c.model().is_err(), "no SDE model");
    assert_eq!(c.dims().unwrap().state, 6);
    // Built-in backends need an SDE model: refused, naming what it offers.
    let e = err(arx, &["filter.backend=pf"]);
    assert_eq!(e.key, "filter.backend");
    assert!(e.problem.contains("discrete-time"), "{e}");
    assert!(e.problem.contains("offers: rbpf-changepoint"), "{e}");
    let e = err(arx, &["control.backend=mppi"]);
    assert_eq!(e.key, "control.backend");
    assert!(e.problem.contains("offers: arx-adaptive, none"), "{e}");
    let e = err(arx, &["filter.backend=kalman"]);
    assert!(e.problem.contains("unknown backend \"kalman\""), "{e}");
    // The backends' own settings are checked before anything starts.
    let e = err(arx, &["arx.control.rule=19"]);
    assert!(e.problem.contains("rule must be 18 or 20"), "{e}");
    let e = err(arx, &["arx.filter.scheme=\"stratified\""]);
    assert!(e.problem.contains("scheme"), "{e}");
    assert!(load_str(arx, &["control.backend=none".into()]).is_ok());
}

#[test]
fn regularisation_and_collapse_fractions_are_keys_with_checked_values() {
    let c = load_str(
        BASE,
        &[
            "filter.pf.regularisation=0.5".into(),
            "filter.pf.collapse_fraction=0.05".into(),
            "filter.chain.collapse_fraction=0.02".into(),
        ],
    )
    .unwrap();
    assert_eq!(c.filter.pf.regularisation, 0.5);
    assert_eq!(c.filter.pf.collapse_fraction, 0.05);
    assert_eq!(c.filter.chain.collapse_fraction, 0.02);
    // Off by default.
    let d = load_str(BASE, &[]).unwrap();
    assert_eq!(d.filter.pf.regularisation, 0.0);
    for (set, key) in [
        ("filter.pf.regularisation=-1", "filter.pf.regularisation"),
        (
            "filter.pf.collapse_fraction=2",
            "filter.pf.collapse_fraction",
        ),
        (
            "filter.chain.collapse_fraction=-0.1",
            "filter.chain.collapse_fraction",
        ),
    ] {
        assert_eq!(err(BASE, &[set]).key, key, "{set}");
    }
}
