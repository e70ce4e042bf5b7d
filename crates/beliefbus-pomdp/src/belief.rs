//! Sparse beliefs and the Bayes update
//! `b^{a,o}(s') = O(o|s',a) Σ_s b(s) T(s'|s,a) / P(o|b,a)`,
//! computed for every observation at once: the prediction
//! `b'_a(s') = Σ_s b(s) T(s'|s,a)` is formed once and split over the
//! observations each end state can emit, so the cost is the non-zeros of T
//! and O touched, never |S|² or |S|·|Z|.

use crate::model::Pomdp;

/// A probability vector over states: sorted indices, non-zero values.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SparseBelief {
    pub idx: Vec<u32>,
    pub val: Vec<f64>,
}

impl SparseBelief {
    /// From a dense vector (zeros dropped).
    pub fn from_dense(d: &[f64]) -> Self {
        let mut b = SparseBelief::default();
        for (i, &p) in d.iter().enumerate() {
            if p != 0.0 {
                b.idx.push(i as u32);
                b.val.push(p);
            }
        }
        b
    }

    /// `Σ_s b(s) v(s)`.
    #[inline]
    pub fn dot(&self, v: &[f64]) -> f64 {
        self.idx
            .iter()
            .zip(&self.val)
            .map(|(&i, &p)| p * v[i as usize])
            .sum()
    }

    pub fn len(&self) -> usize {
        self.idx.len()
    }

    pub fn is_empty(&self) -> bool {
        self.idx.is_empty()
    }

    /// Exact bit pattern, for recognising a belief reached again.
    pub fn key(&self) -> Vec<u64> {
        self.idx
            .iter()
            .zip(&self.val)
            .flat_map(|(&i, &p)| [i as u64, p.to_bits()])
            .collect()
    }
}

/// One observation branch of a belief update.
#[derive(Clone, Debug)]
pub struct Branch {
    pub obs: u32,
    /// P(o | b, a).
    pub prob: f64,
    /// The normalised posterior b^{a,o}.
    pub belief: SparseBelief,
}

/// Reusable buffers for [`Updater::successors`].
pub struct Updater {
    /// Posterior masses below this are dropped (0: exact update).
    pub flush: f64,
    acc: Vec<f64>,
    touched: Vec<u32>,
    buckets: Vec<SparseBelief>,
}

impl Updater {
    pub fn new(p: &Pomdp) -> Self {
        Updater {
            flush: 0.0,
            acc: vec![0.0; p.n_states()],
            touched: Vec::new(),
            buckets: vec![SparseBelief::default(); p.n_obs()],
        }
    }

    /// The prediction `b'_a` (sparse, sorted).
    pub fn predict(&mut self, p: &Pomdp, b: &SparseBelief, a: usize, out: &mut SparseBelief) {
        let t = &p.trans[a];
        for (&s, &bs) in b.idx.iter().zip(&b.val) {
            let (cols, vals) = t.row(s as usize);
            for (&s2, &pt) in cols.iter().zip(vals) {
                if self.acc[s2 as usize] == 0.0 {
                    self.touched.push(s2);
                }
                self.acc[s2 as usize] += bs * pt;
            }
        }
        self.touched.sort_unstable();
        out.idx.clear();
        out.val.clear();
        for &s2 in &self.touched {
            let v = std::mem::take(&mut self.acc[s2 as usize]);
            if v > 0.0 {
                out.idx.push(s2);
                out.val.push(v);
            }
        }
        self.touched.clear();
    }

    /// Every observation with P(o|b,a) > 0 and its posterior, in
    /// observation order.
    pub fn successors(&mut self, p: &Pomdp, b: &SparseBelief, a: usize) -> Vec<Branch> {
        let mut pred = SparseBelief::default();
        self.predict(p, b, a, &mut pred);
        let o_mat = &p.obs[a];
        for (&s2, &bp) in pred.idx.iter().zip(&pred.val) {
            let (obs, probs) = o_mat.row(s2 as usize);
            for (&o, &po) in obs.iter().zip(probs) {
                let bk = &mut self.buckets[o as usize];
                bk.idx.push(s2);
                bk.val.push(bp * po);
            }
        }
        let mut out = Vec::new();
        for (o, bk) in self.buckets.iter_mut().enumerate() {
            if bk.is_empty() {
                continue;
            }
            let prob: f64 = bk.val.iter().sum();
            let mut belief = std::mem::take(bk);
            if prob > 0.0 {
                belief.val.iter_mut().for_each(|v| *v /= prob);
                if self.flush > 0.0 {
                    flush_small(&mut belief, self.flush);
                }
                out.push(Branch {
                    obs: o as u32,
                    prob,
                    belief,
                });
            }
        }
        out
    }
}

/// Drops masses below `eps` and renormalises (the largest mass is kept, so
/// the belief never empties).
fn flush_small(b: &mut SparseBelief, eps: f64) {
    let max = b.val.iter().copied().fold(0.0, f64::max);
    let mut k = 0;
    let mut total = 0.0;
    for j in 0..b.idx.len() {
        if b.val[j] >= eps || b.val[j] == max {
            b.idx[k] = b.idx[j];
            b.val[k] = b.val[j];
            total += b.val[j];
            k += 1;
        }
    }
    b.idx.truncate(k);
    b.val.truncate(k);
    b.val.iter_mut().for_each(|v| *v /= total);
}
