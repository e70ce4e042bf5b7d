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
pub mod double_slit;
pub mod himmelblau;
pub mod inventory;
pub mod param_estimation;
pub mod pi_common;
pub mod refine_sim;
pub mod report;
pub mod ship;
pub mod ship_control;
pub mod smoothing;
pub mod vanderpol;

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
            name: "convergence",
            about: "moments of chain trajectories vs the OU process of eq. 2.9 as n grows (thesis Fig. 2-4)",
            run: convergence::run,
        },
        Experiment {
            name: "vanderpol",
            about: "chain filter vs PF/EKF/UKF on Van der Pol (paper 001 eq. 12), error-vs-compute curve",
            run: vanderpol::run,
        },
        Experiment {
            name: "ship",
            about: "chain filter vs PF-100/EKF/UKF on the drifting ship (paper 001 eq. 10-11)",
            run: ship::run,
        },
        Experiment {
            name: "param-estimation",
            about: "joint state/parameter estimation (paper 001 eq. 13): chain filter vs PF-100",
            run: param_estimation::run,
        },
        Experiment {
            name: "smoothing",
            about: "forward-backward smoother vs chain filter vs PF-1000 on Van der Pol (thesis 3.5.3)",
            run: smoothing::run,
        },
        Experiment {
            name: "decoding",
            about: "MAP trajectory decoding on chains (thesis Alg. 3.2, paper 001 Fig. 6) vs exact RTS",
            run: decoding::run,
        },
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
            name: "anytime",
            about: "the live chain grown by refine while the chain backend filters the ship — error per second vs the offline chain filter at the same size and the PF",
            run: anytime::run,
        },
        Experiment {
            name: "chain-closed-loop",
            about: "the live chain filter vs the PF under strong recorded PD forces on the ship (closed-loop-like)",
            run: chain_closed_loop::run,
        },
        Experiment {
            name: "chain-defaults",
            about: "the chain filter built from ChainFilterSpec's defaults vs PF-300 on Van der Pol and stochastic Lorenz-63: error, CPU per run, ratio",
            run: chain_defaults::run,
        },
        Experiment {
            name: "inventory-average",
            about: "paper 004 Table I: inventory control, average cost of one 10^5-period run per sigma: projected-belief MDP vs CE / CE-MLE / greedy",
            run: inventory::run_average,
        },
        Experiment {
            name: "inventory-discounted",
            about: "paper 004 Table II: inventory control, discounted cost over 1000 runs of horizon 40 per sigma: projected-belief MDP vs CE / CE-MLE / greedy",
            run: inventory::run_discounted,
        },
        Experiment {
            name: "ship-control",
            about: "closed-loop ship: implicit path-integral control vs MPPI-2048/512, cost and compute per control",
            run: ship_control::run,
        },
    ]
    .into_iter()
    // Paper 002, from the beliefbus-changepoint crate.
    .chain(changepoint::experiments())
    .collect()
}

/// Find an experiment by name.
pub fn find(name: &str) -> Option<Experiment> {
    all().into_iter().find(|e| e.name == name)
}
