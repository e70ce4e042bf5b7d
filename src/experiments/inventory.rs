//! `inventory-average` and `inventory-discounted`: paper 004 (Zhou, Fu &
//! Marcus) §VI, Tables I and II — the inventory POMDP under the
//! projected-belief MDP policy, CE, CE-MLE and greedy. The computation lives
//! in the `beliefbus-projection` crate; this adapts its report to the
//! experiment JSON of DESIGN.md (same row shape, field by field).

use super::{ExperimentArgs, ExperimentReport, Row};
use beliefbus_projection::experiments as proj;

fn to_crate_args(args: &ExperimentArgs) -> proj::ExperimentArgs {
    proj::ExperimentArgs {
        runs: args.runs,
        seed: args.seed,
        params: args.params.clone(),
    }
}

fn to_report(r: proj::Report) -> ExperimentReport {
    let rows = |v: Vec<proj::Row>| {
        v.into_iter()
            .map(|r| Row {
                method: r.method,
                metrics: r.metrics,
            })
            .collect()
    };
    ExperimentReport {
        experiment: r.experiment,
        params: r.params,
        results: rows(r.results),
        paper: rows(r.paper),
        notes: r.notes,
    }
}

/// Table I: average cost per period, one run of 10⁵ periods per σ.
pub fn run_average(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    Ok(to_report(proj::inventory::run_average(&to_crate_args(
        args,
    ))?))
}

/// Table II: discounted cost (γ = 0.9), 1000 runs of horizon 40 per σ.
pub fn run_discounted(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    Ok(to_report(proj::inventory::run_discounted(&to_crate_args(
        args,
    ))?))
}
