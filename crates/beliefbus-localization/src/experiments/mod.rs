//! The paper's experiments as library functions: each takes (runs, seed,
//! `key=value` parameters) and returns the workspace's experiment report
//! with our rows beside the paper's. [`all`] lists them for a command line.

pub mod mcl;
pub mod params;
pub mod slam;
pub mod slam_acceptance;
pub mod slam_layout;
pub mod slam_noise;
pub mod slam_paper;
pub mod slam_params;
pub mod slam_plot;
pub mod slam_run;
pub mod slam_svg;
pub mod slam_sweep;
pub mod slam_victoria;
pub mod slam_vp_data;

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
    },
    Experiment {
        name: "slam",
        about: "implicit SLAM vs FastSLAM 1.0, FastSLAM 2.0 and EKF-SLAM on synthetic car parks driven by the Victoria Park odometry: trajectory error and time per update vs samples; one scalar setting given as a list (key=a,b,c) is swept, each row tagged with it",
        reproduces: "paper 003 Table 6 (Fig. 7 right)",
        params: slam::PARAMS,
        run: slam::run,
    },
    Experiment {
        name: "slam-victoria-park",
        about: "implicit SLAM, FastSLAM 2.0 and EKF-SLAM on the whole real Victoria Park run with its tree features: position error against GPS (RMS, 95th percentile), trees mapped, time per update",
        reproduces: "the Victoria Park benchmark (Guivant & Nebot); no paper figure",
        params: slam_victoria::PARAMS,
        run: slam_victoria::run,
    }]
}

/// Find an experiment by name.
pub fn find(name: &str) -> Option<Experiment> {
    all().into_iter().find(|e| e.name == name)
}
