//! Moment-consistent rows over one decision period h: an alternative to the
//! thesis's kernel rows ([`super::rows`]) that matches the SDE's first two
//! moments over h as closely as the chain's states allow (the local
//! consistency conditions of thesis 000 Alg. 4.3 / Kushner–Dupuis, imposed
//! on the period's row directly instead of on the holding-time kernel).
//!
//! For state z and control u, with Σ = F Fᵀ(z) h and τ = tr Σ:
//!
//! ```text
//! m  = clamp_box(z + f(z, u) h)          (the domain's box: the continuous system is clamped there)
//! m ← z + t*(m − z),  t* = max{t ≤ 1 : z + t(m − z) ∈ conv(states)}   (only if m is outside the hull)
//! T(·|z, u) = p,  Σ_k p_k z_k = m,  Σ_k p_k = 1,  p ≥ 0                 (the mean exactly m)
//! p_min = argmin Σ_k p_k |z_k − m|²   over the k nearest states to m      (a linear program)
//! V_min = Σ_k p_min,k |z_k − m|²
//! τ ≤ V_min:  p = p_min                                                 (the least achievable spread)
//! τ > V_min:  p = (1 − w) p_min + w q,  w = (τ − V_min)/(V_q − V_min)   (trace exactly τ)
//!             q_k ∝ N(z_k − m; 0, c Σ) e^{λ·(z_k − m)},  Σ_k q_k (z_k − m) = 0,  V_q > τ
//! ```
//!
//! * **Minimum spread.** The minimum-variance mean-exact distribution is a
//!   linear program in p with d + 1 equality constraints, so an optimal
//!   vertex has at most d + 1 support points; it is the simplex of the
//!   Delaunay triangulation that contains m (Rajan 1991: among all
//!   triangulations of a point set the Delaunay one minimises, at every
//!   point of the hull, the piecewise-linear interpolant of |x|², i.e. this
//!   objective). In 1-D it is the pair of states bracketing m. Solved by
//!   the dense simplex method of [`super::lp`] over the k = 4·3^d states
//!   nearest to m, k doubled until m is inside their hull.
//! * **Trace, not the full matrix.** When the diffusion over h exceeds the
//!   minimum, the mixture's covariance trace is τ exactly; its shape is the
//!   Gaussian kernel's (q), not forced to Σ. c = 1, 2, 4, … until the
//!   tilted kernel is wider than τ; if no kernel over the states within
//!   5√(cτ) is (a domain too small for the diffusion), the widest
//!   mean-exact distribution (the same LP maximising the spread) is used.
//! * **The boundary.** States do not reach the box's walls, so m can lie
//!   outside their convex hull; it is then moved along the segment from z
//!   to the farthest point the states can represent (one LP over all
//!   states, maximising t), and the row's mean is that point: the chain
//!   stops at its last row of states where the clamped system stops at the
//!   wall.
//!
//! Compared with the kernel rows, nothing is snapped: a target between
//! states is reached in the mean by splitting the mass, so a coarse chain
//! is blurred (more spread than the SDE's) rather than sharpened.

use super::lp::{self, LpOutcome};
use super::rows::tilt_to_mean_tol;
use beliefbus_core::chain::Chain;
use beliefbus_core::math::linalg;
use beliefbus_core::model::SdeModel;
use beliefbus_core::MAX_STATE;

/// How a row's spread was set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spread {
    /// Covariance trace exactly τ = tr(FFᵀ h).
    Matched,
    /// τ below the least achievable spread: the minimum-variance row.
    Minimum,
    /// τ above anything the states can represent: the widest row.
    Widest,
}

/// One row's outcome.
#[derive(Clone, Debug, PartialEq)]
pub struct RowInfo {
    /// The row's mean (m, or the point on the hull it was moved to).
    pub mean: Vec<f64>,
    /// m was outside the states' hull and moved towards z.
    pub shrunk: bool,
    pub spread: Spread,
    /// V_min and the row's Σ p_k |z_k − mean|².
    pub min_trace: f64,
    pub trace: f64,
}

