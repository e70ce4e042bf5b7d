//! A k-d tree for the exact k-NN lists of incremental construction
//! (thesis Alg. 2.3 with the k-nearest `Near` rule): k-nearest queries and
//! *reverse* nearest-neighbour queries under insertion.
//!
//! Adding z to S must put z into the Near list of every state j with
//! ‖z − z_j‖ < r_k(j), r_k(j) the distance from z_j to its current k-th
//! neighbour. Each point carries a bound b(j) ≥ r_k(j)² and each node the
//! maximum of b over its subtree, so a reverse query
//!
//! ```text
//! visit node ⇔ mindist²(z, bbox(node)) < max_{j ∈ node} b(j)
//! ```
//!
//! only descends where some point's own radius reaches z (a per-region
//! bound instead of the chain-wide maximum k-th radius). Bounds only need to
//! be upper bounds: they are raised on [`KnnTree::set_bound`], lowered on
//! [`KnnTree::tighten_bound`], and node bounds are tightened on the way back
//! up every reverse query and every tightening (a stem's bound becomes the
//! maximum of its children's).
//!
//! Points live in fixed-capacity leaf buckets (coordinates contiguous per
//! leaf, with their slot and bound), nodes keep tight bounding boxes that
//! grow on insertion; a full leaf splits at the median of its widest axis.
//! There is no removal (chains shrink by rebuilding, see [`super::retire`]).
//!
//! Why a second tree next to kiddo ([`super::index::SpatialIndex`]):
//! kiddo has no reverse query. Emulated with it — a radius query at the
//! chain-wide largest k-th radius, filtered by each point's own bound — it
//! is as exact but slower where the chain needs it, measured per insertion
//! (`nn_timing_tests.rs`, release, loaded machine; points 90 % N(½, 0.05²)
//! and 10 % uniform as the belief-concentrated samplers place them, k =
//! max(⌈1.5 ln n⌉, moment floor)): d = 2, n = 10⁵: 311 µs vs 4.6 µs here;
//! d = 4, n = 10⁵: 1.12 ms vs 0.18 ms; d = 6, n = 10⁵: 1.20 ms vs 0.87 ms;
//! on uniform points 1.0–3.2× slower at n ≥ 10⁴ (faster only at n = 10³,
//! d ≥ 4). kiddo builds 2–5× faster and answers plain k-NN queries faster
//! in most cases (d = 4, n = 10⁵: 6.4 µs vs 14 µs), so it keeps those; this
//! tree serves only the k-NN lists of incremental construction.

/// Points per leaf bucket.
const BUCKET: usize = 32;
/// Points per leaf of a bulk-built tree (room left for insertions).
const BULK_LEAF: usize = 24;
const NONE: u32 = u32::MAX;
/// Largest dimension supported.
pub const MAX_DIM: usize = 16;

#[derive(Clone, Copy, Debug)]
struct Node {
    /// Stem: split axis and children; leaf: `leaf` is the bucket index.
    axis: u32,
    split: f64,
    left: u32,
    right: u32,
    parent: u32,
    leaf: u32,
    /// Upper bound on the point bounds b(j) in the subtree.
    max_b: f64,
}

/// k-d tree over `u32` slots with per-point bounds for reverse queries.
#[derive(Clone, Debug)]
pub struct KnnTree {
    dim: usize,
    nodes: Vec<Node>,
    /// Tight bounding box per node: lo (d values) then hi (d values).
    bbox: Vec<f64>,
    /// Leaf buckets: coordinates (BUCKET × d), slots, bounds, length, node.
    coords: Vec<f64>,
    slots: Vec<u32>,
    bounds: Vec<f64>,
    lens: Vec<u32>,
    leaf_node: Vec<u32>,
    /// Where each slot lives: (leaf, position); NONE if not stored.
    loc: Vec<(u32, u32)>,
    len: usize,
}

impl KnnTree {
    /// An empty tree for points of dimension `dim` (1..=[`MAX_DIM`]).
    pub fn new(dim: usize) -> Self {
        let mut t = Self {
            dim: dim.clamp(1, MAX_DIM),
            nodes: vec![],
            bbox: vec![],
            coords: vec![],
            slots: vec![],
            bounds: vec![],
            lens: vec![],
            leaf_node: vec![],
            loc: vec![],
            len: 0,
        };
        t.new_leaf_node(NONE);
        t
    }

