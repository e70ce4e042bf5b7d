use super::*;
use crate::metrics::TruthView;
use crate::Registry;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::model::{Measurement, ObsMask};

fn system(p: InventoryParams) -> InventorySystem {
    InventorySystem {
        model: p.validate().unwrap(),
        params: p,
    }
}

/// A policy solve small enough for a unit test.
fn small(path: &std::path::Path, sigma: f64) -> InventoryParams {
    let d = InventoryParams::default();
    InventoryParams {
        sigma,
        policy: InventoryPolicyParams {
            path: path.display().to_string(),
            mc_samples: 20,
            cost_samples: 200,
            ..d.policy
        },
        ..d
    }
}

/// A policy file directly in the temp dir (each test removes it at its end).
fn temp(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("beliefbus-inv-{}-{name}.json", std::process::id()))
}

fn filter_ctx(sys: &InventorySystem) -> FilterContext {
    let (m, s) = sys.prior();
    FilterContext {
        seed: 7,
        sample_dt: 0.001,
        start: Gaussian::diagonal(&m, &s),
        resumed: false,
        t0: 0.0,
    }
}

/// The plant runs the stated dynamics on the `inventory-average`
/// experiment's random numbers: run 0 of its seed, period by period.
#[test]
fn the_plant_measures_x0_then_steps_on_the_experiments_demands() {
    let sys = system(InventoryParams::default());
    let n = 200;
    let sc = beliefbus_projection::inventory::sim::Scenario::new(&sys.model, 3, 0, n + 1);
    let mut plant = plant::InventoryPlant::new(&sys, &sys.initial_state(), 3).unwrap();
    let mut y = [0.0; 2];
    plant.step();
    assert_eq!(plant.state(), &[5.0, 0.0, 0.0], "the first sample is x_0's");
    plant.measure(&mut y);
    assert_eq!(y, [5.0 + 1.3 * sc.xi[0], 0.0]);
    let mut x = 5.0;
    for k in 0..n {
        let order = if k % 3 == 0 { 10.0 } else { 0.0 };
        plant.set_control(&[order]);
        plant.step();
        let s = plant.state();
        let d = sc.demand[k];
        assert_eq!(s[1], d, "step {k}");
        let a = usize::from(order > 0.0);
        assert_eq!(s[2], sys.model.cost(x, a, d), "step {k}");
        x = (x + order - d).max(0.0);
        assert_eq!(s[0], x, "step {k}");
        plant.measure(&mut y);
        assert_eq!(y, [x + 1.3 * sc.xi[k + 1], order]);
    }
    // An order is 0 or Q whatever the controller sends.
    plant.set_control(&[7.0]);
    assert_eq!(plant.control(), &[10.0]);
    plant.set_control(&[2.0]);
    assert_eq!(plant.control(), &[0.0]);
}

/// The backend is Algorithm 4 on the inventory model: driven by the same
/// observations and the same stream, it gives exactly the projected
/// beliefs of a bare [`ProjectionPf`] (the experiment's filter).
#[test]
fn the_filter_is_the_projection_pf_on_the_inventory_model() {
    let sys = system(InventoryParams::default());
    let ctx = filter_ctx(&sys);
    let mut f = filter::InventoryPpf::new(&sys, &ctx).unwrap();
    let fam = beliefbus_projection::Gaussian::new(1).unwrap();
    let prior = fam.params(&[5.0], &[1e-12]).unwrap();
    let mut bare = beliefbus_projection::ProjectionPf::new(fam, 200, &prior).unwrap();
    let mut rng = crate::rng::stream(7, 0);
    let mut plant = plant::InventoryPlant::new(&sys, &sys.initial_state(), 9).unwrap();
    let mask = ObsMask(0b11);
    for k in 0..50 {
        let order = if k % 4 == 0 { 10.0 } else { 0.0 };
        plant.step();
        let mut y = [0.0; 2];
        plant.measure(&mut y);
        f.predict(k as f64 * 1e-3, &[order]).unwrap();
        f.update(&Measurement {
            y: &y,
            mask,
            std: None,
        })
        .unwrap();
        if k == 0 {
            bare.initialize(&sys.model, &mut rng);
        } else {
            bare.predict(&sys.model, &[y[1]], &mut rng);
        }
        bare.update(&sys.model, &[y[0]]).unwrap();
        assert_eq!(f.projected(), bare.params(), "step {k}");
        let b = f.belief();
        assert_eq!(b.mean[0], bare.params().mean[0]);
        assert_eq!(b.cov_at(0, 0), bare.params().cov[(0, 0)]);
        plant.set_control(&[order]);
    }
    // A measurement without the applied order is refused.
    let e = f.update(&Measurement {
        y: &[1.0, 0.0],
        mask: ObsMask(0b01),
        std: None,
    });
    assert!(e.is_err());
}

