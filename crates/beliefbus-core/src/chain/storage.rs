//! Compact storage of a chain's transitions and its flat snapshot view.
//!
//! Rows live in one slab (`cols`: u32 state slots, `probs`: f64) with a start,
//! length and capacity per row, so that reconnecting a state (Alg. 2.3 lines
//! 7–8) rewrites its row in place when it fits and relocates it to the end
//! otherwise. [`Transitions::compact`] turns the slab into plain CSR (row
//! offsets of length n + 1), which is the layout of [`ChainView`]: the flat
//! arrays a later stage publishes zero-copy on a slice service.

/// Where a row lives in the slab (one record, so that locating a row of a
/// random state costs one cache miss, not three).
#[derive(Clone, Copy, Debug, Default)]
struct RowLoc {
    start: u32,
    len: u32,
    cap: u32,
}

/// Transition rows of a chain, slab-allocated.
#[derive(Clone, Debug, Default)]
pub struct Transitions {
    loc: Vec<RowLoc>,
    cols: Vec<u32>,
    probs: Vec<f64>,
    /// Entries of `cols` not owned by any row (left behind by relocation).
    garbage: usize,
    /// CSR row offsets, valid while `compact` is true.
    offsets: Vec<u32>,
    compact: bool,
}

impl Transitions {
    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.loc.len()
    }

    /// Number of stored transitions (live entries).
    pub fn nnz(&self) -> usize {
        self.cols.len() - self.garbage - self.spare()
    }

    fn spare(&self) -> usize {
        self.loc.iter().map(|r| (r.cap - r.len) as usize).sum()
    }

    /// Append an empty row.
    pub fn push_row(&mut self) {
        self.loc.push(RowLoc {
            start: self.cols.len() as u32,
            len: 0,
            cap: 0,
        });
        self.compact = false;
    }

    /// Reserve room for `rows` more rows holding `entries` more entries in
    /// total (so that growth by that much allocates nothing).
    pub fn reserve(&mut self, rows: usize, entries: usize) {
        self.loc.reserve(rows);
        self.cols.reserve(entries);
        self.probs.reserve(entries);
    }

    /// Remove the last row (must be empty or its entries become garbage).
    pub fn pop_row(&mut self) {
        if let Some(r) = self.loc.pop() {
            self.garbage += r.cap as usize;
        }
        self.compact = false;
    }

    /// Replace row `i` by `cols`/`probs`.
    pub fn set_row(&mut self, i: usize, cols: &[u32], probs: &[f64]) {
        debug_assert_eq!(cols.len(), probs.len());
        let k = cols.len() as u32;
        let r = &mut self.loc[i];
        if k > r.cap {
            // Relocate to the end with some slack.
            self.garbage += r.cap as usize;
            let cap = row_capacity(k);
            r.start = self.cols.len() as u32;
            r.cap = cap;
            self.cols.resize(self.cols.len() + cap as usize, 0);
            self.probs.resize(self.probs.len() + cap as usize, 0.0);
        }
        r.len = k;
        let s = r.start as usize;
        self.cols[s..s + k as usize].copy_from_slice(cols);
        self.probs[s..s + k as usize].copy_from_slice(probs);
        self.compact = false;
        if self.garbage > self.cols.len() / 2 && self.garbage > 1 << 16 {
            self.compact();
        }
    }

    /// Row `i` as (column slots, probabilities).
    pub fn row(&self, i: usize) -> (&[u32], &[f64]) {
        let r = self.loc[i];
        let (s, e) = (r.start as usize, (r.start + r.len) as usize);
        (&self.cols[s..e], &self.probs[s..e])
    }

    /// Hint the cache to fetch row `i` (its location record, and the
    /// row if `entries`; the record is then read, a cache miss of its own).
    #[inline]
    pub fn prefetch(&self, i: usize, entries: bool) {
        super::prefetch::line(&self.loc[i]);
        if entries {
            let r = self.loc[i];
            if r.cap > 0 {
                super::prefetch::range(&self.cols[r.start as usize..(r.start + r.cap) as usize]);
                super::prefetch::range(&self.probs[r.start as usize..(r.start + r.cap) as usize]);
            }
        }
    }

    /// Row `i` as mutable (column slots, values), for in-place edits that
    /// keep its length (e.g. the Near lists of [`super::Chain`]).
    pub fn row_mut(&mut self, i: usize) -> (&mut [u32], &mut [f64]) {
        let r = self.loc[i];
        let (s, e) = (r.start as usize, (r.start + r.len) as usize);
        (&mut self.cols[s..e], &mut self.probs[s..e])
    }

    /// Rewrite into plain CSR in row order with no slack.
    pub fn compact(&mut self) {
        if self.compact {
            return;
        }
        let n = self.rows();
        let total: usize = self.loc.iter().map(|r| r.len as usize).sum();
        let mut cols = Vec::with_capacity(total);
        let mut probs = Vec::with_capacity(total);
        let mut offsets = Vec::with_capacity(n + 1);
        for i in 0..n {
            offsets.push(cols.len() as u32);
            let (c, p) = self.row(i);
            cols.extend_from_slice(c);
            probs.extend_from_slice(p);
        }
        offsets.push(cols.len() as u32);
        for (r, &o) in self.loc.iter_mut().zip(&offsets) {
            r.start = o;
            r.cap = r.len;
        }
        self.cols = cols;
        self.probs = probs;
        self.offsets = offsets;
        self.garbage = 0;
        self.compact = true;
    }

    /// Whether the rows are plain CSR right now.
    pub fn is_compact(&self) -> bool {
        self.compact
    }

    /// CSR arrays (offsets, cols, probs); `None` unless compact.
    pub fn csr(&self) -> Option<(&[u32], &[u32], &[f64])> {
        self.compact
            .then(|| (&self.offsets[..], &self.cols[..], &self.probs[..]))
    }

    /// Build from CSR arrays.
    pub fn from_csr(offsets: &[u32], cols: &[u32], probs: &[f64]) -> Self {
        let n = offsets.len().saturating_sub(1);
        let loc = (0..n)
            .map(|i| {
                let len = offsets[i + 1] - offsets[i];
                RowLoc {
                    start: offsets[i],
                    len,
                    cap: len,
                }
            })
            .collect();
        Self {
            loc,
            cols: cols.to_vec(),
            probs: probs.to_vec(),
            garbage: 0,
            offsets: offsets.to_vec(),
            compact: true,
        }
    }

    /// Bytes held (capacity of the arrays).
    pub fn bytes(&self) -> usize {
        self.loc.capacity() * std::mem::size_of::<RowLoc>()
            + self.cols.capacity() * 4
            + self.probs.capacity() * 8
            + self.offsets.capacity() * 4
    }
}