    /// A tree over the flat `n × dim` `points`, slot i for point i, all
    /// bounds 0 (balanced: median splits on the widest axis).
    pub fn from_points(dim: usize, points: &[f64]) -> Self {
        let mut t = Self::new(dim);
        let d = t.dim;
        let n = points.len() / d;
        t.loc = vec![(NONE, NONE); n];
        let mut order: Vec<u32> = (0..n as u32).collect();
        if n > 0 {
            t.build(0, points, &mut order);
        }
        t.len = n;
        t
    }

    fn build(&mut self, node: u32, points: &[f64], idx: &mut [u32]) {
        let d = self.dim;
        // Tight box.
        let b = node as usize * 2 * d;
        for &i in idx.iter() {
            let p = &points[i as usize * d..(i as usize + 1) * d];
            for c in 0..d {
                self.bbox[b + c] = self.bbox[b + c].min(p[c]);
                self.bbox[b + d + c] = self.bbox[b + d + c].max(p[c]);
            }
        }
        if idx.len() <= BULK_LEAF {
            let leaf = self.nodes[node as usize].leaf as usize;
            for &i in idx.iter() {
                let pos = self.lens[leaf] as usize;
                let p = &points[i as usize * d..(i as usize + 1) * d];
                self.put(leaf, pos, p, i, 0.0);
                self.lens[leaf] += 1;
            }
            return;
        }
        let axis = self.widest_axis(node as usize);
        let mid = idx.len() / 2;
        idx.select_nth_unstable_by(mid, |a, b| {
            points[*a as usize * d + axis].total_cmp(&points[*b as usize * d + axis])
        });
        let split = points[idx[mid] as usize * d + axis];
        let (l, r) = self.make_stem(node, axis, split);
        let (lo, hi) = idx.split_at_mut(mid);
        self.build(l, points, lo);
        self.build(r, points, hi);
    }

    fn widest_axis(&self, node: usize) -> usize {
        let d = self.dim;
        let b = node * 2 * d;
        (0..d)
            .max_by(|&a, &c| {
                let wa = self.bbox[b + d + a] - self.bbox[b + a];
                let wc = self.bbox[b + d + c] - self.bbox[b + c];
                wa.total_cmp(&wc)
            })
            .unwrap_or(0)
    }

    fn new_leaf_node(&mut self, parent: u32) -> u32 {
        let d = self.dim;
        let leaf = self.lens.len() as u32;
        let node = self.nodes.len() as u32;
        self.nodes.push(Node {
            axis: 0,
            split: 0.0,
            left: NONE,
            right: NONE,
            parent,
            leaf,
            max_b: 0.0,
        });
        self.bbox.extend(std::iter::repeat_n(f64::INFINITY, d));
        self.bbox.extend(std::iter::repeat_n(f64::NEG_INFINITY, d));
        self.coords.resize(self.coords.len() + BUCKET * d, 0.0);
        self.slots.resize(self.slots.len() + BUCKET, NONE);
        self.bounds.resize(self.bounds.len() + BUCKET, 0.0);
        self.lens.push(0);
        self.leaf_node.push(node);
        node
    }

    /// Turn leaf node `node` into a stem with two new empty leaves (the old
    /// bucket is reused by the left child).
    fn make_stem(&mut self, node: u32, axis: usize, split: f64) -> (u32, u32) {
        let old_leaf = self.nodes[node as usize].leaf;
        let l = self.nodes.len() as u32;
        // Left child takes over the old bucket.
        let d = self.dim;
        self.nodes.push(Node {
            axis: 0,
            split: 0.0,
            left: NONE,
            right: NONE,
            parent: node,
            leaf: old_leaf,
            max_b: 0.0,
        });
        self.bbox.extend(std::iter::repeat_n(f64::INFINITY, d));
        self.bbox.extend(std::iter::repeat_n(f64::NEG_INFINITY, d));
        self.leaf_node[old_leaf as usize] = l;
        let r = self.new_leaf_node(node);
        let n = &mut self.nodes[node as usize];
        n.axis = axis as u32;
        n.split = split;
        n.left = l;
        n.right = r;
        n.leaf = NONE;
        (l, r)
    }

