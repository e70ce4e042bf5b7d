//! Reproductions of the reference papers' tables, driven by
//! `beliefbus experiment <name> [--runs N] [--seed S] [--json FILE]`.
//!
//! Every experiment returns an [`ExperimentReport`]: our rows next to the
//! paper's rows, in the experiment JSON of DESIGN.md
//! (`{"experiment", "params", "results": [{"method", <metric>...}], "paper": [...]}`),
//! and prints the same numbers as a table.

pub mod arm;
pub mod double_slit;
pub mod himmelblau;
pub mod pi_common;
pub mod report;
pub mod ship_control;

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
}

impl Default for ExperimentArgs {
    fn default() -> Self {
        Self {
            runs: None,
            seed: 1,
            progress: false,
            params: Vec::new(),
        }
    }
}

/// An experiment: its name, one line of description and its entry point.
pub struct Experiment {
    pub name: &'static str,
    pub about: &'static str,
    pub run: fn(&ExperimentArgs) -> anyhow::Result<ExperimentReport>,
}

/// Every experiment, in the order `beliefbus experiment --list` shows them.
pub fn all() -> Vec<Experiment> {
    vec![
        // Each issue registers its experiments here.
        Experiment {
            name: "double-slit",
            about: "paper 003 Table 2: implicit-sampling path-integral control of the double slit vs the analytic solution and naive MC",
            run: double_slit::run,
        },
        Experiment {
            name: "himmelblau",
            about: "paper 003 Table 4: minimising Himmelblau's function by stochastic optimal control vs undamped Newton",
            run: himmelblau::run,
        },
        Experiment {
            name: "arm",
            about: "paper 003 Fig. 4: path-integral control of the two-link arm with a wrong payload (m1 = 1.4) vs the exact optimal controller",
            run: arm::run,
        },
        Experiment {
            name: "ship-control",
            about: "closed-loop ship: implicit path-integral control vs MPPI-2048/512, cost and compute per control",
            run: ship_control::run,
        },
    ]
}

/// Find an experiment by name.
pub fn find(name: &str) -> Option<Experiment> {
    all().into_iter().find(|e| e.name == name)
}