#[test]
fn belief_mdp_needs_a_current_policy_and_names_the_command() {
    let path = temp("stale");
    let _ = std::fs::remove_file(&path);
    let sys = system(small(&path, 1.3));
    let e = sys.controller(
        BELIEF_MDP,
        &ControlContext {
            seed: 1,
            sample_dt: 1e-3,
        },
    );
    let e = e.unwrap().err().unwrap();
    assert!(e.contains("no policy file"), "{e}");
    let cmd = format!(
        "`beliefbus solve inventory --set inventory.policy.mc_samples=20 \
         --set inventory.policy.cost_samples=200 --out {}`",
        path.display()
    );
    assert!(e.contains(&cmd), "{e}");

    // Solved for σ = 0.5, used at σ = 1.3: stale, naming the field.
    let other = system(small(&path, 0.5));
    let mut log = Vec::new();
    let out = other
        .solve(SolveRequest {
            out: None,
            threads: 1,
            progress: &mut |m: &str| log.push(m.to_string()),
        })
        .unwrap()
        .unwrap();
    assert_eq!(out.path, path);
    assert!(!log.is_empty());
    let e = sys
        .controller(
            BELIEF_MDP,
            &ControlContext {
                seed: 1,
                sample_dt: 1e-3,
            },
        )
        .unwrap()
        .err()
        .unwrap();
    assert!(e.contains("stale") && e.contains("sigma"), "{e}");
    assert!(e.contains(&cmd), "{e}");
    assert!(other
        .solve_command()
        .contains(" --set inventory.sigma=0.5 "));
    assert!(other
        .controller(
            BELIEF_MDP,
            &ControlContext {
                seed: 1,
                sample_dt: 1e-3
            }
        )
        .unwrap()
        .is_ok());
    let _ = std::fs::remove_file(&path);
}

/// `belief-mdp` orders what the solved table says at the nearest grid
/// point of (mean, std), and the table is the experiment's threshold-like
/// policy: order at an empty store, not with a full one.
#[test]
fn belief_mdp_looks_up_the_nearest_grid_point() {
    let path = temp("lookup");
    let sys = system(small(&path, 1.3));
    sys.solve(SolveRequest {
        out: None,
        threads: 1,
        progress: &mut |_| {},
    })
    .unwrap()
    .unwrap();
    let policy = sys.load_policy().unwrap();
    let mut ctl = control::BeliefMdp::new(&sys).unwrap();
    let mut g = Gaussian::zeros(STATE);
    let mut u = [0.0];
    for (m, s) in [
        (0.2, 0.1),
        (3.26, 1.13),
        (7.74, 0.0),
        (9.9, 4.0),
        (30.0, 9.0),
    ] {
        g.mean[0] = m;
        g.set_cov(0, 0, s * s);
        ctl.compute(0.0, &g, &mut u).unwrap();
        let i = policy.grid.nearest(&[m, s]).unwrap();
        assert_eq!(u[0], policy.actions[i] as f64 * 10.0, "({m}, {s})");
    }
    g.mean[0] = 0.0;
    g.set_cov(0, 0, 0.0);
    ctl.compute(0.0, &g, &mut u).unwrap();
    assert_eq!(u[0], 10.0);
    g.mean[0] = 12.0;
    ctl.compute(0.0, &g, &mut u).unwrap();
    assert_eq!(u[0], 0.0);
    g.mean[0] = f64::NAN;
    assert!(ctl.compute(0.0, &g, &mut u).is_err());
    let _ = std::fs::remove_file(&path);
}

/// The report's full-observation shadow is the threshold policy on the
/// plant's demands: recomputed here independently from the recorded
/// demands, and our cost is the plant's.
#[test]
fn metrics_compare_with_the_threshold_policy_on_the_same_demands() {
    let sys = system(InventoryParams::default());
    let mut plant = plant::InventoryPlant::new(&sys, &sys.initial_state(), 5).unwrap();
    let mut m = metrics::InventoryMetrics::new(&sys);
    let (mut xf, mut ours, mut full) = (5.0, 0.0, 0.0);
    let n = 4000;
    let mut y = [0.0; 2];
    for seq in 0..=n {
        plant.step();
        plant.measure(&mut y);
        let x = plant.state().to_vec();
        let u = plant.control().to_vec();
        m.truth(&TruthView {
            seq,
            channel: 0,
            t_ns: seq * 1000,
            counted: true,
            x: &x,
            u: &u,
            y: &[x[0], 0.0],
        });
        if seq > 0 {
            let d = x[1];
            let a = usize::from(xf < 7.9);
            full += sys.model.cost(xf, a, d);
            xf = (xf + a as f64 * 10.0 - d).max(0.0);
            ours += x[2];
        }
        // A naive policy: order every other period.
        plant.set_control(&[if seq % 2 == 0 { 10.0 } else { 0.0 }]);
    }
    let r = m.report();
    let n = n as f64;
    assert_eq!(r["periods"], 4000);
    assert!(
        (r["average_cost"].as_f64().unwrap() - ours / n).abs() < 1e-9,
        "{r}"
    );
    assert!(
        (r["full_obs_cost"].as_f64().unwrap() - full / n).abs() < 1e-9,
        "{r}"
    );
    assert_eq!(r["truth_gaps"], 0);
}

#[test]
fn the_scenario_is_registered_with_its_backends() {
    let info = Registry::builtin().describe();
    let inv = info
        .iter()
        .flatten()
        .find(|i| i.name == "inventory")
        .unwrap();
    assert_eq!((inv.state, inv.obs, inv.control), (3, 2, 1));
    assert_eq!(inv.filters, [PPF]);
    assert_eq!(inv.controllers, [BELIEF_MDP, CE, "none"]);
    // The built-in config's section is the defaults (what `beliefbus solve
    // inventory` without --config solves for).
    let t: toml::Table = toml::from_str(InventoryScenario::CONFIG).unwrap();
    let p: InventoryParams = t["inventory"].clone().try_into().unwrap();
    assert_eq!(p, InventoryParams::default());
    assert_eq!(
        system(p).solve_command(),
        "beliefbus solve inventory",
        "the default section needs no --set"
    );
}