/// Every state's row under one control.
pub struct MomentRows {
    pub rows: Vec<Vec<(u32, f64)>>,
    /// Rows per [`Spread`]: matched, minimum, widest; and rows moved onto
    /// the hull.
    pub matched: usize,
    pub minimum: usize,
    pub widest: usize,
    pub shrunk: usize,
}

/// The rows of control `u` over period `h` on `chain` (module doc).
pub fn moment_rows<M: SdeModel>(chain: &Chain, model: &M, u: &[f64], h: f64) -> MomentRows {
    let d = chain.dim();
    let n = chain.len();
    let pts = chain.states();
    let (lo, hi) = (model.bounds().lo(), model.bounds().hi());
    let mut f = [0.0; MAX_STATE];
    let mut m = vec![0.0; d];
    let mut cov = vec![0.0; d * d];
    let mut out = MomentRows {
        rows: Vec::with_capacity(n),
        matched: 0,
        minimum: 0,
        widest: 0,
        shrunk: 0,
    };
    let k0 = 4 * 3usize.pow(d as u32);
    for i in 0..n {
        let z = chain.state(i);
        model.drift(z, u, &mut f[..d]);
        for c in 0..d {
            m[c] = (z[c] + f[c] * h).clamp(lo[c], hi[c]);
        }
        for (s, &v) in cov.iter_mut().zip(chain.diffusion_at(i)) {
            *s = v * h;
        }
        let mut row = Vec::new();
        let info = moment_row(pts, d, i, &m, &cov, k0, &mut row);
        match info.spread {
            Spread::Matched => out.matched += 1,
            Spread::Minimum => out.minimum += 1,
            Spread::Widest => out.widest += 1,
        }
        out.shrunk += usize::from(info.shrunk);
        out.rows.push(row);
    }
    out
}

/// The row from state `from` of the flat point set `pts` (n × d) with target
/// mean `m` and target covariance `cov` (d × d), the LP over the `k0`
/// states nearest to m first (module doc). Writes (state, probability)
/// pairs sorted by state.
pub fn moment_row(
    pts: &[f64],
    d: usize,
    from: usize,
    m: &[f64],
    cov: &[f64],
    k0: usize,
    row: &mut Vec<(u32, f64)>,
) -> RowInfo {
    let n = pts.len() / d;
    let z = &pts[from * d..(from + 1) * d];
    let dist2 =
        |j: usize, c: &[f64]| -> f64 { (0..d).map(|a| (pts[j * d + a] - c[a]).powi(2)).sum() };
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| dist2(a, m).total_cmp(&dist2(b, m)));
    let mut mean = m.to_vec();
    let mut shrunk = false;
    let mut k = k0.clamp(d + 1, n);
    let (cand, p_min) = loop {
        let cand: Vec<usize> = order[..k].to_vec();
        if let Some(p) = spread_lp(pts, d, &cand, &mean, false) {
            break (cand, p);
        }
        if k < n {
            k = (2 * k).min(n);
            continue;
        }
        // m is outside the hull of all states: move it towards z.
        let (t, p_reach) = reach(pts, d, z, m);
        for c in 0..d {
            mean[c] = z[c] + t * (m[c] - z[c]);
        }
        shrunk = true;
        let all: Vec<usize> = (0..n).collect();
        let p = spread_lp(pts, d, &all, &mean, false).unwrap_or(p_reach);
        break (all, p);
    };
    let second = |p: &[f64], set: &[usize]| -> f64 {
        set.iter()
            .zip(p)
            .map(|(&j, &w)| w * dist2(j, &mean))
            .sum::<f64>()
    };
    let v_min = second(&p_min, &cand);
    let tau: f64 = (0..d).map(|a| cov[a * d + a]).sum();
    let mut info = RowInfo {
        mean: mean.clone(),
        shrunk,
        spread: Spread::Minimum,
        min_trace: v_min,
        trace: v_min,
    };
    let mut set = cand.clone();
    let mut p = p_min.clone();
    if tau > v_min * (1.0 + 1e-12) && !shrunk {
        let (wide_set, q, spread) = wider(pts, d, &mean, cov, tau, &cand);
        let v_q = second(&q, &wide_set);
        // Merge p_min (on `cand`) and q (on `wide_set`) on their union.
        let w = if v_q > tau {
            (tau - v_min) / (v_q - v_min)
        } else {
            1.0
        };
        let mut acc: Vec<(usize, f64)> = cand
            .iter()
            .zip(&p_min)
            .map(|(&j, &v)| (j, (1.0 - w) * v))
            .collect();
        acc.extend(wide_set.iter().zip(&q).map(|(&j, &v)| (j, w * v)));
        acc.sort_by_key(|e| e.0);
        acc.dedup_by(|b, a| {
            if a.0 == b.0 {
                a.1 += b.1;
                true
            } else {
                false
            }
        });
        set = acc.iter().map(|e| e.0).collect();
        p = acc.iter().map(|e| e.1).collect();
        info.spread = spread;
        info.trace = second(&p, &set);
    }
    row.clear();
    row.extend(
        set.iter()
            .zip(&p)
            .filter(|e| *e.1 > 1e-15)
            .map(|(&j, &v)| (j as u32, v)),
    );
    let total: f64 = row.iter().map(|e| e.1).sum();
    row.iter_mut().for_each(|e| e.1 /= total);
    row.sort_by_key(|e| e.0);
    info
}

