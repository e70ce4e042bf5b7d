//! A discrete POMDP ⟨S, A, Z, T, O, R, γ, b₀⟩ in the form the solver uses.
//!
//! * `T(s'|s,a)`: one sparse row-major matrix per action (row `s`, entries
//!   `(s', p)`), so a belief prediction `b'(s') = Σ_s b(s) T(s'|s,a)` costs
//!   the non-zeros it touches.
//! * `O(o|s',a)`: one sparse matrix per action indexed by the **end** state
//!   (row `s'`, entries `(o, p)`).
//! * `R(s,a)`: the expected immediate reward, dense per action. A file's
//!   `r(a,s,s',o)` is reduced to it as
//!   `R(s,a) = Σ_{s'} T(s'|s,a) Σ_o O(o|s',a) r(a,s,s',o)`; the expected
//!   discounted return of every policy is unchanged by that reduction.
//!
//! [`Pomdp::new`] checks every row is a distribution, so a model built in
//! code (a Markov chain turned into a POMDP) and one read from a file reach
//! the solver through the same validated door.

use thiserror::Error;

/// Rows must sum to one within this before they are renormalised.
pub const ROW_TOLERANCE: f64 = 1e-5;

/// A sparse row-major matrix: row `i` holds `(column, value)` pairs sorted by
/// column, no zeros.
#[derive(Clone, Debug, PartialEq)]
pub struct SparseRows {
    offsets: Vec<usize>,
    cols: Vec<u32>,
    vals: Vec<f64>,
    n_cols: usize,
}

impl SparseRows {
    /// From one `(column, value)` list per row (any order; zeros dropped,
    /// duplicate columns summed).
    pub fn from_rows(rows: Vec<Vec<(u32, f64)>>, n_cols: usize) -> Self {
        let mut offsets = Vec::with_capacity(rows.len() + 1);
        let mut cols = Vec::new();
        let mut vals = Vec::new();
        offsets.push(0);
        for mut row in rows {
            row.sort_by_key(|&(c, _)| c);
            for (c, v) in row {
                if v == 0.0 {
                    continue;
                }
                if cols.len() > *offsets.last().unwrap_or(&0) && cols.last() == Some(&c) {
                    *vals.last_mut().expect("pushed with cols") += v;
                } else {
                    cols.push(c);
                    vals.push(v);
                }
            }
            offsets.push(cols.len());
        }
        SparseRows {
            offsets,
            cols,
            vals,
            n_cols,
        }
    }

    /// A dense matrix given row by row.
    pub fn from_dense(rows: &[Vec<f64>]) -> Self {
        let n_cols = rows.first().map_or(0, Vec::len);
        Self::from_rows(
            rows.iter()
                .map(|r| r.iter().enumerate().map(|(j, &v)| (j as u32, v)).collect())
                .collect(),
            n_cols,
        )
    }

    pub fn n_rows(&self) -> usize {
        self.offsets.len() - 1
    }

    pub fn n_cols(&self) -> usize {
        self.n_cols
    }

    /// Non-zeros.
    pub fn nnz(&self) -> usize {
        self.cols.len()
    }

    /// Row `i` as parallel slices (columns, values).
    #[inline]
    pub fn row(&self, i: usize) -> (&[u32], &[f64]) {
        let (a, b) = (self.offsets[i], self.offsets[i + 1]);
        (&self.cols[a..b], &self.vals[a..b])
    }

    /// Entry `(i, j)` (zero when absent).
    pub fn get(&self, i: usize, j: usize) -> f64 {
        let (c, v) = self.row(i);
        c.binary_search(&(j as u32)).map_or(0.0, |k| v[k])
    }

    fn row_sum(&self, i: usize) -> f64 {
        self.row(i).1.iter().sum()
    }

    fn scale_row(&mut self, i: usize, f: f64) {
        let (a, b) = (self.offsets[i], self.offsets[i + 1]);
        for v in &mut self.vals[a..b] {
            *v *= f;
        }
    }
}

/// Why a model is not a POMDP.
#[derive(Debug, Error, PartialEq)]
pub enum ModelError {
    /// Discount outside [0, 1].
    #[error("discount {0} is outside [0, 1]")]
    Discount(f64),
    /// No states, actions or observations.
    #[error("a POMDP needs at least one state, action and observation")]
    Empty,
    /// A table has the wrong shape.
    #[error("{what} has shape {got}, expected {expected}")]
    Shape {
        what: String,
        got: String,
        expected: String,
    },
    /// A probability is negative or not finite.
    #[error("{what}: entry {value} is not a probability")]
    BadProbability { what: String, value: f64 },
    /// A row does not sum to one within [`ROW_TOLERANCE`].
    #[error("{what} sums to {sum}, not 1 (tolerance {ROW_TOLERANCE})")]
    RowSum { what: String, sum: f64 },
    /// A reward is not finite.
    #[error("reward R(s={state}, a={action}) = {value} is not finite")]
    BadReward {
        state: usize,
        action: usize,
        value: f64,
    },
}

