//! State placement: where a chain's states go (thesis §3.3.3, "concentrate
//! the samples around the estimated posterior").
//!
//! The thesis propagates the prior's mean and variance for a time δ and
//! concentrates samples around the result. Here the propagation is by
//! simulation of the SDE itself, so it follows nonlinear flows (a limit
//! cycle, a strange attractor) that a propagated Gaussian cannot:
//!
//! - [`predictive_points`]: i.i.d. draws from a mixture of the uniform law
//!   on S, the prior, and the *arc-length* law along simulated trajectories
//!   of the prior predictive over a horizon;
//! - [`eliminate`]: weighted sample elimination (C. Yuksel, "Sample
//!   elimination for generating Poisson disk sample sets", Computer
//!   Graphics Forum 34(2), Eurographics 2015) with a local radius: keeps
//!   `n` of `m` candidates at the candidates' density, without the clumps
//!   and holes of an i.i.d. draw;
//! - [`predictive_even`]: both, `oversample` × n candidates thinned to n.
//!
//! Why evenly spread states: a transition can only land on existing
//! states, so a hole near the advected point z + f τ forces the
//! moment-matched kernel onto farther neighbours and adds numerical
//! diffusion; an even set gives a smaller error at the same support, which
//! is what a filter step costs.

use super::index::SpatialIndex;
use super::sample::Sampler;
use super::ChainError;
use crate::belief::Gaussian;
use crate::model::discrete::em_integrate;
use crate::model::SdeModel;
use crate::rng::SimRng;
use rand::RngExt;

/// Fraction of [`predictive_points`] drawn from the prior itself.
pub const PRIOR_FRACTION: f64 = 0.05;

/// Draw x ~ N(prior) restricted to S (rejection, then uniform on S after
/// 64 failed tries; see [`Sampler::sample`]) into `x`.
pub fn draw_prior<M: SdeModel + ?Sized>(
    model: &M,
    sampler: &Sampler,
    rng: &mut SimRng,
    x: &mut [f64],
) {
    sampler.sample(model.bounds(), rng, x);
}

/// The sampler of the prior restricted to S (no uniform share).
pub fn prior_sampler(prior: &Gaussian) -> Result<Sampler, ChainError> {
    Sampler::around(prior, 1.0, 0.0).ok_or(ChainError::Config(
        "prior covariance is not positive definite",
    ))
}

/// States concentrated where the prior predictive puts mass (thesis
/// §3.3.3): `n` points (flat n × d), each with probability
/// `uniform_fraction` uniform on S, with probability [`PRIOR_FRACTION`]
/// drawn from the prior, otherwise uniform in *arc length* along
/// trajectories of the SDE started from the prior and run to `horizon`
/// (⌈horizon/max_dt⌉ Euler–Maruyama steps, linear interpolation between
/// them; clamp(n/50, 20, 400) trajectories). Arc length rather than time: a
/// chain needs states where the state moves fast as much as where it
/// lingers (a transition can only reach existing states), and time-uniform
/// points starve the fast parts of a limit cycle. Data-free, so a chain
/// built on them serves every run started from `prior`.
pub fn predictive_points<M: SdeModel + ?Sized>(
    model: &M,
    prior: &Gaussian,
    horizon: f64,
    n: usize,
    uniform_fraction: f64,
    max_dt: f64,
    rng: &mut SimRng,
) -> Result<Vec<f64>, ChainError> {
    let sampler = prior_sampler(prior)?;
    if !(horizon.is_finite() && horizon >= 0.0 && max_dt.is_finite() && max_dt > 0.0) {
        return Err(ChainError::Config(
            "placement horizon must be ≥ 0 and max_dt > 0",
        ));
    }
    let d = prior.dim;
    let u = vec![0.0; model.dims().control];
    let trajs = (n / 50).clamp(20, 400);
    let steps = ((horizon / max_dt).ceil() as usize).max(1);
    let h = horizon / steps as f64;
    // path points and cumulative arc length, trajectory after trajectory
    let mut path = Vec::with_capacity(trajs * (steps + 1) * d);
    let mut cum = Vec::with_capacity(trajs * (steps + 1));
    let mut s = 0.0;
    let mut x = vec![0.0; d];
    let mut prev = vec![0.0; d];
    for _ in 0..trajs {
        draw_prior(model, &sampler, rng, &mut x);
        path.extend_from_slice(&x);
        cum.push(s); // zero-length link from the previous trajectory's end
        for _ in 0..steps {
            prev.copy_from_slice(&x);
            em_integrate(model, &mut x, &u, h, max_dt, rng);
            model.bounds().project(&mut x);
            s += prev
                .iter()
                .zip(&x)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt();
            path.extend_from_slice(&x);
            cum.push(s);
        }
    }
    let mut out = Vec::with_capacity(n * d);
    while out.len() < n * d {
        let a = rng.random::<f64>();
        if a < uniform_fraction {
            model.bounds().sample_uniform(rng, &mut x);
        } else if a < uniform_fraction + PRIOR_FRACTION || !(s > 0.0) {
            draw_prior(model, &sampler, rng, &mut x);
        } else {
            let t = rng.random::<f64>() * s;
            // first index with cum > t (≥ 1 since cum[0] = 0 ≤ t)
            let j = cum.partition_point(|&c| c <= t).clamp(1, cum.len() - 1);
            let len = cum[j] - cum[j - 1];
            let w = if len > 0.0 {
                (t - cum[j - 1]) / len
            } else {
                0.0
            };
            for c in 0..d {
                x[c] = (1.0 - w) * path[(j - 1) * d + c] + w * path[j * d + c];
            }
        }
        out.extend_from_slice(&x);
    }
    Ok(out)
}