    fn put(&mut self, leaf: usize, pos: usize, p: &[f64], slot: u32, b: f64) {
        let d = self.dim;
        let e = leaf * BUCKET + pos;
        self.coords[e * d..(e + 1) * d].copy_from_slice(p);
        self.slots[e] = slot;
        self.bounds[e] = b;
        if self.loc.len() <= slot as usize {
            self.loc.resize(slot as usize + 1, (NONE, NONE));
        }
        self.loc[slot as usize] = (leaf as u32, pos as u32);
        let node = self.leaf_node[leaf] as usize;
        self.nodes[node].max_b = self.nodes[node].max_b.max(b);
    }

    /// Reserve room for `extra` more points (leaves split when full, so
    /// at most one new leaf per BUCKET / 2 insertions).
    pub fn reserve(&mut self, extra: usize) {
        let d = self.dim;
        let leaves = extra / (BUCKET / 2) + 1;
        self.nodes.reserve(2 * leaves);
        self.bbox.reserve(4 * leaves * d);
        self.coords.reserve(leaves * BUCKET * d);
        self.slots.reserve(leaves * BUCKET);
        self.bounds.reserve(leaves * BUCKET);
        self.lens.reserve(leaves);
        self.leaf_node.reserve(leaves);
        self.loc.reserve(extra);
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the tree holds no point.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Insert point `p` as `slot` with bound 0. A slot must be inserted once.
    pub fn insert(&mut self, p: &[f64], slot: u32) {
        let d = self.dim;
        let mut node = 0usize;
        loop {
            let b = node * 2 * d;
            for c in 0..d {
                self.bbox[b + c] = self.bbox[b + c].min(p[c]);
                self.bbox[b + d + c] = self.bbox[b + d + c].max(p[c]);
            }
            let n = self.nodes[node];
            if n.leaf != NONE {
                break;
            }
            node = if p[n.axis as usize] < n.split {
                n.left as usize
            } else {
                n.right as usize
            };
        }
        let leaf = self.nodes[node].leaf as usize;
        let pos = self.lens[leaf] as usize;
        self.put(leaf, pos, p, slot, 0.0);
        self.lens[leaf] += 1;
        self.len += 1;
        if self.lens[leaf] as usize == BUCKET {
            self.split_leaf(node);
        }
    }

    /// Split the full leaf at `node` at the median of its widest axis.
    fn split_leaf(&mut self, node: usize) {
        let d = self.dim;
        let leaf = self.nodes[node].leaf as usize;
        let axis = self.widest_axis(node);
        let mut ent = [([0.0; MAX_DIM], 0u32, 0.0f64); BUCKET];
        for (pos, en) in ent.iter_mut().enumerate() {
            let e = leaf * BUCKET + pos;
            en.0[..d].copy_from_slice(&self.coords[e * d..(e + 1) * d]);
            en.1 = self.slots[e];
            en.2 = self.bounds[e];
        }
        let mid = BUCKET / 2;
        ent.select_nth_unstable_by(mid, |a, b| a.0[axis].total_cmp(&b.0[axis]));
        let split = ent[mid].0[axis];
        let (l, r) = self.make_stem(node as u32, axis, split);
        self.lens[leaf] = 0;
        for (half, child) in [(&ent[..mid], l), (&ent[mid..], r)] {
            let cl = self.nodes[child as usize].leaf as usize;
            let cb = child as usize * 2 * d;
            for (p, slot, b) in half {
                for c in 0..d {
                    self.bbox[cb + c] = self.bbox[cb + c].min(p[c]);
                    self.bbox[cb + d + c] = self.bbox[cb + d + c].max(p[c]);
                }
                let pos = self.lens[cl] as usize;
                self.put(cl, pos, &p[..d], *slot, *b);
                self.lens[cl] += 1;
            }
        }
    }

    /// Set the bound of `slot` to `b` (raising the node bounds above it).
    pub fn set_bound(&mut self, slot: u32, b: f64) {
        let Some(&(leaf, pos)) = self.loc.get(slot as usize) else {
            return;
        };
        if leaf == NONE {
            return;
        }
        self.bounds[leaf as usize * BUCKET + pos as usize] = b;
        let mut node = self.leaf_node[leaf as usize];
        while node != NONE {
            let n = &mut self.nodes[node as usize];
            if n.max_b >= b {
                break;
            }
            n.max_b = b;
            node = n.parent;
        }
    }

    /// Lower the bound of `slot` to `b` (≤ its current bound) and tighten
    /// the node bounds above it to the maximum of what lies below.
    pub fn tighten_bound(&mut self, slot: u32, b: f64) {
        let Some(&(leaf, pos)) = self.loc.get(slot as usize) else {
            return;
        };
        if leaf == NONE {
            return;
        }
        let leaf = leaf as usize;
        let base = leaf * BUCKET;
        self.bounds[base + pos as usize] = b;
        let len = self.lens[leaf] as usize;
        let mut m = self.bounds[base..base + len]
            .iter()
            .fold(0.0f64, |a, &v| a.max(v));
        let mut node = self.leaf_node[leaf] as usize;
        loop {
            if self.nodes[node].max_b == m {
                return;
            }
            self.nodes[node].max_b = m;
            let parent = self.nodes[node].parent;
            if parent == NONE {
                return;
            }
            node = parent as usize;
            let n = self.nodes[node];
            m = self.nodes[n.left as usize]
                .max_b
                .max(self.nodes[n.right as usize].max_b);
        }
    }

    /// The bound of `slot`.
    pub fn bound(&self, slot: u32) -> Option<f64> {
        let &(leaf, pos) = self.loc.get(slot as usize)?;
        (leaf != NONE).then(|| self.bounds[leaf as usize * BUCKET + pos as usize])
    }

    #[inline]
    fn mindist2(&self, node: usize, q: &[f64]) -> f64 {
        let d = self.dim;
        let b = node * 2 * d;
        let mut s = 0.0;
        for c in 0..d {
            s += gap2(self.bbox[b + c], self.bbox[b + d + c], q[c]);
        }
        s
    }

    /// The `k` nearest points to `q` other than `skip` (pass `u32::MAX` to
    /// skip none), ascending, into `out` as (slot, squared distance).
    pub fn nearest(&self, q: &[f64], k: usize, skip: u32, out: &mut Vec<(u32, f64)>) {
        out.clear();
        if k == 0 || self.len == 0 {
            return;
        }
        self.knn_rec(0, q, k, skip, out);
    }

    fn knn_rec(&self, node: usize, q: &[f64], k: usize, skip: u32, out: &mut Vec<(u32, f64)>) {
        let n = self.nodes[node];
        if n.leaf != NONE {
            let d = self.dim;
            let leaf = n.leaf as usize;
            let len = self.lens[leaf] as usize;
            let base = leaf * BUCKET;
            for pos in 0..len {
                let e = base + pos;
                let d2 = sq_dist(&self.coords[e * d..(e + 1) * d], q);
                let slot = self.slots[e];
                if slot == skip {
                    continue;
                }
                offer_nearest(out, k, slot, d2);
            }
            return;
        }
        let (a, b) = (n.left as usize, n.right as usize);
        let (da, db) = (self.mindist2(a, q), self.mindist2(b, q));
        let ((c1, d1), (c2, d2)) = if da <= db {
            ((a, da), (b, db))
        } else {
            ((b, db), (a, da))
        };
        for (c, dc) in [(c1, d1), (c2, d2)] {
            if out.len() == k && !(dc < out[k - 1].1) {
                return;
            }
            self.knn_rec(c, q, k, skip, out);
        }
    }

    /// Reverse query: `visit(slot, d2, bound)` for every point with
    /// squared distance d2 to `q` below its bound (strictly). `visit`
    /// returns the point's new bound (e.g. its new k-th squared distance
    /// once q joined its list). Node bounds are tightened on the way.
    pub fn reverse<F: FnMut(u32, f64, f64) -> f64>(&mut self, q: &[f64], visit: &mut F) {
        let mut none = Vec::new();
        self.nearest_and_reverse(q, 0, NONE, &mut none, visit);
    }

    /// [`Self::nearest`] and [`Self::reverse`] in one traversal (the k
    /// nearest points lie where the reverse query searches anyway); `visit`
    /// runs before the k nearest are final.
    pub fn nearest_and_reverse<F: FnMut(u32, f64, f64) -> f64>(
        &mut self,
        q: &[f64],
        k: usize,
        skip: u32,
        out: &mut Vec<(u32, f64)>,
        visit: &mut F,
    ) {
        out.clear();
        if self.len == 0 {
            return;
        }
        // The leaf scans and box distances dominate: compile them for the
        // common state dimensions (D = 0: run-time d).
        match self.dim {
            2 => self.both_rec::<2, F>(0, q, k, skip, out, visit),
            3 => self.both_rec::<3, F>(0, q, k, skip, out, visit),
            4 => self.both_rec::<4, F>(0, q, k, skip, out, visit),
            _ => self.both_rec::<0, F>(0, q, k, skip, out, visit),
        }
    }

    /// Squared distance from `q` to point `e` of the leaf slabs.
    #[inline(always)]
    fn point_d2<const D: usize>(&self, e: usize, q: &[f64]) -> f64 {
        if D == 0 {
            let d = self.dim;
            return sq_dist(&self.coords[e * d..(e + 1) * d], q);
        }
        let p = &self.coords[e * D..e * D + D];
        let q = &q[..D];
        let mut s = 0.0;
        for c in 0..D {
            let v = p[c] - q[c];
            s += v * v;
        }
        s
    }

    /// [`Self::mindist2`] for a dimension known at compile time.
    #[inline(always)]
    fn mindist2_d<const D: usize>(&self, node: usize, q: &[f64]) -> f64 {
        if D == 0 {
            return self.mindist2(node, q);
        }
        let b = &self.bbox[node * 2 * D..node * 2 * D + 2 * D];
        let q = &q[..D];
        let mut s = 0.0;
        for c in 0..D {
            s += gap2(b[c], b[D + c], q[c]);
        }
        s
    }

    fn both_rec<const D: usize, F: FnMut(u32, f64, f64) -> f64>(
        &mut self,
        node: usize,
        q: &[f64],
        k: usize,
        skip: u32,
        out: &mut Vec<(u32, f64)>,
        visit: &mut F,
    ) {
        let n = self.nodes[node];
        if n.leaf != NONE {
            let leaf = n.leaf as usize;
            let len = self.lens[leaf] as usize;
            let base = leaf * BUCKET;
            let mut m = 0.0f64;
            for pos in 0..len {
                let e = base + pos;
                let d2 = self.point_d2::<D>(e, q);
                if d2 < self.bounds[e] {
                    self.bounds[e] = visit(self.slots[e], d2, self.bounds[e]);
                }
                m = m.max(self.bounds[e]);
                let slot = self.slots[e];
                if k == 0 || slot == skip {
                    continue;
                }
                offer_nearest(out, k, slot, d2);
            }
            self.nodes[node].max_b = m;
            return;
        }
        let (a, b) = (n.left as usize, n.right as usize);
        let (da, db) = (self.mindist2_d::<D>(a, q), self.mindist2_d::<D>(b, q));
        let order = if da <= db {
            [(a, da), (b, db)]
        } else {
            [(b, db), (a, da)]
        };
        for (c, dc) in order {
            let for_knn = k > 0 && (out.len() < k || dc < out[k - 1].1);
            if for_knn || dc < self.nodes[c].max_b {
                self.both_rec::<D, F>(c, q, k, skip, out, visit);
            }
        }
        self.nodes[node].max_b = self.nodes[a].max_b.max(self.nodes[b].max_b);
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.nodes.capacity() * std::mem::size_of::<Node>()
            + (self.bbox.capacity() + self.coords.capacity() + self.bounds.capacity()) * 8
            + (self.slots.capacity() + self.lens.capacity() + self.leaf_node.capacity()) * 4
            + self.loc.capacity() * 8
    }
}

/// Squared distance from coordinate `q` to the interval [lo, hi] (0 inside).
#[inline(always)]
fn gap2(lo: f64, hi: f64, q: f64) -> f64 {
    let v = if q < lo {
        lo - q
    } else if q > hi {
        q - hi
    } else {
        0.0
    };
    v * v
}

/// Squared Euclidean distance.
#[inline]
fn sq_dist(p: &[f64], q: &[f64]) -> f64 {
    p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum()
}

/// Insert (slot, d2) into `out`, the up to `k` nearest so far sorted by
/// squared distance, if it is nearer than the k-th (ties keep the earlier).
#[inline]
fn offer_nearest(out: &mut Vec<(u32, f64)>, k: usize, slot: u32, d2: f64) {
    if out.len() == k {
        if !(d2 < out[k - 1].1) {
            return;
        }
        out.pop();
    }
    let mut i = out.len();
    out.push((slot, d2));
    while i > 0 && out[i - 1].1 > d2 {
        out[i] = out[i - 1];
        i -= 1;
    }
    out[i] = (slot, d2);
}

#[cfg(test)]
#[path = "knn_tree_tests.rs"]
mod tests;