/// A validated discrete POMDP (see the module doc for the layout).
#[derive(Clone, Debug)]
pub struct Pomdp {
    pub discount: f64,
    /// Initial belief b₀, dense over states.
    pub start: Vec<f64>,
    /// `trans[a]`: row `s` → `(s', T(s'|s,a))`.
    pub trans: Vec<SparseRows>,
    /// `obs[a]`: row `s'` → `(o, O(o|s',a))`.
    pub obs: Vec<SparseRows>,
    /// `reward[a][s]` = R(s,a).
    pub reward: Vec<Vec<f64>>,
    pub state_names: Vec<String>,
    pub action_names: Vec<String>,
    pub obs_names: Vec<String>,
}

impl Pomdp {
    /// The one-step backup of `v` under action `a` at state `s`:
    /// r(s, a) + γ Σ_{s'} T(s' | s, a) v(s'), over the sparse row.
    pub fn backup_at(&self, a: usize, s: usize, v: &[f64]) -> f64 {
        let (cols, vals) = self.trans[a].row(s);
        let ev: f64 = cols
            .iter()
            .zip(vals)
            .map(|(&j, &t)| t * v[j as usize])
            .sum();
        self.reward[a][s] + self.discount * ev
    }

    /// Checks shapes and distributions; rows (and b₀) that sum to one within
    /// [`ROW_TOLERANCE`] are renormalised exactly. Names default to indices.
    pub fn new(
        discount: f64,
        mut start: Vec<f64>,
        mut trans: Vec<SparseRows>,
        mut obs: Vec<SparseRows>,
        reward: Vec<Vec<f64>>,
    ) -> Result<Self, ModelError> {
        if !(0.0..=1.0).contains(&discount) {
            return Err(ModelError::Discount(discount));
        }
        let (ns, na) = (start.len(), trans.len());
        let no = obs.first().map_or(0, SparseRows::n_cols);
        if ns == 0 || na == 0 || no == 0 {
            return Err(ModelError::Empty);
        }
        let shape = |what: &str, got: String, expected: String| ModelError::Shape {
            what: what.into(),
            got,
            expected,
        };
        if obs.len() != na || reward.len() != na {
            return Err(shape(
                "observation/reward tables",
                format!("{} and {} actions", obs.len(), reward.len()),
                format!("{na} actions"),
            ));
        }
        for a in 0..na {
            if trans[a].n_rows() != ns || trans[a].n_cols() != ns {
                return Err(shape(
                    &format!("T for action {a}"),
                    format!("{}x{}", trans[a].n_rows(), trans[a].n_cols()),
                    format!("{ns}x{ns}"),
                ));
            }
            if obs[a].n_rows() != ns || obs[a].n_cols() != no {
                return Err(shape(
                    &format!("O for action {a}"),
                    format!("{}x{}", obs[a].n_rows(), obs[a].n_cols()),
                    format!("{ns}x{no}"),
                ));
            }
            if reward[a].len() != ns {
                return Err(shape(
                    &format!("R for action {a}"),
                    reward[a].len().to_string(),
                    ns.to_string(),
                ));
            }
            for (s, &r) in reward[a].iter().enumerate() {
                if !r.is_finite() {
                    return Err(ModelError::BadReward {
                        state: s,
                        action: a,
                        value: r,
                    });
                }
            }
            for s in 0..ns {
                normalise_row(&mut trans[a], s, || format!("T(.|s={s}, a={a})"))?;
                normalise_row(&mut obs[a], s, || format!("O(.|s'={s}, a={a})"))?;
            }
        }
        normalise(&mut start, || "start distribution".into())?;
        Ok(Pomdp {
            discount,
            start,
            trans,
            obs,
            reward,
            state_names: (0..ns).map(|i| i.to_string()).collect(),
            action_names: (0..na).map(|i| i.to_string()).collect(),
            obs_names: (0..no).map(|i| i.to_string()).collect(),
        })
    }

    pub fn n_states(&self) -> usize {
        self.start.len()
    }

    pub fn n_actions(&self) -> usize {
        self.trans.len()
    }

    pub fn n_obs(&self) -> usize {
        self.obs[0].n_cols()
    }

    /// Smallest and largest R(s,a).
    pub fn reward_range(&self) -> (f64, f64) {
        self.reward
            .iter()
            .flatten()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &r| {
                (lo.min(r), hi.max(r))
            })
    }
}

fn check_entries(vals: &[f64], what: &dyn Fn() -> String) -> Result<f64, ModelError> {
    let mut sum = 0.0;
    for &v in vals {
        if !(v >= 0.0) || !v.is_finite() {
            return Err(ModelError::BadProbability {
                what: what(),
                value: v,
            });
        }
        sum += v;
    }
    if (sum - 1.0).abs() > ROW_TOLERANCE {
        return Err(ModelError::RowSum { what: what(), sum });
    }
    Ok(sum)
}

fn normalise_row(
    m: &mut SparseRows,
    i: usize,
    what: impl Fn() -> String,
) -> Result<(), ModelError> {
    let sum = check_entries(m.row(i).1, &what)?;
    debug_assert!((m.row_sum(i) - sum).abs() < 1e-12);
    m.scale_row(i, 1.0 / sum);
    Ok(())
}

fn normalise(v: &mut [f64], what: impl Fn() -> String) -> Result<(), ModelError> {
    let sum = check_entries(v, &what)?;
    v.iter_mut().for_each(|x| *x /= sum);
    Ok(())
}