/// The mean-exact distribution over `set` minimising (or, `widest`,
/// maximising) Σ_k p_k |z_k − m|²; `None` if m is outside their hull.
pub fn spread_lp(
    pts: &[f64],
    d: usize,
    set: &[usize],
    m: &[f64],
    widest: bool,
) -> Option<Vec<f64>> {
    let k = set.len();
    let mut dz = vec![0.0; k * d];
    let mut scale = 0.0f64;
    for (r, &j) in set.iter().enumerate() {
        for c in 0..d {
            dz[r * d + c] = pts[j * d + c] - m[c];
            scale = scale.max(dz[r * d + c].abs());
        }
    }
    if scale == 0.0 {
        // m is the only point.
        return Some(vec![1.0 / k as f64; k]);
    }
    let rows = d + 1;
    let mut a = vec![0.0; rows * k];
    let mut cost = vec![0.0; k];
    for r in 0..k {
        for c in 0..d {
            a[c * k + r] = dz[r * d + c] / scale;
        }
        a[d * k + r] = 1.0;
        let q: f64 = (0..d).map(|c| (dz[r * d + c] / scale).powi(2)).sum();
        cost[r] = if widest { -q } else { q };
    }
    let mut b = vec![0.0; rows];
    b[d] = 1.0;
    match lp::solve(rows, k, &a, &b, &cost) {
        LpOutcome::Optimal(p) => Some(p),
        _ => None,
    }
}

/// max t ≤ 1 with z + t(m − z) in the hull of all points, and the
/// distribution representing that point (one LP over every point).
fn reach(pts: &[f64], d: usize, z: &[f64], m: &[f64]) -> (f64, Vec<f64>) {
    let n = pts.len() / d;
    let scale = (0..n * d)
        .map(|i| (pts[i] - z[i % d]).abs())
        .fold(f64::MIN_POSITIVE, f64::max);
    // Columns: p_1..p_n, t, slack of t ≤ 1.
    let (rows, cols) = (d + 2, n + 2);
    let mut a = vec![0.0; rows * cols];
    for j in 0..n {
        for c in 0..d {
            a[c * cols + j] = (pts[j * d + c] - z[c]) / scale;
        }
        a[d * cols + j] = 1.0;
    }
    for c in 0..d {
        a[c * cols + n] = -(m[c] - z[c]) / scale;
    }
    a[(d + 1) * cols + n] = 1.0;
    a[(d + 1) * cols + n + 1] = 1.0;
    let mut b = vec![0.0; rows];
    b[d] = 1.0;
    b[d + 1] = 1.0;
    let mut cost = vec![0.0; cols];
    cost[n] = -1.0;
    match lp::solve(rows, cols, &a, &b, &cost) {
        LpOutcome::Optimal(x) => (x[n].clamp(0.0, 1.0), x[..n].to_vec()),
        // z itself is a point, so t = 0 is always feasible; guard anyway.
        _ => {
            let from = (0..n)
                .find(|&j| (0..d).all(|c| pts[j * d + c] == z[c]))
                .unwrap_or(0);
            let mut p = vec![0.0; n];
            p[from] = 1.0;
            (0.0, p)
        }
    }
}

