//! The solved policy of the projected-belief MDP as a table over the
//! parameter grid, its file format and its on-line use.
//!
//! On-line the controller computes θ̂_k with the projection particle filter
//! and applies a_k = μ^p(nearest grid point of θ̂_k) (paper §IV): a
//! projection plus an O(dim) lookup. The file (JSON) carries a
//! [`PolicyKey`] — every parameter the solution depends on (model, noise,
//! grid, family, criterion, Monte Carlo size, seed) as exact text — and
//! [`GridPolicy::load_checked`] refuses a file whose key differs from the
//! problem at hand, naming the first differing field.

use crate::grid::ParamGrid;
use crate::ProjectionError;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// The format version written into policy files.
pub const POLICY_FORMAT: u32 = 1;

/// The parameters a solved policy depends on, as exact text (floats in
/// their shortest round-trip form), so equality is exact.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PolicyKey(pub BTreeMap<String, String>);

impl PolicyKey {
    /// An empty key.
    pub fn new() -> Self {
        Self::default()
    }

    /// Add a numeric field.
    pub fn num(mut self, name: &str, v: f64) -> Self {
        self.0.insert(name.to_string(), format!("{v:?}"));
        self
    }

    /// Add an integer field.
    pub fn int(mut self, name: &str, v: u64) -> Self {
        self.0.insert(name.to_string(), v.to_string());
        self
    }

    /// Add a text field.
    pub fn text(mut self, name: &str, v: &str) -> Self {
        self.0.insert(name.to_string(), v.to_string());
        self
    }

    /// The first field (in name order) whose value differs, with the value
    /// in `self` and in `expected` ("<absent>" when missing).
    pub fn first_difference(&self, expected: &PolicyKey) -> Option<(String, String, String)> {
        let absent = || "<absent>".to_string();
        let names: std::collections::BTreeSet<&String> =
            self.0.keys().chain(expected.0.keys()).collect();
        names.into_iter().find_map(|k| {
            let (a, b) = (self.0.get(k), expected.0.get(k));
            (a != b).then(|| {
                (
                    k.clone(),
                    a.cloned().unwrap_or_else(absent),
                    b.cloned().unwrap_or_else(absent),
                )
            })
        })
    }
}

/// The optimality criterion a policy was solved for.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Criterion {
    /// Discounted total cost, factor γ, value iteration.
    Discounted { gamma: f64 },
    /// Average cost per period, relative value iteration.
    Average,
}

/// What solving cost and how it stopped.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SolveStats {
    /// Monte Carlo build of costs and transitions, seconds.
    pub build_s: f64,
    /// Value / relative value iteration, seconds.
    pub iterate_s: f64,
    pub iterations: usize,
    pub nnz: usize,
    /// Average-cost criterion: the gain (optimal cost per period of the
    /// grid MDP).
    pub gain: Option<f64>,
}

/// Errors of loading, checking and using a policy file.
#[derive(Debug, Error)]
pub enum PolicyError {
    #[error("no policy file at {path}: solve the problem first")]
    Missing { path: PathBuf },
    #[error("cannot read or write policy file {path}: {cause}")]
    Io {
        path: PathBuf,
        /// In the message, not returned by `source()`: a chained report
        /// (`{:#}`) would print it twice.
        cause: std::io::Error,
    },
    #[error("policy file {path} is not a valid policy: {detail}")]
    Parse { path: PathBuf, detail: String },
    #[error("policy file {path} is stale: it was solved for {field} = {found}, the problem has {field} = {expected}; solve again")]
    Stale {
        path: PathBuf,
        field: String,
        found: String,
        expected: String,
    },
    #[error(transparent)]
    Projection(#[from] ProjectionError),
}

/// A policy table over a parameter grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridPolicy {
    pub format: u32,
    pub key: PolicyKey,
    /// The exponential family the grid coordinates belong to.
    pub family: String,
    pub criterion: Criterion,
    pub grid: ParamGrid,
    /// The action at each grid point (flat grid index).
    pub actions: Vec<u16>,
    /// Discounted: J(θ_i); average: the relative values h(θ_i).
    pub values: Vec<f64>,
    pub stats: SolveStats,
}

impl GridPolicy {
    /// A policy from a solver's output; checks the table sizes.
    pub fn new(
        key: PolicyKey,
        family: &str,
        criterion: Criterion,
        grid: ParamGrid,
        actions: &[usize],
        values: Vec<f64>,
        stats: SolveStats,
    ) -> Result<Self, ProjectionError> {
        ProjectionError::check_len("policy table", grid.len(), actions.len())?;
        ProjectionError::check_len("value table", grid.len(), values.len())?;
        let actions = actions
            .iter()
            .map(|&a| {
                u16::try_from(a)
                    .map_err(|_| ProjectionError::invalid("action", format!("{a} > u16::MAX")))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            format: POLICY_FORMAT,
            key,
            family: family.to_string(),
            criterion,
            grid,
            actions,
            values,
            stats,
        })
    }

    /// The action for projected parameters with grid coordinates `coords`
    /// (nearest grid point). No allocation.
    #[inline]
    pub fn act(&self, coords: &[f64]) -> Result<usize, ProjectionError> {
        Ok(self.actions[self.grid.nearest(coords)?] as usize)
    }

    /// Refuse the policy unless its key equals `expected`.
    pub fn check_key(&self, path: &Path, expected: &PolicyKey) -> Result<(), PolicyError> {
        match self.key.first_difference(expected) {
            None => Ok(()),
            Some((field, found, expected)) => Err(PolicyError::Stale {
                path: path.to_path_buf(),
                field,
                found,
                expected,
            }),
        }
    }

    /// Write the policy as JSON, creating the parent directory if needed
    /// (a cache directory that does not exist yet is not an error).
    pub fn save(&self, path: &Path) -> Result<(), PolicyError> {
        let text = serde_json::to_string(self).map_err(|e| PolicyError::Parse {
            path: path.to_path_buf(),
            detail: e.to_string(),
        })?;
        let io = |cause| PolicyError::Io {
            path: path.to_path_buf(),
            cause,
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        std::fs::write(path, text).map_err(io)
    }

    /// Read a policy file and check its internal consistency.
    pub fn load(path: &Path) -> Result<Self, PolicyError> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(PolicyError::Missing {
                    path: path.to_path_buf(),
                })
            }
            Err(cause) => {
                return Err(PolicyError::Io {
                    path: path.to_path_buf(),
                    cause,
                })
            }
        };
        let parse = |detail: String| PolicyError::Parse {
            path: path.to_path_buf(),
            detail,
        };
        let p: GridPolicy = serde_json::from_str(&text).map_err(|e| parse(e.to_string()))?;
        if p.format != POLICY_FORMAT {
            return Err(parse(format!(
                "format {} (this build reads {POLICY_FORMAT})",
                p.format
            )));
        }
        if p.grid.is_empty() || p.grid.len() != p.actions.len() || p.grid.len() != p.values.len() {
            return Err(parse(format!(
                "{} grid points but {} actions and {} values",
                p.grid.len(),
                p.actions.len(),
                p.values.len()
            )));
        }
        Ok(p)
    }

    /// [`GridPolicy::load`] then [`GridPolicy::check_key`].
    pub fn load_checked(path: &Path, expected: &PolicyKey) -> Result<Self, PolicyError> {
        let p = Self::load(path)?;
        p.check_key(path, expected)?;
        Ok(p)
    }
}
