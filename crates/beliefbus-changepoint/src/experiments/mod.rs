//! The paper's experiments as library functions: each takes (runs, seed,
//! `key=value` parameters) and returns a [`report::Report`] with our rows,
//! the paper's rows and notes. [`all`] lists them for a command line.

pub mod arx_common;
pub mod arx_control;
pub mod arx_identify;
pub mod cv2;
pub mod meanshift_common;
pub mod par;
pub mod report;
pub mod step_cost;
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
    pub params: &'static [beliefbus_core::experiment_params::ParamDoc],
    pub run: RunFn,
}

/// Every experiment of this crate.
pub fn all() -> Vec<Experiment> {
    let e = |name, about, params, run| Experiment {
        name,
        about,
        params,
        run,
    };
    vec![
        e(
            "changepoint-cv2",
            "paper 002 Table 1: fast RBPF on the mean-shift model, SSE and resamplings per cv2 bound and scheme, vs the exact filter",
            cv2::PARAMS,
            cv2::run,
        ),
        e(
            "changepoint-tilt",
            "paper 002 Table 2: fast RBPF with the tilted proposal rho~ = r*rho and weights (12), cv2 bound 1",
            tilt::PARAMS,
            tilt::run,
        ),
        e(
            "changepoint-unknown-rho",
            "paper 002 Table 3: fast RBPF with rho ~ Beta(1, 999) integrated out (eq. 29): SSE(rho), Bayes SSE, resamplings",
            unknown_rho::PARAMS,
            unknown_rho::run,
        ),
        e(
            "arx-identify",
            "paper 002 sec. 3.3 (Chen & Lai 2007): change-point ARX identification, RBPF Bayes estimate vs tuned sliding-window and forgetting-factor LS",
            arx_identify::PARAMS,
            arx_identify::run,
        ),
        e(
            "arx-control",
            "paper 002 sec. 3.4 (Chen & Lai 2007 Tables III-IV): adaptive control rules (18) and (20) on the Bayes, window and forgetting estimates vs an oracle",
            arx_control::PARAMS,
            arx_control::run,
        ),
        e(
            "changepoint-step-cost",
            "fast RBPF vs bootstrap PF at equal M on the Table 1 model: time per step and SSE (no paper figure)",
            step_cost::PARAMS,
            step_cost::run,
        ),
    ]
}

/// Find an experiment by name.
pub fn find(name: &str) -> Option<Experiment> {
    all().into_iter().find(|e| e.name == name)
}
