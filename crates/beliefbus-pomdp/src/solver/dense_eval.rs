//! Test support: a finite-state controller's value by a dense linear
//! solve, independent of [`super::graph::evaluate`]'s iteration and
//! certificate.

use super::graph::Controller;
use crate::model::Pomdp;
use nalgebra::{DMatrix, DVector};

/// The controller's value by solving `(I − γ M) V = R` densely
/// (independent of [`super::graph::evaluate`]'s iteration and certificate).
pub(crate) fn exact_value(p: &Pomdp, c: &Controller) -> Vec<Vec<f64>> {
    let (ns, no, k) = (p.n_states(), p.n_obs(), c.len());
    let n = k * ns;
    let mut m = DMatrix::<f64>::identity(n, n);
    let mut r = DVector::<f64>::zeros(n);
    for node in 0..k {
        let a = c.action[node];
        for s in 0..ns {
            let row = node * ns + s;
            r[row] = p.reward[a][s];
            for s2 in 0..ns {
                let t = p.trans[a].get(s, s2);
                for o in 0..no {
                    let q = p.obs[a].get(s2, o);
                    let col = c.next[node * no + o] as usize * ns + s2;
                    m[(row, col)] -= p.discount * t * q;
                }
            }
        }
    }
    let v = m.lu().solve(&r).expect("I − γM is invertible for γ < 1");
    (0..k)
        .map(|node| v.as_slice()[node * ns..(node + 1) * ns].to_vec())
        .collect()
}
