//! The spatial index behind `Near` (thesis §2.4.1): a k-d tree with
//! incremental insertion and removal, from the `kiddo` crate.
//!
//! kiddo fixes the dimension at compile time (`[f64; K]`); chains get theirs
//! from the model at run time, so [`SpatialIndex`] dispatches over one tree
//! type per dimension 1..=9 (state dimensions up to [`crate::MAX_STATE`] plus
//! one for the decoder's time-augmented chain).

use kiddo::{MutableKdTree, SquaredEuclidean};
use std::num::NonZeroUsize;

/// Largest dimension the index supports.
pub const MAX_INDEX_DIM: usize = 9;

/// The k-d tree could not store a point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IndexError;

/// A k-d tree over points of a run-time dimension, items are `u32` slots.
pub struct SpatialIndex {
    tree: Tree,
}

enum Tree {
    D1(MutableKdTree<f64, 1>),
    D2(MutableKdTree<f64, 2>),
    D3(MutableKdTree<f64, 3>),
    D4(MutableKdTree<f64, 4>),
    D5(MutableKdTree<f64, 5>),
    D6(MutableKdTree<f64, 6>),
    D7(MutableKdTree<f64, 7>),
    D8(MutableKdTree<f64, 8>),
    D9(MutableKdTree<f64, 9>),
}

macro_rules! dispatch {
    ($self:expr, $t:ident, $k:ident => $body:expr) => {
        match $self {
            Tree::D1($t) => {
                const $k: usize = 1;
                $body
            }
            Tree::D2($t) => {
                const $k: usize = 2;
                $body
            }
            Tree::D3($t) => {
                const $k: usize = 3;
                $body
            }
            Tree::D4($t) => {
                const $k: usize = 4;
                $body
            }
            Tree::D5($t) => {
                const $k: usize = 5;
                $body
            }
            Tree::D6($t) => {
                const $k: usize = 6;
                $body
            }
            Tree::D7($t) => {
                const $k: usize = 7;
                $body
            }
            Tree::D8($t) => {
                const $k: usize = 8;
                $body
            }
            Tree::D9($t) => {
                const $k: usize = 9;
                $body
            }
        }
    };
}

impl Clone for SpatialIndex {
    /// kiddo's mutable trees are not `Clone`; rebuild from their entries.
    fn clone(&self) -> Self {
        let tree = match &self.tree {
            Tree::D1(t) => Tree::D1(rebuild(t.iter())),
            Tree::D2(t) => Tree::D2(rebuild(t.iter())),
            Tree::D3(t) => Tree::D3(rebuild(t.iter())),
            Tree::D4(t) => Tree::D4(rebuild(t.iter())),
            Tree::D5(t) => Tree::D5(rebuild(t.iter())),
            Tree::D6(t) => Tree::D6(rebuild(t.iter())),
            Tree::D7(t) => Tree::D7(rebuild(t.iter())),
            Tree::D8(t) => Tree::D8(rebuild(t.iter())),
            Tree::D9(t) => Tree::D9(rebuild(t.iter())),
        };
        Self { tree }
    }
}

fn rebuild<const K: usize>(it: impl Iterator<Item = (u32, [f64; K])>) -> MutableKdTree<f64, K> {
    let mut t = MutableKdTree::<f64, K>::default();
    for (item, p) in it {
        // Every entry came from a tree that held it.
        t.add(&p, item).expect("re-inserting a stored entry");
    }
    t
}

fn arr<const K: usize>(p: &[f64]) -> [f64; K] {
    let mut a = [0.0; K];
    a.copy_from_slice(&p[..K]);
    a
}

impl SpatialIndex {
    /// An empty index for points of dimension `dim` (1..=[`MAX_INDEX_DIM`]).
    pub fn new(dim: usize) -> Option<Self> {
        let tree = match dim {
            1 => Tree::D1(Default::default()),
            2 => Tree::D2(Default::default()),
            3 => Tree::D3(Default::default()),
            4 => Tree::D4(Default::default()),
            5 => Tree::D5(Default::default()),
            6 => Tree::D6(Default::default()),
            7 => Tree::D7(Default::default()),
            8 => Tree::D8(Default::default()),
            9 => Tree::D9(Default::default()),
            _ => return None,
        };
        Some(Self { tree })
    }

    /// Build an index over `points` (flat, `n × dim`), item i for point i.
    pub fn from_points(dim: usize, points: &[f64]) -> Option<Self> {
        Self::bulk(dim, points).or_else(|| {
            // Bulk construction refuses inputs with many equal coordinates
            // on one axis (e.g. the decoder's states on {T} × S); insert
            // one by one instead.
            let mut idx = Self::new(dim)?;
            for (i, p) in points.chunks_exact(dim).enumerate() {
                idx.insert(p, i as u32).ok()?;
            }
            Some(idx)
        })
    }

