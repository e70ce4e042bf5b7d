//! Storage that gives the format's overwrite semantics without dense 4-D
//! arrays: a later entry replaces earlier values for the cells it names,
//! never adds to them.
//!
//! * [`ProbTable`] (T or O): one sorted sparse row per (action, row state),
//!   cells set or whole rows replaced, with the line that last wrote a row so
//!   that a bad row sum can be reported where it was written.
//! * [`RewardTable`]: the entries themselves, in file order, indexed by their
//!   (action, start state) pattern and end state; `r(a,s,s',o)` is the value of
//!   the **last** entry matching the cell, and [`RewardTable::reduce`] forms
//!   `R(s,a) = Σ_{s'} T(s'|s,a) Σ_o O(o|s',a) r(a,s,s',o)` visiting only the
//!   non-zero T and O cells.

use crate::model::SparseRows;
use std::collections::HashMap;

/// Which indices a position of an entry covers (`None` = the `*` wildcard).
pub(crate) type Sel = Option<u32>;

pub(crate) fn expand(sel: Sel, n: usize) -> std::ops::Range<u32> {
    match sel {
        Some(i) => i..i + 1,
        None => 0..n as u32,
    }
}

/// T (rows: start state, columns: end state) or O (rows: end state,
/// columns: observation) for every action.
pub(crate) struct ProbTable {
    pub n_rows: usize,
    pub n_cols: usize,
    rows: Vec<Vec<(u32, f64)>>,
    pub line: Vec<usize>,
}

impl ProbTable {
    pub fn new(n_actions: usize, n_rows: usize, n_cols: usize) -> Self {
        ProbTable {
            n_rows,
            n_cols,
            rows: vec![Vec::new(); n_actions * n_rows],
            line: vec![0; n_actions * n_rows],
        }
    }

    pub fn set_cell(&mut self, a: u32, i: u32, j: u32, p: f64, line: usize) {
        let k = a as usize * self.n_rows + i as usize;
        let row = &mut self.rows[k];
        match row.binary_search_by_key(&j, |&(c, _)| c) {
            Ok(pos) if p == 0.0 => {
                row.remove(pos);
            }
            Ok(pos) => row[pos].1 = p,
            Err(_) if p == 0.0 => {}
            Err(pos) => row.insert(pos, (j, p)),
        }
        self.line[k] = line;
    }

    pub fn set_row(&mut self, a: u32, i: u32, dense: &[f64], line: usize) {
        let k = a as usize * self.n_rows + i as usize;
        self.rows[k] = dense
            .iter()
            .enumerate()
            .filter(|(_, &p)| p != 0.0)
            .map(|(j, &p)| (j as u32, p))
            .collect();
        self.line[k] = line;
    }

    /// Replaces a row by sorted, non-zero `(column, value)` pairs.
    pub fn set_sparse_row(&mut self, a: u32, i: u32, row: Vec<(u32, f64)>, line: usize) {
        let k = a as usize * self.n_rows + i as usize;
        self.rows[k] = row;
        self.line[k] = line;
    }

    pub fn scale_row(&mut self, a: usize, i: usize, f: f64) {
        for (_, p) in &mut self.rows[a * self.n_rows + i] {
            *p *= f;
        }
    }

    pub fn row(&self, a: usize, i: usize) -> &[(u32, f64)] {
        &self.rows[a * self.n_rows + i]
    }

    /// The per-action sparse matrices (rows are normalised by the caller).
    pub fn into_matrices(self, n_actions: usize) -> Vec<SparseRows> {
        let mut rows = self.rows.into_iter();
        (0..n_actions)
            .map(|_| SparseRows::from_rows(rows.by_ref().take(self.n_rows).collect(), self.n_cols))
            .collect()
    }
}

