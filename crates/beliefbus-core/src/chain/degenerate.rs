//! Diffusions whose F Fᵀ is singular on some coordinates (positions and
//! attitudes driven only by velocities): which coordinates are noise-free,
//! and what a chain can promise there (`docs/degenerate-chains.md`).
//!
//! Split z = (x, v), x the coordinates whose row and column of F Fᵀ are
//! zero. Local consistency (thesis eq. 2.6–2.7) asks, with m = fΔt,
//! ```text
//! E[Δz] = m,   E[Δv Δvᵀ] = (F Fᵀ)_vv Δt + m_v m_vᵀ,   E[Δx Δvᵀ] = m_x m_vᵀ,
//! E[Δx Δxᵀ] − m_x m_xᵀ = o(Δt)
//! ```
//! The last cannot hold exactly on scattered states: with Σ p = 1 its left
//! side is the covariance of Δx under the row, positive unless every state
//! reached shares one x-displacement. It is the row's *numerical
//! diffusion* D_x Δt on the noise-free block, reported by
//! [`super::diagnostics::row_report`]. The moment-matching kernel's
//! least-violating fit over every second moment (the noise-free block
//! with its target m mᵀ) trades a shortfall in the velocity variance
//! against D_x; both shrink as n grows, and faster in the anisotropic
//! metric of [`super::metric`], which shrinks the x-spacing of the
//! neighbours relative to their v-spacing. A kernel that met the first
//! three conditions exactly and only minimised D_x (neighbours offered in
//! order of ‖Δx‖) was measured worse: its D_x stays at 2–4 ‖F Fᵀ‖ at
//! every n in the isotropic metric, and its filter gap to Kalman was 1.5–10×
//! the least-violating fit's on the double integrator (see the docs page).

/// Bit mask of the noise-free coordinates of F Fᵀ (d × d column-major):
/// those whose diagonal entry is zero relative to the largest. `None` when
/// there are none (full rank, or a rotated degeneracy without zero
/// diagonal entries) or when F Fᵀ is zero.
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

#[cfg(test)]
#[path = "degenerate_tests.rs"]
mod tests;

#[cfg(test)]
#[path = "quadrotor_tests.rs"]
mod quadrotor;

#[cfg(test)]
#[path = "rigid_body_tests.rs"]
mod rigid_body;