/// Slab capacity given to a row of `k` entries when it is (re)located: some
/// slack so the row can grow a little before moving again (out-degree
/// grows like log n).
pub fn row_capacity(k: u32) -> u32 {
    k + k / 4 + 2
}

/// A read-only snapshot of a chain as flat slices — the layout published
/// zero-copy by the refine stage and consumed by the filters.
///
/// Invariants (checked by [`ChainView::validate`]): `states.len() = n·dim`,
/// `ids`, `holding`, `radius` have length n, `row_offsets` has length n + 1,
/// is non-decreasing and ends at `cols.len() = probs.len()`, every column is
/// < n, every row's probabilities are ≥ 0 and sum to 1 (or the row is empty,
/// an absorbing state with infinite holding time).
#[derive(Clone, Copy, Debug)]
pub struct ChainView<'a> {
    pub dim: usize,
    /// State coordinates, n × dim row-major (state i at `i*dim..`).
    pub states: &'a [f64],
    /// Stable state ids (unique; never reused).
    pub ids: &'a [u32],
    /// Holding times Δt(z).
    pub holding: &'a [f64],
    /// Near radius r(z) used when the state was last connected.
    pub radius: &'a [f64],
    /// CSR row offsets (n + 1).
    pub row_offsets: &'a [u32],
    /// Column state slots.
    pub cols: &'a [u32],
    /// Transition probabilities p(z' | z).
    pub probs: &'a [f64],
}

