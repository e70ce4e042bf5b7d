//! Reproductions of the reference papers' tables, driven by
//! `beliefbus experiment <name> [--runs N] [--seed S] [--json FILE]`.
//!
//! Every experiment returns an [`ExperimentReport`]: our rows next to the
//! paper's rows, in the experiment JSON of DESIGN.md
//! (`{"experiment", "params", "results": [{"method", <metric>...}], "paper": [...]}`),
//! and prints the same numbers as a table.

pub mod anytime;
pub mod arm;
pub mod chain_closed_loop;
pub mod chain_defaults;
pub mod chain_util;
pub mod changepoint;
pub mod convergence;
pub mod decoding;
pub mod degenerate;
pub mod double_slit;
pub mod himmelblau;
pub mod inventory;
pub mod localization;
pub mod param_estimation;
pub mod pi_common;
pub mod pomdp_light_dark;
pub mod pomdp_lqg;
pub mod refine_sim;
pub mod registry;
pub mod report;
pub mod ship;
pub mod ship_control;
pub mod ship_states;
pub mod ship_states_recentred;
pub mod smoothing;
pub mod vanderpol;

pub use beliefbus_core::experiment_params::ParamDoc;
pub use report::{ExperimentReport, Progress, Row};

/// Options shared by all experiments.
#[derive(Clone, Debug)]
pub struct ExperimentArgs {
    /// Monte-Carlo repetitions (None: the experiment's default, usually the
    /// paper's).
    pub runs: Option<usize>,
    /// Base seed; repetition i uses stream i of it.
    pub seed: u64,
    /// Show a progress bar on stderr.
    pub progress: bool,
    /// Extra `key=value` parameters (experiment specific, validated by it).
    pub params: Vec<(String, String)>,
    /// The experiment's documented parameters (empty when the caller did
    /// not come through the registry); the lookups check their defaults
    /// against it in debug builds.
    pub doc: &'static [ParamDoc],
}

impl Default for ExperimentArgs {
    fn default() -> Self {
        Self {
            runs: None,
            seed: 1,
            progress: false,
            params: Vec::new(),
            doc: &[],
        }
    }
}

/// An experiment: its name, one line of description, the paper figure it
/// reproduces, its documented parameters and its entry point.
pub struct Experiment {
    pub name: &'static str,
    pub about: &'static str,
    pub reproduces: &'static str,
    pub params: &'static [ParamDoc],
    pub run: fn(&ExperimentArgs) -> anyhow::Result<ExperimentReport>,
}

pub use registry::all;

/// Find an experiment by name.
pub fn find(name: &str) -> Option<Experiment> {
    all().into_iter().find(|e| e.name == name)
}
