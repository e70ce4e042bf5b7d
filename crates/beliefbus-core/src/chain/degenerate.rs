//! Moment matching when F Fᵀ is singular with noise-free coordinates
//! (positions and attitudes driven only by velocities): the kernel of
//! `docs/src/degenerate-chains.md`.
//!
//! Split z = (x, v), x the coordinates whose row and column of F Fᵀ are
//! zero, v the rest. Local consistency (thesis eq. 2.6–2.7) asks, with m the
//! required mean displacement (fΔt, or the flow's over τ):
//! ```text
//! E[Δz] = m,   E[Δv Δvᵀ] = (F Fᵀ)_vv Δt + m_v m_vᵀ,   E[Δx Δvᵀ] = m_x m_vᵀ,
//! E[Δx Δxᵀ] − m_x m_xᵀ = o(Δt)
//! ```
//! The first three are linear equalities in the row (p₀, p_k) and are met
//! exactly (to [`FEAS_TOL`] on scaled rows) whenever the neighbours permit.
//! The last cannot be met exactly by a chain on scattered states: with
//! Σ p = 1, E[Δx Δxᵀ] − m_x m_xᵀ is the covariance of Δx under the row,
//! positive unless every state reached shares one x-displacement. It is the
//! *numerical diffusion* D_x Δt of the noise-free block, and the kernel
//! keeps it small by solving the equalities over the neighbours with the
//! smallest noise-free displacement ‖Δx_k‖ first (a subset doubled until
//! feasible), so D_x ≈ ‖Δx_k‖²/‖Δv_k‖² · tr(F Fᵀ) over the chosen
//! neighbours. It vanishes only if the neighbours' x-spacing shrinks faster
//! than their v-spacing, which an anisotropic metric provides
//! ([`super::frame`]'s scaled coordinates, [`ScaledCoords`]). The chain
//! diagnostics report D_x per state ([`super::diagnostics`]).

use super::kernel::{KernelOutcome, KernelWork, MomentFit, FEAS_TOL, SUM_ROW_WEIGHT};
use super::nnls::{MAX_COLS, MAX_ROWS};

/// Bit mask of the noise-free coordinates of F Fᵀ (d × d column-major):
/// those whose diagonal entry is zero relative to the largest. `None` when
/// there are none, when every coordinate is noise-free, or when F Fᵀ is
/// singular without a zero diagonal (a rotated degeneracy this kernel does
/// not treat).
pub fn noise_free_mask(d: usize, ff: &[f64]) -> Option<u32> {
    let dmax = (0..d).map(|i| ff[i + i * d]).fold(0.0f64, f64::max);
    if !(dmax > 0.0) {
        return None;
    }
    let mut mask = 0u32;
    for i in 0..d {
        if ff[i + i * d] <= 1e-12 * dmax {
            mask |= 1 << i;
        }
    }
    (mask != 0).then_some(mask)
}

/// Whether coordinate `i` is in `mask`.
#[inline]
pub fn is_free(mask: u32, i: usize) -> bool {
    mask & (1 << i) != 0
}

/// Number of equality rows: Σp = 1, d means, the second moments of every
/// pair (i ≤ c) with at least one noisy coordinate.
pub fn equality_rows(d: usize, mask: u32) -> usize {
    let mut m = 1 + d;
    for i in 0..d {
        for c in i..d {
            if !(is_free(mask, i) && is_free(mask, c)) {
                m += 1;
            }
        }
    }
    m
}

