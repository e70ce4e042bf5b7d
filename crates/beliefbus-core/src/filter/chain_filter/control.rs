//! The control's exponential tilt of the kernel built for u₀ (see the
//! module doc of [`super`]): p_u(z'|z) ∝ p(z'|z) exp(θ(z)ᵀ(z' − z)),
//! θ = (FFᵀ)⁻¹ (f(z,u) − f(z,u₀)).

use super::ChainFilter;
use crate::chain::linalg::{backward_sub_t, forward_sub};
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
        for i in 0..view.len() {
            let s = view.row_offsets[i] as usize;
            let e = view.row_offsets[i + 1] as usize;
            let z = view.state(i);
            let chol = self.chain.chol_at(i);
            let Some(l) = chol else {
                self.tilt_probs[s..e].copy_from_slice(&view.probs[s..e]);
                continue;
            };
            self.model.drift(z, u, &mut fu[..d]);
            let f0 = self.chain.drift_at(i);
            for a in 0..d {
                theta[a] = fu[a] - f0[a];
            }
            forward_sub(l, d, &mut theta[..d]);
            backward_sub_t(l, d, &mut theta[..d]);
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
            if sum > 0.0 {
                for w in &mut self.tilt_probs[s..e] {
                    *w /= sum;
                }
            } else {
                self.tilt_probs[s..e].copy_from_slice(&view.probs[s..e]);
            }
        }
        self.kern
            .set_jump_probs(view.holding, view.row_offsets, &self.tilt_probs);
    }
}
