//! The paper's experiments as library functions: each takes (runs, seed,
//! `key=value` parameters) and returns the workspace's experiment report
//! with our rows beside the paper's. [`all`] lists them for a command line.

pub mod mcl;
pub mod params;

use crate::error::LocalizationError;
use beliefbus_core::experiment_params::ParamDoc;

/// The workspace's experiment report.
pub use beliefbus_core::report::{ExperimentReport as Report, Row};

/// An experiment entry point: (runs, seed, parameters) → report.
pub type RunFn = fn(Option<usize>, u64, &[(String, String)]) -> Result<Report, LocalizationError>;

/// A named experiment with one line of description and its parameters.
pub struct Experiment {
    pub name: &'static str,
    pub about: &'static str,
    pub reproduces: &'static str,
    pub params: &'static [ParamDoc],
    pub run: RunFn,
}

/// Every experiment of this crate.
pub fn all() -> Vec<Experiment> {
    vec![Experiment {
        name: "mcl",
        about: "implicit-sampling MCL vs standard MCL on a synthetic car park driven by the Victoria Park odometry: relative trajectory error and time per update vs samples",
        reproduces: "paper 003 Table 5 (Fig. 6 right)",
        params: mcl::PARAMS,
        run: mcl::run,
    }]
}

/// Find an experiment by name.
pub fn find(name: &str) -> Option<Experiment> {
    all().into_iter().find(|e| e.name == name)
}
