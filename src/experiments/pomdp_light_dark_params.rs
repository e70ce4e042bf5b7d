//! The `--param` keys of `beliefbus experiment pomdp-light-dark` with
//! their defaults (printed by `--help`).

use beliefbus_core::experiment_params::{p, ParamDoc};

/// The documented parameters, in the order `--help` prints them.
pub const PARAMS: &[ParamDoc] = &[
    p("states", "75,150,300,600", "2-D chain sizes n"),
    p("solve_s", "60", "solver time per 2-D size (s)"),
    p(
        "anytime_s",
        "5,15,30,60",
        "solver budgets of the anytime curve at anytime_states (s)",
    ),
    p(
        "anytime_states",
        "150",
        "2-D chain size of the anytime curve",
    ),
    p("states_1d", "20", "regular 1-D chain states on [-1.9, 1.9]"),
    p("solve_1d_s", "10", "solver time of the 1-D problem (s)"),
    p("noise", "0.1", "diffusion sigma of dx = u dt + sigma dw"),
    p(
        "epsilon",
        "0.1",
        "observation sigma in the light (1/epsilon in the dark)",
    ),
    p(
        "rate",
        "0.1",
        "discount rate rho, gamma = exp(-rho h) (1/s)",
    ),
    p(
        "plot",
        "(none)",
        "write the 1-D belief trajectory to this SVG file",
    ),
    p(
        "carry_check",
        "0",
        "1: also value each previous plan off its chain (continuous simulation, carried)",
    ),
    p(
        "match_mean",
        "0",
        "1: chain rows consistent in the mean (E[dz] = u h at every state)",
    ),
    p(
        "period_s",
        "0",
        "decision period fixed across sizes (s); 0: the chain step of each size",
    ),
    p(
        "rows",
        "kernel",
        "transition rows: kernel (the thesis's) or moment (mean z + u h exactly, spread tr(FF'h) or the least the states allow)",
    ),
    p(
        "goal_reward",
        "state",
        "terminal reward at each state's point (state) or averaged over its Voronoi cell (cell)",
    ),
    p(
        "goal_states",
        "centre",
        "2-D chain states seeded in the goal: its centre (centre) or also the four border points on its axes (cross)",
    ),
    p(
        "solves",
        "1",
        "independent 2-D solves (chains from seed, seed+1, ...), summarised per size in rows 'replicates'",
    ),
    p(
        "budget",
        "fixed",
        "2-D solver time per size: fixed (solve_s at every size) or per_state (solve_s * n / first n)",
    ),
    p(
        "open",
        "0",
        "1: also run each 2-D policy with no walls at the box edge (continuous_open, wall_frac_open)",
    ),
    p(
        "edge",
        "wall",
        "the 2-D box's edge: wall (the system stops there) or cliff (reaching it ends the episode with -1000), in the chain and the truth",
    ),
    p(
        "trial_gap",
        "0.5",
        "2-D solver: each trial aims at this fraction of the gap at b0 (0: the precision, HSVI2's deep trials)",
    ),
    p(
        "follow_lower",
        "0",
        "2-D solver: every k-th trial follows the lower bound's plan instead of the upper bound (0: never)",
    ),
    p(
        "eval_seed",
        "common",
        "2-D evaluations: common (every solve from seed, so one draw shifts all solves) or per_solve (solve r from seed + r; sizes stay paired within a solve)",
    ),
    p(
        "dump",
        "(none)",
        "write every 2-D solve's policy to DIR/solve<r>-n<states>.policy",
    ),
    p(
        "load",
        "(none)",
        "read every 2-D policy from DIR/solve<r>-n<states>.policy (as dump writes them) instead of solving",
    ),
    p(
        "trace",
        "(none)",
        "append each 2-D policy's declared continuous episodes to this CSV file",
    ),
    p(
        "kappa_drift",
        "1",
        "kappa_f of the 2-D chain's holding time r^2/(kappa_F |FF'| + kappa_f r |f|)",
    ),
];

/// The last `--param key=…` value as given (None: absent).
pub fn raw(args: &crate::experiments::ExperimentArgs, key: &str) -> Option<String> {
    args.params
        .iter()
        .rev()
        .find(|(k, _)| k == key)
        .map(|(_, v)| v.clone())
}

/// `--param anytime_s=s1,s2,…` (default 5, 15, 30, 60 s), recorded in the
/// report.
pub fn anytime(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
) -> anyhow::Result<Vec<f64>> {
    use anyhow::Context;
    let anytime: Vec<f64> = match raw(args, "anytime_s") {
        Some(s) => s
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .context("--param anytime_s: a list of seconds")?,
        None => vec![5.0, 15.0, 30.0, 60.0],
    };
    rep.param("anytime_s", serde_json::json!(anytime));
    Ok(anytime)
}

/// A two-word `--param key=off|on` (read directly: a word, not a number),
/// recorded in the report; true for `on`, `off` when absent.
fn word_choice(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
    key: &str,
    off: &str,
    on: &str,
) -> anyhow::Result<bool> {
    let raw = raw(args, key).map(|v| v.trim().to_string());
    let chosen = match raw.as_deref() {
        None => false,
        Some(v) if v == off => false,
        Some(v) if v == on => true,
        Some(v) => anyhow::bail!("--param {key}: '{off}' or '{on}', not '{v}'"),
    };
    rep.param(key, if chosen { on } else { off });
    Ok(chosen)
}

