//! The paper's experiments as library functions: each takes (runs, seed,
//! `key=value` parameters) and returns a [`report::Report`] with our rows,
//! the paper's rows and notes. [`all`] lists them for a command line.

pub mod cv2;
pub mod meanshift_common;
pub mod par;
pub mod report;
pub mod tilt;
pub mod unknown_rho;

pub use report::{Report, Row};

use crate::error::ChangepointError;

/// An experiment entry point: (runs, seed, parameters) → report.
pub type RunFn = fn(Option<usize>, u64, &[(String, String)]) -> Result<Report, ChangepointError>;

/// A named experiment with one line of description and its parameters.
pub struct Experiment {
    pub name: &'static str,
    pub about: &'static str,
    pub params: &'static [&'static str],
    pub run: RunFn,
}

/// Every experiment of this crate.
pub fn all() -> Vec<Experiment> {
    vec![
    Experiment {
        name: "changepoint-cv2",
        about: "paper 002 Table 1: fast RBPF on the mean-shift model, SSE and resampling count per cv2 bound and scheme, vs the exact filter",
        params: cv2::PARAMS,
        run: cv2::run,
    },
    Experiment {
        name: "changepoint-tilt",
        about: "paper 002 Table 2: fast RBPF with the tilted proposal rho~ = r*rho and weights (12), cv2 bound 1",
        params: tilt::PARAMS,
        run: tilt::run,
    },
    Experiment {
        name: "changepoint-unknown-rho",
        about: "paper 002 Table 3: fast RBPF with rho ~ Beta(1, 999) integrated out (eq. 29): SSE(rho), Bayes SSE, resamplings",
        params: unknown_rho::PARAMS,
        run: unknown_rho::run,
    }]
}

/// Find an experiment by name.
pub fn find(name: &str) -> Option<Experiment> {
    all().into_iter().find(|e| e.name == name)
}
