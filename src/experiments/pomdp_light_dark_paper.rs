//! The thesis's figures beside `pomdp-light-dark`'s rows (Figs. 4-7 and
//! 4-8: SARSOP after 200 s) and the report's notes on its columns.

use super::{ExperimentReport, Row, PAPER_ANYTIME, PAPER_STATES};

/// Appends the paper rows and the notes to `rep`.
pub fn append(rep: &mut ExperimentReport) {
    for (n, r, pm) in PAPER_STATES {
        rep.paper.push(
            Row::new("sarsop-200s")
                .text("problem", "2-D")
                .int("states", n as u64)
                .num("solve_s", 200.0)
                .num("reward", r)
                .num("reward_ci95", pm),
        );
    }
    for (t, r, pm) in PAPER_ANYTIME {
        rep.paper.push(
            Row::new("anytime")
                .text("problem", "2-D")
                .int("states", 150)
                .num("solve_s", t)
                .num("reward", r)
                .num("reward_ci95", pm),
        );
    }
    rep.notes.push("continuous: the same policy's discounted return in the continuous problem (Euler-Maruyama truth, real-valued y, belief over the chain's states by the chain filter, argmax over the alpha-vectors each period; ±1000 by the true x); goal_frac: episodes declared inside the goal; same seeds and start draws at every size".into());
    rep.notes.push("reward: the discrete POMDP's discounted return from b0 over seeded runs; the paper's ± is listed under reward_ci95 (its kind of interval is not stated)".into());
    rep.notes.push(
        "solve_s: solver wall-clock on a shared, loaded 2-core machine (the paper: SARSOP, 200 s)"
            .into(),
    );
}