/// `--param rows=kernel|moment`.
pub fn rows(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
) -> anyhow::Result<beliefbus_pomdp::chain_pomdp::Rows> {
    use beliefbus_pomdp::chain_pomdp::Rows;
    Ok(if word_choice(args, rep, "rows", "kernel", "moment")? {
        Rows::Moment
    } else {
        Rows::Kernel
    })
}

/// `--param goal_reward=state|cell`: true for `cell`.
pub fn cell_goal(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
) -> anyhow::Result<bool> {
    word_choice(args, rep, "goal_reward", "state", "cell")
}

/// `--param goal_states=centre|cross`: true for `cross`.
pub fn goal_cross(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
) -> anyhow::Result<bool> {
    word_choice(args, rep, "goal_states", "centre", "cross")
}

/// Every `--param` key must be one of [`PARAMS`].
pub fn check_keys(args: &crate::experiments::ExperimentArgs) -> anyhow::Result<()> {
    match args
        .params
        .iter()
        .find(|(k, _)| !PARAMS.iter().any(|d| d.key == k.as_str()))
    {
        Some((k, _)) => anyhow::bail!("unknown --param '{k}'"),
        None => Ok(()),
    }
}

/// `--param budget=fixed|per_state`: the solver seconds of each size in
/// `sizes`, `solve_s` at every size or `solve_s · n / sizes[0]` (the
/// solver's work per backup grows with n, so a fixed budget buys the
/// larger chains fewer backups).
pub fn budgets(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
    sizes: &[usize],
    solve_s: f64,
) -> anyhow::Result<Vec<f64>> {
    let per_state = word_choice(args, rep, "budget", "fixed", "per_state")?;
    let first = sizes.first().copied().unwrap_or(1).max(1) as f64;
    Ok(sizes
        .iter()
        .map(|&n| {
            if per_state {
                solve_s * n as f64 / first
            } else {
                solve_s
            }
        })
        .collect())
}

/// `--param eval_seed=common|per_solve`: the evaluation seed of solve `r`
/// — `seed` for every solve (common random numbers across solves: a lucky
/// or unlucky draw moves every solve's figure together, and the spread
/// over solves does not see it), or `seed + r` (independent per solve, so
/// the spread over solves includes the evaluation's noise). Within a solve
/// every size uses the same seed either way, so sizes still pair.
pub fn eval_seeds(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
) -> anyhow::Result<fn(u64, u64) -> u64> {
    let per_solve = word_choice(args, rep, "eval_seed", "common", "per_solve")?;
    Ok(if per_solve {
        |seed, r| seed.wrapping_add(r)
    } else {
        |seed, _| seed
    })
}

/// `--param edge=wall|cliff`: true for `cliff`.
pub fn cliff(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
) -> anyhow::Result<bool> {
    word_choice(args, rep, "edge", "wall", "cliff")
}

/// The solver's settings of every light-dark solve: `secs` of budget, the
/// default trial gap.
pub fn solve_opts(
    secs: f64,
    initial: Option<beliefbus_pomdp::solver::graph::Controller>,
) -> beliefbus_pomdp::SolveOptions {
    solve_opts_gap(secs, initial, 0.5)
}

/// As [`solve_opts`] with the trial gap fraction `trial_gap`.
pub fn solve_opts_gap(
    secs: f64,
    initial: Option<beliefbus_pomdp::solver::graph::Controller>,
    trial_gap: f64,
) -> beliefbus_pomdp::SolveOptions {
    beliefbus_pomdp::SolveOptions {
        trial_gap_fraction: trial_gap,
        precision: 1e-2,
        time_limit: Some(std::time::Duration::from_secs_f64(secs)),
        threads: 1,
        initial_controller: initial,
        belief_flush: 1e-7,
        prune_lower: false,
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiments::{ExperimentArgs, ExperimentReport};

    fn args(kv: &[(&str, &str)]) -> ExperimentArgs {
        ExperimentArgs {
            params: kv
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect(),
            ..ExperimentArgs::default()
        }
    }

    #[test]
    fn a_word_param_takes_its_two_words_records_them_and_names_the_key_otherwise() {
        let mut rep = ExperimentReport::new("t");
        assert!(!cliff(&args(&[]), &mut rep).unwrap());
        assert_eq!(rep.params["edge"], "wall");
        assert!(cliff(&args(&[("edge", " cliff ")]), &mut rep).unwrap());
        assert_eq!(rep.params["edge"], "cliff");
        // The last of repeated keys wins.
        let two = args(&[("goal_reward", "cell"), ("goal_reward", "state")]);
        assert!(!cell_goal(&two, &mut rep).unwrap());
        assert_eq!(
            budgets(&args(&[("budget", "per_state")]), &mut rep, &[75, 150], 2.0).unwrap(),
            vec![2.0, 4.0]
        );
        let common = eval_seeds(&args(&[]), &mut rep).unwrap();
        assert_eq!(rep.params["eval_seed"], "common");
        assert_eq!((common(7, 0), common(7, 3)), (7, 7));
        let own = eval_seeds(&args(&[("eval_seed", "per_solve")]), &mut rep).unwrap();
        assert_eq!(rep.params["eval_seed"], "per_solve");
        assert_eq!((own(7, 0), own(7, 3)), (7, 10));
        let e = rows(&args(&[("rows", "moments")]), &mut rep).unwrap_err();
        assert_eq!(
            e.to_string(),
            "--param rows: 'kernel' or 'moment', not 'moments'"
        );
    }
}
