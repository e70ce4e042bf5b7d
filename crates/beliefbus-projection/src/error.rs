//! Typed errors of projection, filtering and MDP solving.

use thiserror::Error;

/// What can go wrong in projection, filtering or MDP building.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ProjectionError {
    /// Every particle has zero likelihood (or a NaN): the observation is
    /// impossible under the predicted belief, there is nothing to project.
    #[error(
        "all particle weights are zero or not finite (observation outside the predicted support)"
    )]
    NoSupport,
    /// A buffer or parameter has the wrong length.
    #[error("dimension mismatch in {what}: expected {expected}, got {got}")]
    Dimension {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    /// A parameter outside its domain (negative variance, zero particles…).
    #[error("invalid {what}: {detail}")]
    Invalid { what: &'static str, detail: String },
}

impl ProjectionError {
    /// Check that `got == expected` for buffer `what`.
    pub fn check_len(what: &'static str, expected: usize, got: usize) -> Result<(), Self> {
        if expected == got {
            Ok(())
        } else {
            Err(Self::Dimension {
                what,
                expected,
                got,
            })
        }
    }

    /// An invalid-parameter error.
    pub fn invalid(what: &'static str, detail: impl Into<String>) -> Self {
        Self::Invalid {
            what,
            detail: detail.into(),
        }
    }
}
