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
        "kappa_drift",
        "1",
        "kappa_f of the 2-D chain's holding time r^2/(kappa_F |FF'| + kappa_f r |f|)",
    ),
];

/// `--param rows=kernel|moment` (read directly: a word, not a number).
pub fn rows(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
) -> anyhow::Result<beliefbus_pomdp::chain_pomdp::Rows> {
    use beliefbus_pomdp::chain_pomdp::Rows;
    let raw = args
        .params
        .iter()
        .rev()
        .find(|(k, _)| k == "rows")
        .map(|(_, v)| v.trim().to_string());
    let rows = match raw.as_deref() {
        None | Some("kernel") => Rows::Kernel,
        Some("moment") => Rows::Moment,
        Some(v) => anyhow::bail!("--param rows: 'kernel' or 'moment', not '{v}'"),
    };
    rep.param(
        "rows",
        if rows == Rows::Moment {
            "moment"
        } else {
            "kernel"
        },
    );
    Ok(rows)
}

/// `--param goal_reward=state|cell`: true for `cell`.
pub fn cell_goal(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
) -> anyhow::Result<bool> {
    let raw = args
        .params
        .iter()
        .rev()
        .find(|(k, _)| k == "goal_reward")
        .map(|(_, v)| v.trim().to_string());
    let cell = match raw.as_deref() {
        None | Some("state") => false,
        Some("cell") => true,
        Some(v) => anyhow::bail!("--param goal_reward: 'state' or 'cell', not '{v}'"),
    };
    rep.param("goal_reward", if cell { "cell" } else { "state" });
    Ok(cell)
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
    let raw = args
        .params
        .iter()
        .rev()
        .find(|(k, _)| k == "budget")
        .map(|(_, v)| v.trim().to_string());
    let per_state = match raw.as_deref() {
        None | Some("fixed") => false,
        Some("per_state") => true,
        Some(v) => anyhow::bail!("--param budget: 'fixed' or 'per_state', not '{v}'"),
    };
    rep.param("budget", if per_state { "per_state" } else { "fixed" });
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

/// `--param edge=wall|cliff`: true for `cliff`.
pub fn cliff(
    args: &crate::experiments::ExperimentArgs,
    rep: &mut crate::experiments::ExperimentReport,
) -> anyhow::Result<bool> {
    let raw = args
        .params
        .iter()
        .rev()
        .find(|(k, _)| k == "edge")
        .map(|(_, v)| v.trim().to_string());
    let cliff = match raw.as_deref() {
        None | Some("wall") => false,
        Some("cliff") => true,
        Some(v) => anyhow::bail!("--param edge: 'wall' or 'cliff', not '{v}'"),
    };
    rep.param("edge", if cliff { "cliff" } else { "wall" });
    Ok(cliff)
}
