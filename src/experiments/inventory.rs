//! `inventory-average` and `inventory-discounted`: paper 004 (Zhou, Fu &
//! Marcus) §VI, Tables I and II — the inventory POMDP under the
//! projected-belief MDP policy, CE, CE-MLE and greedy. The computation lives
//! in the `beliefbus-projection` crate, which fills the workspace's
//! experiment report; this registers them.

use super::{ExperimentArgs, ExperimentReport};
use beliefbus_projection::experiments as proj;

fn to_crate_args(args: &ExperimentArgs) -> proj::ExperimentArgs {
    proj::ExperimentArgs {
        runs: args.runs,
        seed: args.seed,
        params: args.params.clone(),
    }
}

/// Table I: average cost per period, one run of 10⁵ periods per σ.
pub fn run_average(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    Ok(proj::inventory::run_average(&to_crate_args(args))?)
}

/// Table II: discounted cost (γ = 0.9), 1000 runs of horizon 40 per σ.
pub fn run_discounted(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    Ok(proj::inventory::run_discounted(&to_crate_args(args))?)
}
