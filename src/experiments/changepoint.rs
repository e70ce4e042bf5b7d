//! Paper 002 (Chen, Lai & Wu, fast particle filters for change-point
//! models): its experiments live in the `beliefbus-changepoint` crate; this
//! module registers them as `beliefbus experiment <name>` (the same report
//! type, `--param KEY=VALUE` validated by the crate).

use super::{ExperimentArgs, ExperimentReport};
use beliefbus_changepoint::experiments as cp;

fn run_named(name: &str, args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    let exp = cp::find(name)
        .ok_or_else(|| anyhow::anyhow!("experiment {name} missing from beliefbus-changepoint"))?;
    Ok((exp.run)(args.runs, args.seed, &args.params)?)
}

/// `changepoint-cv2` (Table 1).
pub fn cv2(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    run_named("changepoint-cv2", args)
}

/// `changepoint-tilt` (Table 2).
pub fn tilt(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    run_named("changepoint-tilt", args)
}

/// `changepoint-unknown-rho` (Table 3).
pub fn unknown_rho(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    run_named("changepoint-unknown-rho", args)
}

/// `arx-identify`.
pub fn arx_identify(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    run_named("arx-identify", args)
}

/// `arx-control`.
pub fn arx_control(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    run_named("arx-control", args)
}

/// `changepoint-step-cost`.
pub fn step_cost(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    run_named("changepoint-step-cost", args)
}

/// The registry entries, with the crate's descriptions.
pub fn experiments() -> Vec<super::Experiment> {
    type RunFn = fn(&ExperimentArgs) -> anyhow::Result<ExperimentReport>;
    let entries: [(&str, &str, RunFn); 6] = [
        ("changepoint-cv2", "paper 002 Table 1", cv2),
        ("changepoint-tilt", "paper 002 Table 2", tilt),
        ("changepoint-unknown-rho", "paper 002 Table 3", unknown_rho),
        (
            "arx-identify",
            "paper 002 sec. 3.3 (Chen & Lai 2007's identification study)",
            arx_identify,
        ),
        (
            "arx-control",
            "paper 002 sec. 3.4 (Chen & Lai 2007 Tables III-IV)",
            arx_control,
        ),
        (
            "changepoint-step-cost",
            "no paper figure (cost per step of paper 002's filter)",
            step_cost,
        ),
    ];
    entries
        .into_iter()
        .filter_map(|(name, reproduces, run)| {
            cp::find(name).map(|e| super::Experiment {
                name: e.name,
                about: e.about,
                reproduces,
                params: e.params,
                run,
            })
        })
        .collect()
}
