//! Typed errors: bad data files, bad parameters and degenerate filters come
//! back here; nothing on a reachable path panics.

use thiserror::Error;

/// Where the Victoria Park files come from, for the "data missing" message.
pub const DATA_SOURCE: &str = "http://www-personal.acfr.usyd.edu.au/nebot/victoria_park.htm \
(aa3_dr.mat and aa3_lsr2.mat; the data folder's convert.py writes odometry.csv as \
time_s,speed_mps,steering_rad and laser_times.csv as scan_index,time_s)";

/// Everything this crate can refuse.
#[derive(Debug, Error)]
pub enum LocalizationError {
    /// The data folder or one of its files is missing.
    #[error("Victoria Park data not found: {path} does not exist. Get the data set from {DATA_SOURCE}, then pass --param data_dir=DIR or set BELIEFBUS_VICTORIA_PARK=DIR")]
    DataMissing { path: String },
    /// A file that exists could not be read.
    #[error("reading {path}: {cause}")]
    Io {
        path: String,
        /// In the message, not returned by `source()`: a chained report
        /// (`{:#}`) would print it twice.
        cause: std::io::Error,
    },
    /// A malformed line in a data file.
    #[error("{file} line {line}: {msg}")]
    Parse {
        file: &'static str,
        line: usize,
        msg: String,
    },
    /// A model or scenario setting outside its domain.
    #[error("{name} = {value} {need}")]
    Invalid {
        name: &'static str,
        value: f64,
        need: &'static str,
    },
    /// An experiment parameter that is unknown or does not parse.
    #[error("parameter {key}: {msg}")]
    Param { key: String, msg: String },
    /// A matrix that must be symmetric positive definite is not.
    #[error("{0} is not symmetric positive definite")]
    NotPositiveDefinite(&'static str),
    /// A particle's pose or cost became NaN or infinite.
    #[error("non-finite {what} at step {step}")]
    NonFinite { what: &'static str, step: usize },
    /// Every particle weight vanished or became NaN.
    #[error("all particle weights vanished or are NaN at step {step}")]
    Degenerate { step: usize },
    /// A method failed on one data set of an experiment: which one, and why
    /// (the cause in the message, as for `Io`).
    #[error("{method} at M = {samples}, data set {run}: {cause}")]
    InRun {
        method: &'static str,
        samples: usize,
        run: u64,
        cause: Box<LocalizationError>,
    },
}

impl LocalizationError {
    /// `value` must be finite and > 0.
    pub fn positive(name: &'static str, value: f64) -> Result<f64, Self> {
        if value.is_finite() && value > 0.0 {
            Ok(value)
        } else {
            Err(Self::Invalid {
                name,
                value,
                need: "must be finite and > 0",
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A failed run names the method, its samples and the data set, and its
    /// cause once: in the message, not again through `source()`.
    #[test]
    fn a_failed_run_names_the_method_and_the_data_set() {
        let e = LocalizationError::InRun {
            method: "fastslam1",
            samples: 100,
            run: 7,
            cause: Box::new(LocalizationError::Degenerate { step: 1726 }),
        };
        assert_eq!(
            e.to_string(),
            "fastslam1 at M = 100, data set 7: all particle weights vanished or are NaN at step 1726"
        );
        assert!(std::error::Error::source(&e).is_none());
    }
}