    fn bulk(dim: usize, points: &[f64]) -> Option<Self> {
        let n = points.len() / dim.max(1);
        let tree = match dim {
            1 => Tree::D1(MutableKdTree::new_from_slice(&chunks::<1>(points)).ok()?),
            2 => Tree::D2(MutableKdTree::new_from_slice(&chunks::<2>(points)).ok()?),
            3 => Tree::D3(MutableKdTree::new_from_slice(&chunks::<3>(points)).ok()?),
            4 => Tree::D4(MutableKdTree::new_from_slice(&chunks::<4>(points)).ok()?),
            5 => Tree::D5(MutableKdTree::new_from_slice(&chunks::<5>(points)).ok()?),
            6 => Tree::D6(MutableKdTree::new_from_slice(&chunks::<6>(points)).ok()?),
            7 => Tree::D7(MutableKdTree::new_from_slice(&chunks::<7>(points)).ok()?),
            8 => Tree::D8(MutableKdTree::new_from_slice(&chunks::<8>(points)).ok()?),
            9 => Tree::D9(MutableKdTree::new_from_slice(&chunks::<9>(points)).ok()?),
            _ => return None,
        };
        let idx = Self { tree };
        debug_assert_eq!(idx.len(), n);
        Some(idx)
    }

    /// Number of points stored.
    pub fn len(&self) -> usize {
        dispatch!(&self.tree, t, K => { let _ = K; t.size() })
    }

    /// Whether the index is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Insert point `p` with item `slot`. Fails when a leaf cannot be split
    /// (more than a bucket of points share a coordinate value on every
    /// splittable axis — kiddo's limitation).
    pub fn insert(&mut self, p: &[f64], slot: u32) -> Result<(), IndexError> {
        dispatch!(&mut self.tree, t, K => {
            t.add(&arr::<K>(p), slot).map_err(|_| IndexError)
        })
    }

    /// Remove point `p` with item `slot`.
    pub fn remove(&mut self, p: &[f64], slot: u32) {
        dispatch!(&mut self.tree, t, K => { t.remove(&arr::<K>(p), slot); })
    }

    /// The `k` nearest points to `p`, sorted by distance, into `out` as
    /// (slot, squared distance). `out` is cleared first.
    pub fn nearest(&self, p: &[f64], k: usize, out: &mut Vec<(u32, f64)>) {
        out.clear();
        let Some(k) = NonZeroUsize::new(k) else {
            return;
        };
        dispatch!(&self.tree, t, K => {
            let q = arr::<K>(p);
            let res = t.query(&q).nearest_n::<SquaredEuclidean<f64>>(k).execute();
            out.extend(res.iter().map(|r| (r.item, r.distance)));
        })
    }

    /// Every point within Euclidean distance `radius` of `p` (unsorted),
    /// into `out` as (slot, squared distance). `out` is cleared first.
    pub fn within(&self, p: &[f64], radius: f64, out: &mut Vec<(u32, f64)>) {
        out.clear();
        let r2 = radius * radius;
        dispatch!(&self.tree, t, K => {
            let q = arr::<K>(p);
            t.query(&q)
                .within::<SquaredEuclidean<f64>>(r2)
                .unsorted()
                .visit(|r| out.push((r.item, r.distance)));
        })
    }
}

fn chunks<const K: usize>(points: &[f64]) -> Vec<[f64; K]> {
    points.chunks_exact(K).map(arr::<K>).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::stream;
    use rand::RngExt;

    #[test]
    fn nearest_and_within_match_brute_force() {
        let mut rng = stream(3, 0);
        for dim in [1usize, 2, 4, 9] {
            let n = 500;
            let pts: Vec<f64> = (0..n * dim).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut idx = SpatialIndex::new(dim).unwrap();
            for i in 0..n {
                idx.insert(&pts[i * dim..(i + 1) * dim], i as u32).unwrap();
            }
            let built = SpatialIndex::from_points(dim, &pts).unwrap();
            assert_eq!(idx.len(), n);
            assert_eq!(built.len(), n);
            let q: Vec<f64> = (0..dim).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut d2: Vec<(u32, f64)> = (0..n)
                .map(|i| {
                    let s = (0..dim).map(|j| (pts[i * dim + j] - q[j]).powi(2)).sum();
                    (i as u32, s)
                })
                .collect();
            d2.sort_by(|a, b| a.1.total_cmp(&b.1));
            let mut out = Vec::new();
            for tree in [&idx, &built] {
                tree.nearest(&q, 7, &mut out);
                let got: Vec<u32> = out.iter().map(|x| x.0).collect();
                let want: Vec<u32> = d2[..7].iter().map(|x| x.0).collect();
                assert_eq!(got, want, "dim {dim}");
                let r = d2[20].1.sqrt() + 1e-12;
                tree.within(&q, r, &mut out);
                let mut got: Vec<u32> = out.iter().map(|x| x.0).collect();
                got.sort();
                let mut want: Vec<u32> = d2[..21].iter().map(|x| x.0).collect();
                want.sort();
                assert_eq!(got, want, "dim {dim}");
            }
            idx.remove(&pts[0..dim], 0);
            assert_eq!(idx.len(), n - 1);
        }
    }
}
