//! The control's exponential tilt of the kernel built for u₀ (see the
//! module doc of [`super`]): p_u(z'|z) ∝ p(z'|z) exp(θ(z)ᵀ(z' − z)),
//! θ = (FFᵀ)⁻¹ (f(z,u) − f(z,u₀)).
//!
//! Where F Fᵀ is singular with noise-free coordinates x (zero rows and
//! columns, [`crate::chain::degenerate`]) and the control moves only the
//! noisy ones v (forces and torques: Δf_x = 0), the tilt uses the noisy
//! block: θ_v = (FFᵀ)_vv⁻¹ Δf_v, θ_x = 0. The row's covariance being
//! (FFᵀ)_vv Δt on v and o(Δt) elsewhere, the mean moves by Δf Δt to first
//! order, as in the full-rank case. Where that is impossible (the control
//! moves a noise-free coordinate, or F Fᵀ is singular without zero
//! diagonal entries) the row is left untilted and the state is counted
//! ([`ChainFilter::control_unapplied`]) — never skipped silently.

use super::ChainFilter;
use crate::chain::degenerate::{is_free, noise_free_mask};
use crate::chain::linalg::{backward_sub_t, cholesky, forward_sub};
use crate::model::SdeModel;
use crate::MAX_STATE;

impl<M: SdeModel> ChainFilter<M> {
    /// Tilt the kernel for control u (see module doc).
    pub(super) fn apply_control(&mut self, u: &[f64]) {
        let c = self.dims.control;
        if c == 0 || self.u_last[..c] == *u {
            return;
        }
        self.u_last[..c].copy_from_slice(u);
        let view = self
            .chain
            .compact_view()
            .expect("installed chain is compact");
        if u == self.chain.reference_control() {
            self.kern
                .set_jump_probs(view.holding, view.row_offsets, view.probs);
            return;
        }
        let d = self.dims.state;
        let mut fu = [0.0; MAX_STATE];
        let mut theta = [0.0; MAX_STATE];
        let mut unapplied = 0u64;
        for i in 0..view.len() {
            let s = view.row_offsets[i] as usize;
            let e = view.row_offsets[i + 1] as usize;
            let z = view.state(i);
            self.model.drift(z, u, &mut fu[..d]);
            let f0 = self.chain.drift_at(i);
            for a in 0..d {
                theta[a] = fu[a] - f0[a];
            }
            let solved = match self.chain.chol_at(i) {
                Some(l) => {
                    forward_sub(l, d, &mut theta[..d]);
                    backward_sub_t(l, d, &mut theta[..d]);
                    true
                }
                None => solve_noisy_block(d, self.chain.diffusion_at(i), &mut theta),
            };
            if !solved {
                if s < e {
                    unapplied += 1;
                }
                self.tilt_probs[s..e].copy_from_slice(&view.probs[s..e]);
                continue;
            }
            let mut amax = f64::NEG_INFINITY;
            for edge in s..e {
                let zc = view.state(view.cols[edge] as usize);
                let a: f64 = (0..d).map(|k| theta[k] * (zc[k] - z[k])).sum();
                self.tilt_probs[edge] = a;
                amax = amax.max(a);
            }
            let mut sum = 0.0;
            for edge in s..e {
                let w = view.probs[edge] * (self.tilt_probs[edge] - amax).exp();
                self.tilt_probs[edge] = w;
                sum += w;
            }
            if sum > 0.0 && sum.is_finite() {
                for w in &mut self.tilt_probs[s..e] {
                    *w /= sum;
                }
            } else {
                unapplied += 1;
                self.tilt_probs[s..e].copy_from_slice(&view.probs[s..e]);
            }
        }
        self.control_unapplied += unapplied;
        self.kern
            .set_jump_probs(view.holding, view.row_offsets, &self.tilt_probs);
    }
}

/// θ ← (FFᵀ)_vv⁻¹ Δf_v on the noisy coordinates v, 0 on the noise-free
/// ones, for `theta` = Δf on entry. False (θ unspecified) when F Fᵀ has no
/// zero-diagonal structure, its noisy block is not positive definite, or
/// Δf moves a noise-free coordinate (beyond rounding).
fn solve_noisy_block(d: usize, ff: &[f64], theta: &mut [f64; MAX_STATE]) -> bool {
    let Some(free) = noise_free_mask(d, ff) else {
        return false;
    };
    let scale = theta[..d].iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mut idx = [0usize; MAX_STATE];
    let mut nv = 0;
    for a in 0..d {
        if is_free(free, a) {
            if theta[a].abs() > 1e-12 * scale.max(f64::MIN_POSITIVE) {
                return false;
            }
        } else {
            idx[nv] = a;
            nv += 1;
        }
    }
    let mut l = [0.0; MAX_STATE * MAX_STATE];
    let mut rhs = [0.0; MAX_STATE];
    for p in 0..nv {
        rhs[p] = theta[idx[p]];
        for q in 0..nv {
            l[p + q * nv] = ff[idx[p] + idx[q] * d];
        }
    }
    if !cholesky(&mut l[..nv * nv], nv) {
        return false;
    }
    forward_sub(&l[..nv * nv], nv, &mut rhs[..nv]);
    backward_sub_t(&l[..nv * nv], nv, &mut rhs[..nv]);
    theta[..d].fill(0.0);
    for p in 0..nv {
        theta[idx[p]] = rhs[p];
    }
    true
}

#[cfg(test)]
#[path = "control_tests.rs"]
mod tests;
