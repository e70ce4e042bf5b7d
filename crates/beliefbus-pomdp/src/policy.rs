//! α-vector policies: act with the action of `argmax_α α·b`; `max_α α·b` is
//! the policy's guaranteed value (a lower bound on V*(b)).
//!
//! Text format (one policy per file, `#` comments and blank lines ignored):
//!
//! ```text
//! beliefbus-alpha 1
//! states <|S|> actions <|A|> vectors <N>
//! <action> <α(0)> <α(1)> … <α(|S|−1)>        # N such lines
//! ```
//!
//! `<action>` is the 0-based action index (the order of the model's
//! `actions:` line); values are written with Rust's shortest round-trip
//! formatting, so a policy reads back bit for bit.

use crate::belief::SparseBelief;
use std::fmt::Write as _;
use std::path::Path;
use thiserror::Error;

/// A set of α-vectors, each with its action.
#[derive(Clone, Debug, PartialEq)]
pub struct AlphaPolicy {
    pub n_states: usize,
    pub n_actions: usize,
    pub vectors: Vec<Vec<f64>>,
    pub actions: Vec<usize>,
}

/// Why a policy file could not be read.
#[derive(Debug, Error)]
pub enum PolicyError {
    #[error("{file}: {cause}")]
    Io {
        file: String,
        /// In the message, not returned by `source()`: a chained report
        /// (`{:#}`) would print it twice.
        cause: std::io::Error,
    },
    #[error("{file}:{line}: {message}")]
    Format {
        file: String,
        line: usize,
        message: String,
    },
    /// The policy does not fit the model it is used with.
    #[error("policy has {got}, the model has {expected}")]
    Mismatch { got: String, expected: String },
}

impl AlphaPolicy {
    /// Index of the best vector at a dense belief, and its value.
    pub fn best_dense(&self, b: &[f64]) -> (usize, f64) {
        let mut best = (0, f64::NEG_INFINITY);
        for (k, v) in self.vectors.iter().enumerate() {
            let x: f64 = v.iter().zip(b).map(|(a, p)| a * p).sum();
            if x > best.1 {
                best = (k, x);
            }
        }
        best
    }

    /// Index of the best vector at a sparse belief, and its value (the
    /// cost is the belief's support, not |S|).
    pub fn best_sparse(&self, b: &SparseBelief) -> (usize, f64) {
        let mut best = (0, f64::NEG_INFINITY);
        for (k, v) in self.vectors.iter().enumerate() {
            let x = b.dot(v);
            if x > best.1 {
                best = (k, x);
            }
        }
        best
    }

    /// The action at a dense belief.
    pub fn action(&self, b: &[f64]) -> usize {
        self.actions[self.best_dense(b).0]
    }

    /// The policy's value bound at a dense belief.
    pub fn value(&self, b: &[f64]) -> f64 {
        self.best_dense(b).1
    }

    /// Checks the policy fits a model with these sizes.
    pub fn check_fits(&self, n_states: usize, n_actions: usize) -> Result<(), PolicyError> {
        if self.n_states != n_states || self.n_actions != n_actions {
            return Err(PolicyError::Mismatch {
                got: format!("{} states and {} actions", self.n_states, self.n_actions),
                expected: format!("{n_states} states and {n_actions} actions"),
            });
        }
        Ok(())
    }

    /// The text format (module doc).
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "beliefbus-alpha 1");
        let _ = writeln!(
            s,
            "states {} actions {} vectors {}",
            self.n_states,
            self.n_actions,
            self.vectors.len()
        );
        for (v, a) in self.vectors.iter().zip(&self.actions) {
            let _ = write!(s, "{a}");
            for x in v {
                let _ = write!(s, " {x}");
            }
            s.push('\n');
        }
        s
    }

    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        std::fs::write(path, self.to_text())
    }

    pub fn read(path: &Path) -> Result<Self, PolicyError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|cause| PolicyError::Io {
            file: file.clone(),
            cause,
        })?;
        Self::from_text(&file, &text)
    }

    /// Parses the text format; `file` names it in errors.
    pub fn from_text(file: &str, text: &str) -> Result<Self, PolicyError> {
        let err = |line: usize, message: String| PolicyError::Format {
            file: file.into(),
            line,
            message,
        };
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.split('#').next().unwrap_or("").trim()))
            .filter(|(_, l)| !l.is_empty());
        match lines.next() {
            Some((_, "beliefbus-alpha 1")) => {}
            Some((i, l)) => {
                return Err(err(i, format!("expected `beliefbus-alpha 1`, found `{l}`")))
            }
            None => return Err(err(1, "empty policy file".into())),
        }
        let (hl, header) = lines
            .next()
            .ok_or_else(|| err(2, "missing `states N actions A vectors K` line".into()))?;
        let h: Vec<&str> = header.split_whitespace().collect();
        let num = |k: usize| h.get(k).and_then(|x| x.parse::<usize>().ok());
        let (ns, na, nv) = match (
            h.len(),
            h.first(),
            h.get(2),
            h.get(4),
            num(1),
            num(3),
            num(5),
        ) {
            (
                6,
                Some(&"states"),
                Some(&"actions"),
                Some(&"vectors"),
                Some(ns),
                Some(na),
                Some(nv),
            ) if ns > 0 && na > 0 => (ns, na, nv),
            _ => {
                return Err(err(
                    hl,
                    format!("expected `states N actions A vectors K`, found `{header}`"),
                ))
            }
        };
        let mut p = AlphaPolicy {
            n_states: ns,
            n_actions: na,
            vectors: Vec::with_capacity(nv),
            actions: Vec::with_capacity(nv),
        };
        for (i, l) in lines {
            let mut it = l.split_whitespace();
            let a: usize = it
                .next()
                .and_then(|x| x.parse().ok())
                .filter(|&a| a < na)
                .ok_or_else(|| err(i, format!("expected an action index below {na}")))?;
            let v: Vec<f64> = it
                .map(|x| x.parse::<f64>().ok().filter(|v| v.is_finite()))
                .collect::<Option<_>>()
                .ok_or_else(|| err(i, "expected finite numbers".into()))?;
            if v.len() != ns {
                return Err(err(i, format!("expected {ns} values, found {}", v.len())));
            }
            p.vectors.push(v);
            p.actions.push(a);
        }
        if p.vectors.len() != nv || nv == 0 {
            return Err(err(
                text.lines().count(),
                format!("header says {nv} vectors, found {}", p.vectors.len()),
            ));
        }
        Ok(p)
    }
}
