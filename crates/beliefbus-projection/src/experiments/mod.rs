//! Reproductions of the paper's Tables I and II, in the project's
//! experiment convention: a function of (runs, seed, params) returning our
//! rows (`method`, `sigma`, `cost`, `cost_se`, `time_s`, …) beside the
//! paper's rows, and the JSON shape
//! `{"experiment", "params", "results": [...], "paper": [...]}`.

pub mod inventory;
mod inventory_exact_ref;
pub mod inventory_print;
pub mod paper;
pub mod report;

pub use report::{ExperimentArgs, ExperimentError, Report, Row};

/// An experiment: its name, one line of description, its entry point.
pub struct Experiment {
    pub name: &'static str,
    pub about: &'static str,
    pub run: fn(&ExperimentArgs) -> Result<Report, ExperimentError>,
}

/// The experiments of this crate.
pub fn all() -> Vec<Experiment> {
    vec![
        Experiment {
            name: "inventory-average",
            about: "paper 004 Table I: inventory control, average cost of one 10^5-period run per sigma, projected-belief MDP vs CE / CE-MLE / greedy",
            run: inventory::run_average,
        },
        Experiment {
            name: "inventory-discounted",
            about: "paper 004 Table II: inventory control, discounted cost (gamma 0.9) over 1000 runs of horizon 40 per sigma, projected-belief MDP vs CE / CE-MLE / greedy",
            run: inventory::run_discounted,
        },
    ]
}

/// Find an experiment by name.
pub fn find(name: &str) -> Option<Experiment> {
    all().into_iter().find(|e| e.name == name)
}