/// What one `R:` entry gives for the (s', o) cells of the (a, s) it names.
pub(crate) enum RewardValues {
    /// `R: a : s : s' : o v`
    Cell { end: Sel, obs: Sel, value: f64 },
    /// `R: a : s : s'` followed by one value per observation.
    Row { end: Sel, values: Vec<f64> },
    /// `R: a : s` followed by a |S| × |Z| matrix (row = end state).
    Matrix { values: Vec<f64> },
}

#[derive(Default)]
struct Bucket {
    /// Entries naming one end state, by that state (ascending entry order).
    by_end: HashMap<u32, Vec<usize>>,
    /// Entries for every end state (`*` or a matrix).
    any_end: Vec<usize>,
}

pub(crate) struct RewardTable {
    n_obs: usize,
    entries: Vec<RewardValues>,
    buckets: HashMap<(Sel, Sel), Bucket>,
}

impl RewardTable {
    pub fn new(n_obs: usize) -> Self {
        RewardTable {
            n_obs,
            entries: Vec::new(),
            buckets: HashMap::new(),
        }
    }

    pub fn push(&mut self, action: Sel, start: Sel, values: RewardValues) {
        let idx = self.entries.len();
        let bucket = self.buckets.entry((action, start)).or_default();
        match &values {
            RewardValues::Cell { end: Some(e), .. } | RewardValues::Row { end: Some(e), .. } => {
                bucket.by_end.entry(*e).or_default().push(idx)
            }
            _ => bucket.any_end.push(idx),
        }
        self.entries.push(values);
    }

    /// The value of entry `idx` at (s', o), if it covers that cell.
    fn value_at(&self, idx: usize, end: u32, obs: u32) -> Option<f64> {
        match &self.entries[idx] {
            RewardValues::Cell {
                end: e,
                obs: o,
                value,
            } => (e.is_none_or(|e| e == end) && o.is_none_or(|o| o == obs)).then_some(*value),
            RewardValues::Row { end: e, values } => {
                e.is_none_or(|e| e == end).then(|| values[obs as usize])
            }
            RewardValues::Matrix { values } => {
                Some(values[end as usize * self.n_obs + obs as usize])
            }
        }
    }

    /// Latest entry among `buckets` covering (s', o): (entry index, value).
    fn lookup(&self, buckets: &[&Bucket], end: u32, obs: u32) -> Option<(usize, f64)> {
        let mut best: Option<(usize, f64)> = None;
        let mut consider = |list: &[usize]| {
            for &idx in list.iter().rev() {
                if best.is_some_and(|(b, _)| b > idx) {
                    return;
                }
                if let Some(v) = self.value_at(idx, end, obs) {
                    best = Some((idx, v));
                    return;
                }
            }
        };
        for b in buckets {
            if let Some(list) = b.by_end.get(&end) {
                consider(list);
            }
            consider(&b.any_end);
        }
        best
    }

    /// `R(s,a)` for every action and state (see the module doc).
    pub fn reduce(&self, trans: &ProbTable, obs: &ProbTable, n_actions: usize) -> Vec<Vec<f64>> {
        let n_states = trans.n_rows;
        let mut out = vec![vec![0.0; n_states]; n_actions];
        if self.entries.is_empty() {
            return out;
        }
        for a in 0..n_actions as u32 {
            for s in 0..n_states as u32 {
                let buckets: Vec<&Bucket> = [
                    (Some(a), Some(s)),
                    (Some(a), None),
                    (None, Some(s)),
                    (None, None),
                ]
                .iter()
                .filter_map(|k| self.buckets.get(k))
                .collect();
                if buckets.is_empty() {
                    continue;
                }
                let mut r = 0.0;
                for &(end, pt) in trans.row(a as usize, s as usize) {
                    for &(o, po) in obs.row(a as usize, end as usize) {
                        if let Some((_, v)) = self.lookup(&buckets, end, o) {
                            r += pt * po * v;
                        }
                    }
                }
                out[a as usize][s as usize] = r;
            }
        }
        out
    }
}