/// A view whose arrays are inconsistent.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ViewError {
    #[error("snapshot: {0}")]
    Shape(&'static str),
    #[error("snapshot: row {0} is not a probability distribution")]
    Row(usize),
    #[error("snapshot: column out of range in row {0}")]
    Column(usize),
}

impl<'a> ChainView<'a> {
    /// Number of states.
    pub fn len(&self) -> usize {
        self.ids.len()
    }
    /// Whether there are no states.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
    /// Number of transitions.
    pub fn nnz(&self) -> usize {
        self.cols.len()
    }
    /// State i.
    pub fn state(&self, i: usize) -> &'a [f64] {
        &self.states[i * self.dim..(i + 1) * self.dim]
    }
    /// Row i as (cols, probs).
    pub fn row(&self, i: usize) -> (&'a [u32], &'a [f64]) {
        let s = self.row_offsets[i] as usize;
        let e = self.row_offsets[i + 1] as usize;
        (&self.cols[s..e], &self.probs[s..e])
    }

    /// Check the invariants listed on the type.
    pub fn validate(&self) -> Result<(), ViewError> {
        let n = self.ids.len();
        if self.dim == 0 || self.states.len() != n * self.dim {
            return Err(ViewError::Shape("states length is not n × dim"));
        }
        if self.holding.len() != n || self.radius.len() != n {
            return Err(ViewError::Shape("holding/radius length is not n"));
        }
        if self.row_offsets.len() != n + 1 || self.row_offsets[0] != 0 {
            return Err(ViewError::Shape(
                "row_offsets must have n + 1 entries from 0",
            ));
        }
        if self.cols.len() != self.probs.len() || self.row_offsets[n] as usize != self.cols.len() {
            return Err(ViewError::Shape("row_offsets do not end at nnz"));
        }
        for i in 0..n {
            if self.row_offsets[i + 1] < self.row_offsets[i] {
                return Err(ViewError::Shape("row_offsets decrease"));
            }
            let (c, p) = self.row(i);
            if c.iter().any(|&j| j as usize >= n) {
                return Err(ViewError::Column(i));
            }
            if !(self.holding[i] > 0.0) {
                return Err(ViewError::Row(i));
            }
            if c.is_empty() {
                continue;
            }
            let s: f64 = p.iter().sum();
            if p.iter().any(|v| !(*v >= 0.0)) || (s - 1.0).abs() > 1e-9 {
                return Err(ViewError::Row(i));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_rows_survive_relocation_and_compaction() {
        let mut t = Transitions::default();
        for _ in 0..3 {
            t.push_row();
        }
        t.set_row(0, &[1, 2], &[0.5, 0.5]);
        t.set_row(1, &[0], &[1.0]);
        t.set_row(2, &[0, 1], &[0.25, 0.75]);
        t.set_row(0, &[1, 2, 1, 2, 1, 2, 1, 2], &[0.125; 8]); // grows: relocates
        t.set_row(1, &[2], &[1.0]); // fits in place
        assert_eq!(t.row(0).0.len(), 8);
        assert_eq!(t.row(1), (&[2u32][..], &[1.0][..]));
        assert_eq!(t.nnz(), 11);
        assert!(t.csr().is_none());
        t.compact();
        let (off, cols, probs) = t.csr().unwrap();
        assert_eq!(off, &[0, 8, 9, 11]);
        assert_eq!(&cols[8..], &[2, 0, 1]);
        assert_eq!(probs[10], 0.75);
        let u = Transitions::from_csr(off, cols, probs);
        assert_eq!(u.row(2), t.row(2));
    }
}
