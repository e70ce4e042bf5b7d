//! The live light-dark scenario through the whole multi-process pipeline:
//! a run without a solved policy is refused with the command to run,
//! `beliefbus solve light-dark` writes it (a short budget, so CI stays
//! fast), a policy solved for another problem is refused as stale, and the
//! run — the scenario's chain filter and `pomdp` controller, with the
//! background solve swapping improved policies in — reaches the goal in a
//! good fraction of its episodes and leaves no shared memory behind.

use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};

fn beliefbus(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_beliefbus"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

#[test]
fn the_light_dark_scenario_solves_its_policy_then_runs_it_live_with_swaps() {
    let dir = std::env::temp_dir().join(format!("beliefbus-light-dark-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let policy = dir.join("light-dark.alpha");
    let policy_set = format!("light-dark.policy.path={:?}", policy.display().to_string());
    let mut run_args = vec!["run", "--scenario", "light-dark", "--duration", "8"];
    run_args.extend(["--quiet", "--set", &policy_set]);
    // Background rounds of 1 s: several swaps within the run. At nice 0,
    // not the default 19: on a machine busy with other work a nice-19
    // thread gets ~1.5 % of a core and may not finish a round in the run.
    run_args.extend(["--set", "light-dark.policy.refine_round_s=1.0"]);
    run_args.extend(["--set", "light-dark.policy.refine_nice=0"]);

    // No policy yet: refused at validation, naming the command.
    let o = beliefbus(&dir, &run_args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    let cmd = format!("beliefbus solve light-dark --out {}", policy.display());
    assert!(
        err.contains("no policy file") && err.contains(&cmd),
        "{err}"
    );

    // Solve it (the command the error names, with a 0.3 s budget: the
    // budget is not part of the problem, so the file stays current). Short
    // on purpose: the background rounds must find a better policy during
    // the run (a 3 s policy's V̲(b₀) 457 is more than a 1 s round from it
    // reaches; a 0.3 s policy's 401 is not: 5 swaps in 8 s).
    let solve = [
        "solve",
        "light-dark",
        "--out",
        policy.to_str().unwrap(),
        "--set",
        "light-dark.policy.solve_s=0.3",
    ];
    let o = beliefbus(&dir, &solve);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        out.contains("lookup_ns") && out.contains("lower_b0"),
        "{out}"
    );
    // The on-line table is bounded by the capacity and smaller than the
    // solver's set (the vectors maximal at the simulated beliefs).
    let figure = |k: &str| {
        out.lines()
            .find_map(|l| l.trim().strip_prefix(&format!("{k} = ")))
            .and_then(|v| v.trim().parse::<f64>().ok())
            .unwrap_or_else(|| panic!("no {k} in {out}"))
    };
    let (table, full) = (figure("lookup_vectors"), figure("undominated_vectors"));
    assert!((1.0..=128.0).contains(&table) && table < full, "{out}");
    assert!(figure("table_loss") >= 0.0, "{out}");

    // Another process noise is another chain: stale, refused.
    let o = beliefbus(
        &dir,
        &[&run_args[..], &["--set", "light-dark.noise=0.2"]].concat(),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("stale") && err.contains("--set light-dark.noise=0.2"),
        "{err}"
    );

    // The live run.
    let report = dir.join("light-dark.json");
    let rep = report.to_str().unwrap();
    let o = beliefbus(&dir, &[&run_args[..], &["--report", rep]].concat());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "exit {:?}: {err}", o.status);
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(r["scenario"], "light-dark");
    assert_eq!(r["filter_backend"], "chain-pomdp");
    assert_eq!(r["controller"], "pomdp");
    for s in ["ingest", "filter", "control", "plant"] {
        let st = &r["stages"][s];
        assert!(st["processed"].as_u64().unwrap() > 500, "{s}: {st}");
        assert_eq!(st["rejected"], 0, "{s}: {st}");
        assert_eq!(st["exit_status"], "exit 0", "{s}");
    }
    let m = &r["scenario_metrics"]["light-dark"];
    let episodes = m["episodes"].as_u64().unwrap();
    assert!(episodes >= 20, "{m}");
    assert_eq!(m["truth_gaps"], 0, "{m}");
    assert_eq!(m["fallbacks"], 0, "{m}");
    // The 0.3 s policy and its improvements reach the goal in 71 of 71
    // live episodes (8 s, release); the scenario's unit tests ask ≥ 70 %
    // of the discrete problem's at 95 %; here the 95 % Wilson interval of
    // the live fraction must lie above 60 %.
    let ci = m["goal_fraction_ci95"].as_array().unwrap();
    assert!(ci[0].as_f64().unwrap() > 0.6, "{m}");
    // The background solve improved the 0.3 s policy during the run.
    assert!(m["policy_swaps"].as_u64().unwrap() >= 1, "{m}");
    // Lookup times and deadline misses are reported, not asserted (no
    // timing limits in tests; the figures are in docs and the notes).
    assert!(m["lookup_us_p50"].as_f64().unwrap() > 0.0, "{m}");

    // The launcher's own per-run prefix: nothing of it is left.
    let prefix = r["prefix"].as_str().unwrap();
    assert!(beliefbus::ipc::cleanup::resources(prefix).is_empty());
    assert_eq!(r["shared_memory"]["files_left"], 0);
    let _ = std::fs::remove_dir_all(&dir);
}
