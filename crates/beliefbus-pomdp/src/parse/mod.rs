//! Reader for Tony Cassandra's `.pomdp` text format (pomdp.org, "POMDP file
//! format"; the format of pomdp-solve, SARSOP/APPL, ZMDP, POMDPs.jl).
//!
//! Supported, in full:
//! * preamble items in any order: `discount:`, `values: reward|cost`,
//!   `states:` / `actions:` / `observations:` as a count (items are then
//!   0-based numbers) or a name list (numbers are still accepted as indices);
//!   name spaces are separate (a state and an observation may share a name);
//! * `start:` as a vector, `uniform`, one state (name or number),
//!   `start include: <states>` (uniform over them) or
//!   `start exclude: <states>` (uniform over the rest); no `start` = uniform;
//! * `T:` single entries `T: a : s : s' p`, rows `T: a : s` + |S| numbers
//!   (or `uniform`, or `reset` = the start distribution), matrices `T: a` +
//!   |S|×|S| numbers (or `uniform`, `identity`);
//! * `O:` the same with observations as columns (`O: a : s' : o p`, rows,
//!   matrices, `uniform`);
//! * `R: a : s : s' : o v`, the row form `R: a : s : s'` + |Z| values and the
//!   matrix form `R: a : s` + |S|×|Z| values;
//! * `*` in every position of every entry; a later entry overwrites earlier
//!   ones for the cells it covers;
//! * numbers on following lines, `#` comments anywhere, tabs, CRLF.
//!
//! Rows of T and O and the start vector must sum to 1 within
//! [`ROW_TOLERANCE`](crate::model::ROW_TOLERANCE) and are then renormalised;
//! a worse row is an error naming the row and the line that last wrote it.
//! `values: cost` negates every reward (the solver maximises).

mod grammar;
mod lexer;
mod tables;

use crate::model::{ModelError, Pomdp};
use std::path::Path;
use thiserror::Error;

/// Why a `.pomdp` file could not be read.
#[derive(Debug, Error)]
pub enum ParseError {
    /// The file could not be read.
    #[error("{file}: {cause}")]
    Io {
        file: String,
        /// In the message, not returned by `source()`: a chained report
        /// (`{:#}`) would print it twice.
        cause: std::io::Error,
    },
    /// A token other than the grammar allows.
    #[error("{file}:{line}: expected {expected}, found {found}")]
    Syntax {
        file: String,
        line: usize,
        expected: String,
        found: String,
    },
    /// Well-formed text with a meaning error (unknown name, wrong count, …).
    #[error("{file}:{line}: {message}")]
    Semantic {
        file: String,
        line: usize,
        message: String,
    },
    /// A distribution that does not sum to one.
    #[error("{file}:{line}: {what} sums to {sum:.7}, expected 1 (within {tol})")]
    RowSum {
        file: String,
        line: usize,
        what: String,
        sum: f64,
        tol: f64,
    },
    /// A required item is missing.
    #[error("{file}: missing {what}")]
    Missing { file: String, what: String },
    /// The parsed model failed validation.
    #[error("{file}: {cause}")]
    Model { file: String, cause: ModelError },
}

impl ParseError {
    /// The line the error points at, if any.
    pub fn line(&self) -> Option<usize> {
        match self {
            ParseError::Syntax { line, .. }
            | ParseError::Semantic { line, .. }
            | ParseError::RowSum { line, .. } => Some(*line),
            _ => None,
        }
    }
}

/// Parses `.pomdp` text; `file` names it in error messages.
pub fn parse_str(file: &str, text: &str) -> Result<Pomdp, ParseError> {
    let tokens = lexer::lex(file, text)?;
    grammar::Parser::new(file, tokens).parse()
}

/// Reads and parses a `.pomdp` file.
pub fn parse_file(path: &Path) -> Result<Pomdp, ParseError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|cause| ParseError::Io {
        file: file.clone(),
        cause,
    })?;
    parse_str(&file, &text)
}