/// A mean-exact distribution around m wider than τ (module doc): the
/// tilted Gaussian kernel with covariance c Σ, c = 1, 2, 4, …, over `cand`
/// and the states within 5√(cτ) of m; else the widest LP row.
fn wider(
    pts: &[f64],
    d: usize,
    m: &[f64],
    cov: &[f64],
    tau: f64,
    cand: &[usize],
) -> (Vec<usize>, Vec<f64>, Spread) {
    let n = pts.len() / d;
    // Σ is symmetric, so its layout does not matter to the factorisation.
    let mut chol = cov.to_vec();
    if !linalg::cholesky(&mut chol, d) {
        chol.fill(0.0);
        for a in 0..d {
            chol[a * d + a] = (tau / d as f64).sqrt();
        }
    }
    let dz_of = |j: usize| -> Vec<f64> { (0..d).map(|c| pts[j * d + c] - m[c]).collect() };
    let mut last: Vec<usize> = cand.to_vec();
    for c in [1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0] {
        let r2 = 25.0 * c * tau;
        let mut set: Vec<usize> = (0..n)
            .filter(|&j| dz_of(j).iter().map(|v| v * v).sum::<f64>() <= r2)
            .collect();
        let extra: Vec<usize> = cand.iter().copied().filter(|j| !set.contains(j)).collect();
        set.extend(extra);
        let dz: Vec<f64> = set.iter().flat_map(|&j| dz_of(j)).collect();
        let mut q: Vec<f64> = dz
            .chunks(d)
            .map(|v| (-0.5 * mahalanobis(d, &chol, v) / c).exp())
            .collect();
        let tot: f64 = q.iter().sum();
        q.iter_mut().for_each(|v| *v /= tot);
        if tilt_to_mean_tol(d, &dz, &vec![0.0; d], &mut q, 1e-13)
            || tilt_to_mean_tol(d, &dz, &vec![0.0; d], &mut q, 1e-10)
        {
            let v_q: f64 = dz
                .chunks(d)
                .zip(&q)
                .map(|(v, w)| w * v.iter().map(|x| x * x).sum::<f64>())
                .sum();
            if v_q > tau {
                return (set, q, Spread::Matched);
            }
        }
        last = set;
    }
    let p = spread_lp(pts, d, &last, m, true).unwrap_or_else(|| {
        let mut p = vec![0.0; last.len()];
        p[0] = 1.0;
        p
    });
    let v: f64 = last
        .iter()
        .zip(&p)
        .map(|(&j, w)| w * dz_of(j).iter().map(|x| x * x).sum::<f64>())
        .sum();
    let spread = if v > tau {
        Spread::Matched
    } else {
        Spread::Widest
    };
    (last, p, spread)
}

/// vᵀ (L Lᵀ)⁻¹ v = |L⁻¹ v|² by forward substitution (L from
/// [`linalg::cholesky`]).
fn mahalanobis(d: usize, l: &[f64], v: &[f64]) -> f64 {
    let mut y = [0.0; MAX_STATE];
    y[..d].copy_from_slice(v);
    linalg::forward_sub(l, d, &mut y[..d]);
    y[..d].iter().map(|x| x * x).sum()
}

#[cfg(test)]
#[path = "rows_moment_tests.rs"]
mod tests;
