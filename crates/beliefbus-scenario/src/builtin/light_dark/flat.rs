//! The policy as the control path reads it: α-vectors over the chain
//! states in one contiguous row-major block, and the lookup argmax_k α_k·b
//! (allocation-free, no branch per state).

use beliefbus_pomdp::AlphaPolicy;

/// The policy as the controller uses it: the α-vectors restricted to the
/// chain states (the absorbing state's entry is never weighed: the live
/// belief has no mass there), row-major, and their actions.
#[derive(Clone, Debug, PartialEq)]
pub struct FlatPolicy {
    /// Chain states n.
    pub n: usize,
    /// K × n values.
    pub alphas: Vec<f64>,
    pub actions: Vec<usize>,
    /// V̲(b₀) of the solve that produced it.
    pub lower_b0: f64,
}

impl FlatPolicy {
    /// From a policy over the POMDP's states (the chain's n, then the
    /// absorbing one), without the vectors another one dominates on the
    /// chain states (α_j ≤ α_k everywhere: α_j is never needed for the
    /// maximum, so dropping it changes no lookup's value; of equal vectors
    /// the first is kept). O(K² n), done where the policy is prepared,
    /// never on the lookup path.
    pub fn new(p: &AlphaPolicy, n: usize, lower_b0: f64) -> Self {
        let vs = &p.vectors;
        let dominated = |j: usize| {
            (0..vs.len()).any(|k| {
                k != j
                    && vs[k][..n].iter().zip(&vs[j][..n]).all(|(a, b)| a >= b)
                    && (k < j || vs[k][..n] != vs[j][..n])
            })
        };
        let mut alphas = Vec::with_capacity(vs.len() * n);
        let mut actions = Vec::with_capacity(vs.len());
        for (j, v) in vs.iter().enumerate() {
            if !dominated(j) {
                alphas.extend_from_slice(&v[..n]);
                actions.push(p.actions[j]);
            }
        }
        Self {
            n,
            alphas,
            actions,
            lower_b0,
        }
    }

    /// The table of vectors `keep` (indices into this one, in order).
    pub fn subset(&self, keep: &[usize]) -> Self {
        let mut alphas = Vec::with_capacity(keep.len() * self.n);
        for &k in keep {
            alphas.extend_from_slice(self.row(k));
        }
        Self {
            n: self.n,
            alphas,
            actions: keep.iter().map(|&k| self.actions[k]).collect(),
            lower_b0: self.lower_b0,
        }
    }

    /// Vector k.
    pub fn row(&self, k: usize) -> &[f64] {
        &self.alphas[k * self.n..(k + 1) * self.n]
    }

    /// Vectors in the table.
    pub fn len(&self) -> usize {
        self.actions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.actions.is_empty()
    }

    /// The action of argmax_α α·b (`b` has n entries): K·n multiply-adds,
    /// no allocation.
    #[inline]
    pub fn act(&self, b: &[f64]) -> usize {
        self.actions[self.best(b).0]
    }

    /// argmax_α α·b and its value. Four running sums per product (the
    /// entries in groups of four) so the multiply-adds do not wait on one
    /// another; the order of the additions, hence the last bits, differ
    /// from a plain left-to-right sum.
    #[inline]
    pub fn best(&self, b: &[f64]) -> (usize, f64) {
        let b = &b[..self.n];
        let (b4, b_tail) = b.split_at(self.n - self.n % 4);
        let mut best = (0, f64::NEG_INFINITY);
        for (k, alpha) in self.alphas.chunks_exact(self.n).enumerate() {
            let (a4, a_tail) = alpha.split_at(b4.len());
            let mut s = [0.0; 4];
            for (a, p) in a4.chunks_exact(4).zip(b4.chunks_exact(4)) {
                for j in 0..4 {
                    s[j] += a[j] * p[j];
                }
            }
            let mut x = (s[0] + s[1]) + (s[2] + s[3]);
            for (a, p) in a_tail.iter().zip(b_tail) {
                x += a * p;
            }
            if x > best.1 {
                best = (k, x);
            }
        }
        best
    }
}