/// The degenerate moment-matching kernel (module doc) over the K = dz.len()/d
/// neighbours at displacements `dz`: writes the jump probabilities into
/// `p` (length K, zero for neighbours not used) and returns the outcome and
/// the holding time of the chain without self-loop. `r` scales the rows;
/// `mean_weight` weights the mean rows of the least-violation fit.
#[allow(clippy::too_many_arguments)]
pub fn moment_matched_degenerate(
    d: usize,
    dz: &[f64],
    mean: &[f64],
    dt: f64,
    r: f64,
    mean_weight: f64,
    ff: &[f64],
    free: u32,
    work: &mut KernelWork,
    p: &mut [f64],
) -> MomentFit {
    let k = dz.len() / d;
    let m = equality_rows(d, free);
    debug_assert!(m <= MAX_ROWS && k < MAX_COLS);
    // Neighbours by noise-free displacement, nearest first.
    work.order.clear();
    for j in 0..k {
        let s: f64 = (0..d)
            .filter(|&i| is_free(free, i))
            .map(|i| dz[j * d + i] * dz[j * d + i])
            .sum();
        work.order.push((s, j as u32));
    }
    work.order
        .sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let inv_r = 1.0 / r;
    let inv_r2 = inv_r * inv_r;
    let mut b = [0.0f64; MAX_ROWS];
    b[0] = SUM_ROW_WEIGHT;
    for i in 0..d {
        b[1 + i] = mean[i] * inv_r;
    }
    let mut row = 1 + d;
    for i in 0..d {
        for c in i..d {
            if !(is_free(free, i) && is_free(free, c)) {
                b[row] = (ff[i + c * d] * dt + mean[i] * mean[c]) * inv_r2;
                row += 1;
            }
        }
    }
    let mut kk = k.min((2 * m).max(16));
    let mut outcome = KernelOutcome::LeastSquares;
    loop {
        let last = kk == k;
        let w = if last { mean_weight } else { 1.0 };
        let cols = fill_matrix(d, dz, kk, free, inv_r, inv_r2, w, m, work);
        for (t, bt) in work.b[..m].iter_mut().zip(&b[..m]) {
            *t = *bt;
        }
        for v in &mut work.b[1..1 + d] {
            *v *= w;
        }
        let res = work.nnls.solve(
            &work.a[..m * cols],
            m,
            cols,
            &work.b[..m],
            &mut work.x[..cols],
        );
        if res <= FEAS_TOL {
            outcome = KernelOutcome::Exact;
            break;
        }
        if last {
            break;
        }
        kk = (2 * kk).min(k);
    }
    let x = &work.x[..kk + 1];
    let total: f64 = x.iter().sum();
    let jump: f64 = x[1..].iter().sum();
    p[..k].fill(0.0);
    if !(jump > 1e-12 * total) || !total.is_finite() {
        // All mass on the self-loop: no admissible move. The state is
        // absorbing (empty row), counted with the least-squares rows.
        return MomentFit {
            outcome: KernelOutcome::LeastSquares,
            holding: f64::INFINITY,
        };
    }
    for (t, &(_, j)) in work.order[..kk].iter().enumerate() {
        p[j as usize] = x[t + 1] / jump;
    }
    MomentFit {
        outcome,
        holding: dt * total / jump,
    }
}

/// The scaled equality matrix (m × (kk + 1), column 0 the self-loop) over
/// the first `kk` neighbours of `work.order`, the mean rows weighted by
/// `w`; returns the column count.
#[allow(clippy::too_many_arguments)]
fn fill_matrix(
    d: usize,
    dz: &[f64],
    kk: usize,
    free: u32,
    inv_r: f64,
    inv_r2: f64,
    w: f64,
    m: usize,
    work: &mut KernelWork,
) -> usize {
    let cols = kk + 1;
    let a = &mut work.a[..m * cols];
    a.fill(0.0);
    a[0] = SUM_ROW_WEIGHT;
    for t in 0..kk {
        let j = work.order[t].1 as usize;
        let z = &dz[j * d..(j + 1) * d];
        let col = (t + 1) * m;
        a[col] = SUM_ROW_WEIGHT;
        for i in 0..d {
            a[col + 1 + i] = w * z[i] * inv_r;
        }
        let mut row = 1 + d;
        for i in 0..d {
            for c in i..d {
                if !(is_free(free, i) && is_free(free, c)) {
                    a[col + row] = z[i] * z[c] * inv_r2;
                    row += 1;
                }
            }
        }
    }
    cols
}

#[cfg(test)]
#[path = "degenerate_tests.rs"]
mod tests;
