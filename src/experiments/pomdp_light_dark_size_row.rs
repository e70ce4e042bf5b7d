//! One 2-D size's row of `pomdp-light-dark`: the chain reward, the
//! continuous value under the setting's edge (with `wall_frac`,
//! `crash_frac`), the chain as truth, optionally the open box
//! (`continuous_open`, `open_minus_main` paired episode by episode), and
//! the paired step from the previous size of the same solve
//! (`continuous_step`, `open_step`).

use super::continuous::{value as continuous_value, Edge, Outcome, Truth};
use super::{expected_reward, Row, Setting, Sized};
use anyhow::Result;

/// The evaluation's settings.
pub struct Eval {
    pub runs: usize,
    pub seed: u64,
    /// Also run the policy with no wall at the box's edge.
    pub open: bool,
    /// Which independent solve this is.
    pub solve: u64,
    /// Append the main truth's declared episodes to this CSV file.
    pub trace: Option<String>,
}

/// The previous size's outcomes (main truth, open box) in this solve.
pub type Before = Option<(Outcome, Option<Outcome>)>;

/// The row of size `z`; `before` is read for the paired steps and then
/// replaced by this size's outcomes.
pub fn size_row(z: &Sized<'_>, s: &Setting, e: &Eval, before: &mut Before) -> Result<Row> {
    let cp = z.cp;
    let (m, se) = expected_reward(cp, &z.sol.policy, e.runs, e.seed)?;
    let tc = std::time::Instant::now();
    let c = continuous_value(cp, &z.sol.policy, s, 2, e.runs, e.seed, s.truth());
    let continuous_s = tc.elapsed().as_secs_f64();
    if let Some(path) = &e.trace {
        let goal = super::goal_2d();
        super::trace::append(path, e.solve, cp, &c, |x| goal.contains(x))?;
    }
    let on_chain = continuous_value(cp, &z.sol.policy, s, 2, e.runs, e.seed, Truth::Chain);
    let c_open = e.open.then(|| {
        continuous_value(
            cp,
            &z.sol.policy,
            s,
            2,
            e.runs,
            e.seed,
            Truth::Sde(Edge::Open),
        )
    });
    let row = Row::new("chain-pomdp")
        .text("problem", "2-D")
        .int("states", cp.n_chain() as u64)
        .int("solve", e.solve)
        .num("solve_s", z.sol.time_s)
        .int("trials", z.sol.trials)
        .num("reward", m)
        .num("reward_se", se)
        .num("reward_ci95", 1.96 * se);
    let mut row = c
        .columns(row)
        .num("continuous_s", continuous_s)
        .num("chain_truth", on_chain.mean)
        .num("chain_truth_se", on_chain.std_err)
        .num("chain_truth_goal_frac", on_chain.goal_frac)
        .num("lower_b0", z.sol.lower)
        .num("upper_b0", z.sol.upper)
        .num("period_s", cp.period)
        .int("controls", cp.controls.len() as u64)
        .int("observations", cp.observations.len() as u64);
    if let Some(c) = z.carried_b0 {
        row = row.num("carried_b0", c).num("carry_s", z.carry_s);
    }
    if let Some(o) = &c_open {
        row = row
            .num("continuous_open", o.mean)
            .num("continuous_open_se", o.std_err)
            .num("goal_frac_open", o.goal_frac)
            .num("wall_frac_open", o.wall_frac)
            .num(
                "open_minus_main",
                o.paired_diff(&c).map_or(f64::NAN, |d| d.0),
            )
            .num(
                "open_minus_main_se",
                o.paired_diff(&c).map_or(f64::NAN, |d| d.1),
            );
    }
    // Paired against the previous size of this solve.
    if let Some((pc, po)) = before.as_ref() {
        if let Some((d, dse)) = c.paired_diff(pc) {
            row = row.num("continuous_step", d).num("continuous_step_se", dse);
        }
        if let (Some(o), Some(po)) = (&c_open, po) {
            if let Some((d, dse)) = o.paired_diff(po) {
                row = row.num("open_step", d).num("open_step_se", dse);
            }
        }
    }
    *before = Some((c, c_open));
    Ok(row)
}
