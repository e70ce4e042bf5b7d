//! The live inventory scenario through the whole multi-process pipeline:
//! `beliefbus solve inventory` writes the projected-belief MDP's policy
//! (a small Monte Carlo size, so CI stays fast), a run without it is
//! refused with the command to run, and the run with it — the scenario's
//! own projection PF and `belief-mdp` controller on a discrete-time plant
//! — costs what the same policy costs off-line at the same σ, within a
//! statistical bound.

use beliefbus_projection::inventory::policies::ProjectedController;
use beliefbus_projection::inventory::sim::{batch_means, filter_rng, run_closed_loop, Scenario};
use beliefbus_projection::inventory::Inventory;
use beliefbus_projection::GridPolicy;
use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};

/// The small solve: N_s = 100, N_c = 5000 (the defaults are 500 and 20000).
const SMALL: [&str; 4] = [
    "--set",
    "inventory.policy.mc_samples=100",
    "--set",
    "inventory.policy.cost_samples=5000",
];

fn beliefbus(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_beliefbus"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

/// The policy's average cost off-line: the experiment's closed loop (the
/// projection PF with N = 200 and the table) over `periods` periods at
/// σ = 1.3, with its batch-means standard error.
fn offline_cost(policy: &GridPolicy, periods: usize) -> (f64, f64) {
    let model = Inventory::paper(1.3).unwrap();
    let mut ctl = ProjectedController::new(&model, 200, policy).unwrap();
    let sc = Scenario::new(&model, 11, 0, periods);
    let mut costs = vec![0.0; periods];
    run_closed_loop(&model, &mut ctl, &sc, &mut filter_rng(11, 0), &mut costs).unwrap();
    batch_means(&costs, 20)
}

#[test]
fn the_inventory_scenario_solves_its_policy_then_runs_it_live() {
    let dir = std::env::temp_dir().join(format!("beliefbus-inventory-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let policy = dir.join("policy.json");
    let policy_set = format!("inventory.policy.path={}", policy.display());
    let mut run_args = vec!["run", "--scenario", "inventory", "--duration", "4"];
    run_args.extend(["--quiet", "--set", &policy_set]);
    run_args.extend(SMALL);

    // No policy yet: refused at validation, naming the command.
    let o = beliefbus(&dir, &run_args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    let cmd = format!(
        "beliefbus solve inventory --set inventory.policy.mc_samples=100 --set inventory.policy.cost_samples=5000 --out {}",
        policy.display()
    );
    assert!(
        err.contains("no policy file") && err.contains(&cmd),
        "{err}"
    );

    // Solve it (the command the error names).
    let mut solve = vec!["solve", "inventory", "--out", policy.to_str().unwrap()];
    solve.extend(SMALL);
    let o = beliefbus(&dir, &solve);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("lookup_ns"), "{out}");

    // Solved for another σ: stale, refused.
    let o = beliefbus(
        &dir,
        &[&run_args[..], &["--set", "inventory.sigma=0.5"]].concat(),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("stale") && err.contains("sigma"), "{err}");

    // The live run.
    let report = dir.join("inventory.json");
    let rep = report.to_str().unwrap();
    let o = beliefbus(&dir, &[&run_args[..], &["--report", rep]].concat());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "exit {:?}: {err}", o.status);
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(r["scenario"], "inventory");
    assert_eq!(r["filter_backend"], "projection-pf");
    assert_eq!(r["controller"], "belief-mdp");
    for s in ["ingest", "filter", "control", "plant"] {
        let st = &r["stages"][s];
        assert!(st["processed"].as_u64().unwrap() > 1000, "{s}: {st}");
        assert_eq!(st["rejected"], 0, "{s}: {st}");
        assert_eq!(st["exit_status"], "exit 0", "{s}");
    }
    let m = &r["scenario_metrics"]["inventory"];
    let periods = m["periods"].as_u64().unwrap();
    assert!(periods > 3000, "{m}");
    assert_eq!(m["truth_gaps"], 0, "{m}");
    // (A loaded CI machine may deliver a few controls after the next period.)
    assert!(m["controlled_fraction"].as_f64().unwrap() > 0.9, "{m}");
    // The filter beats the raw count.
    assert!(
        m["filter_rmse"].as_f64().unwrap() < m["raw_rmse"].as_f64().unwrap(),
        "{m}"
    );

    // The same policy off-line (10⁵ periods, other random numbers): the
    // live average cost within 4 combined standard errors.
    let pol = GridPolicy::load(&policy).unwrap();
    let (off, off_se) = offline_cost(&pol, 100_000);
    let live = m["average_cost"].as_f64().unwrap();
    let live_se = m["average_cost_se"].as_f64().unwrap();
    let bound = 4.0 * (live_se * live_se + off_se * off_se).sqrt();
    assert!(
        (live - off).abs() < bound,
        "live {live} ± {live_se} vs off-line {off} ± {off_se}"
    );
    // Above the full-observation threshold policy on the same demands, by
    // less than the paper's largest deviation (5.3 % at σ = 3.3) plus
    // 4 paired standard errors.
    let dev = m["deviation"].as_f64().unwrap();
    let dev_se = m["deviation_se"].as_f64().unwrap();
    let full = m["full_obs_cost"].as_f64().unwrap();
    assert!(dev < 0.053 * full + 4.0 * dev_se, "{m}");
    assert!(dev > -4.0 * dev_se, "{m}");

    let prefix = r["prefix"].as_str().unwrap();
    assert!(beliefbus::ipc::cleanup::resources(prefix).is_empty());
    assert_eq!(r["shared_memory"]["files_left"], 0);
    let _ = std::fs::remove_dir_all(&dir);
}
