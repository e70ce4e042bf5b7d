//! Batch construction (thesis Alg. 2.1) as resumable work: the same chain
//! as [`Chain::batch`], built in units that a caller with a deadline can
//! stop between and continue later (the refine stage's anytime rounds).
//!
//! ```text
//! push:    per point: f(z), F Fᵀ(z), its Cholesky factor (caches)   one unit per state
//! index:   the k-d tree over all points                             one unit
//! order:   the Hilbert-curve order of the points                    one unit
//! connect: ConnectState(z) with the final n, in Hilbert order       one unit per row
//! ```
//!
//! Each row depends only on the states (Alg. 2.1 connects with the final
//! n), so stopping between units changes nothing in the result: a build run
//! in slices gives the rows of [`Chain::batch`] bit for bit (test
//! `a_build_in_slices_is_the_batch_chain`). The largest unit is the k-d tree
//! (O(n log n), about a tenth of the rows' cost at n = 2000).

use super::Chain;
use crate::chain::index::SpatialIndex;
use crate::chain::{ChainConfig, ChainError};
use crate::model::SdeModel;

/// Where a [`BatchBuild`] is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// States pushed so far.
    Push(usize),
    Index,
    Order,
    /// Position in `order` of the next row to connect.
    Connect(usize),
    Done,
}

/// A batch chain under construction (see the module doc).
pub struct BatchBuild {
    chain: Chain,
    points: Vec<f64>,
    order: Vec<u32>,
    phase: Phase,
}

impl BatchBuild {
    /// Start building the batch chain of `points` (flat n × d) for `model`
    /// with `cfg`. Checks the configuration and the points' length; no
    /// state is pushed yet.
    pub fn new<M: SdeModel + ?Sized>(
        model: &M,
        cfg: ChainConfig,
        points: Vec<f64>,
    ) -> Result<Self, ChainError> {
        let mut chain = Chain::new(model, cfg)?;
        let d = chain.dim;
        if !points.len().is_multiple_of(d) {
            return Err(ChainError::State("points length is not a multiple of d"));
        }
        chain.reserve(points.len() / d);
        Ok(Self {
            chain,
            points,
            order: Vec::new(),
            phase: Phase::Push(0),
        })
    }

    /// Number of states of the chain being built.
    pub fn len(&self) -> usize {
        self.points.len() / self.chain.dim
    }

    /// Whether the chain has no states.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Whether every row is connected ([`Self::finish`] then returns the
    /// chain).
    pub fn is_done(&self) -> bool {
        self.phase == Phase::Done
    }

    /// Units done and units in all: n pushes, the index, the order, n rows.
    pub fn progress(&self) -> (usize, usize) {
        let n = self.len();
        let done = match self.phase {
            Phase::Push(i) => i,
            Phase::Index => n,
            Phase::Order => n + 1,
            Phase::Connect(k) => n + 2 + k,
            Phase::Done => 2 * n + 2,
        };
        (done, 2 * n + 2)
    }

    /// Do units of work while `more()` says so: `more` is asked before
    /// every unit but the first, so each call makes progress and a build
    /// always completes. `model` must be the one given to [`Self::new`]
    /// (it is read while states are pushed). Returns whether the build is
    /// complete.
    pub fn run<M: SdeModel + ?Sized>(
        &mut self,
        model: &M,
        mut more: impl FnMut() -> bool,
    ) -> Result<bool, ChainError> {
        let mut first = true;
        while self.phase != Phase::Done && (first || more()) {
            first = false;
            self.unit(model)?;
        }
        Ok(self.is_done())
    }

    /// One unit of work.
    fn unit<M: SdeModel + ?Sized>(&mut self, model: &M) -> Result<(), ChainError> {
        let d = self.chain.dim;
        let n = self.len();
        self.phase = match self.phase {
            Phase::Push(i) if i < n => {
                self.chain
                    .push_state(model, &self.points[i * d..(i + 1) * d])?;
                if i + 1 < n {
                    Phase::Push(i + 1)
                } else {
                    Phase::Index
                }
            }
            // No states: nothing to push.
            Phase::Push(_) | Phase::Index => {
                self.chain.index =
                    SpatialIndex::from_points(d, &self.points).ok_or(ChainError::State(
                        "kd-tree cannot store the states (too many share coordinate values)",
                    ))?;
                // The reverse-query tree serves incremental insertion only;
                // it is built from the lists at the first `add_state` (batch
                // pays nothing).
                self.chain.rtree = None;
                Phase::Order
            }
            Phase::Order => {
                // ConnectState in a space-filling-curve order of the
                // states: each row depends only on the states, so the order
                // changes no result, but consecutive k-d tree queries then
                // touch the same leaves.
                self.order = crate::chain::order::hilbert_order(&self.points, d);
                Phase::Connect(0)
            }
            Phase::Connect(k) if k < self.order.len() => {
                self.chain.connect(self.order[k] as usize)?;
                if k + 1 < self.order.len() {
                    Phase::Connect(k + 1)
                } else {
                    Phase::Done
                }
            }
            Phase::Connect(_) | Phase::Done => Phase::Done,
        };
        Ok(())
    }

    /// The chain, once the build is complete (check [`Self::is_done`]:
    /// an incomplete build is an error and is dropped).
    pub fn finish(self) -> Result<Chain, ChainError> {
        if self.is_done() {
            Ok(self.chain)
        } else {
            Err(ChainError::State(
                "batch construction stopped before its end",
            ))
        }
    }
}