/// Weighted sample elimination (Yuksel 2015, see the module doc) with a
/// local radius, so that the candidates' density is kept: `n` of the points
/// in `cand` (flat m × d), spread more evenly than an i.i.d. draw of the
/// same density (no clumps, no holes). Each candidate i gets the radius R_i
/// of its k-th nearest candidate, k = ⌈3.5 m/n⌉ (≈ the neighbourhood that
/// will keep ~3 points), and the weight
///
/// ```text
/// W_i = Σ_{j ∈ kNN(i)} (1 − ‖z_i − z_j‖/R_i)⁸
/// ```
///
/// the candidate of largest weight is removed and its neighbours' weights
/// lowered, until n remain. Scale-free in R_i, so every region is thinned
/// by about the same factor m/n. Deterministic (no random draws). Returns
/// `cand` unchanged when n ≥ m.
pub fn eliminate(cand: &[f64], d: usize, n: usize) -> Vec<f64> {
    use std::collections::BinaryHeap;
    if d == 0 {
        return cand.to_vec();
    }
    let m = cand.len() / d;
    if n >= m {
        return cand.to_vec();
    }
    let Some(index) = SpatialIndex::from_points(d, cand) else {
        return cand[..n * d].to_vec();
    };
    let k = ((3.5 * m as f64 / n as f64).ceil() as usize).clamp(2, m - 1);
    let mut weight = vec![0.0f64; m];
    // rev[j]: (i, w_ij) for every i that has j among its neighbours
    let mut rev: Vec<Vec<(u32, f64)>> = vec![Vec::new(); m];
    let mut near = Vec::with_capacity(k + 1);
    for i in 0..m {
        index.nearest(&cand[i * d..(i + 1) * d], k + 1, &mut near);
        let r = near.last().map_or(0.0, |&(_, d2)| d2.sqrt());
        if r <= 0.0 {
            continue;
        }
        for &(j, d2) in &near {
            if j as usize == i {
                continue;
            }
            let w = (1.0 - d2.sqrt() / r).max(0.0).powi(8);
            weight[i] += w;
            rev[j as usize].push((i as u32, w));
        }
    }
    // max-heap on the weight's bits (weights ≥ 0 order like their bits);
    // stale entries are skipped on pop
    let mut heap: BinaryHeap<(u64, u32)> =
        (0..m).map(|i| (weight[i].to_bits(), i as u32)).collect();
    let mut removed = vec![false; m];
    let mut left = m;
    while left > n {
        let Some((bits, i)) = heap.pop() else { break };
        let i = i as usize;
        if removed[i] || bits != weight[i].to_bits() {
            continue;
        }
        removed[i] = true;
        left -= 1;
        for &(j, w) in &rev[i] {
            let j = j as usize;
            if !removed[j] {
                weight[j] = (weight[j] - w).max(0.0);
                heap.push((weight[j].to_bits(), j as u32));
            }
        }
    }
    (0..m)
        .filter(|&i| !removed[i])
        .flat_map(|i| cand[i * d..(i + 1) * d].iter().copied())
        .collect()
}

/// [`predictive_points`] with `oversample` × n candidates thinned to `n`
/// by [`eliminate`]: the prior predictive's density, evenly spread.
#[allow(clippy::too_many_arguments)]
pub fn predictive_even<M: SdeModel + ?Sized>(
    model: &M,
    prior: &Gaussian,
    horizon: f64,
    n: usize,
    oversample: usize,
    uniform_fraction: f64,
    max_dt: f64,
    rng: &mut SimRng,
) -> Result<Vec<f64>, ChainError> {
    let cand = predictive_points(
        model,
        prior,
        horizon,
        n * oversample.max(1),
        uniform_fraction,
        max_dt,
        rng,
    )?;
    Ok(eliminate(&cand, prior.dim, n))
}

#[cfg(test)]
#[path = "placement_tests.rs"]
mod tests;
