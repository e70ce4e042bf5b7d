//! One control's transition rows on a chain (thesis Alg. 4.3,
//! `ComputeHoldingTime` and `ComputeTransProb` per sampled control):
//!
//! ```text
//! Δt(z, u) = r(z)² / (κ_F ‖FFᵀ(z)‖₂ + κ_f r(z) ‖f(z, u)‖₂)
//! p_u(z_k | z) ∝ exp(−½ (z_k − z − f(z,u)Δt)ᵀ (FFᵀ Δt)⁻¹ (z_k − z − f(z,u)Δt)),  z_k ∈ Near(z)
//! ```
//!
//! with the chain's r(z), Near(z) (its row's columns), FFᵀ(z) and κ's, so
//! that u = u₀ reproduces the chain's own rows. The one-step equalised row
//! over δ and its K-th power are in [`ControlKernel::step_rows`].

use beliefbus_core::chain::kernel::{gaussian, holding_time, KernelWork, LocalDyn};
use beliefbus_core::chain::Chain;
use beliefbus_core::math::linalg::sym_spectral_norm;
use beliefbus_core::model::SdeModel;
use beliefbus_core::MAX_STATE;

/// Holding times and jump probabilities of every state under one control.
pub struct ControlKernel {
    /// Δt(z, u) (∞ for an absorbing state).
    pub holding: Vec<f64>,
    /// Jump probabilities over the chain row's columns, CSR like the chain.
    pub offsets: Vec<usize>,
    pub probs: Vec<f64>,
}

impl ControlKernel {
    /// The kernel of control `u` on `chain` (built with the Gaussian kernel).
    pub fn new<M: SdeModel>(chain: &Chain, model: &M, u: &[f64]) -> Self {
        let d = chain.dim();
        let cfg = chain.config();
        let n = chain.len();
        let mut holding = Vec::with_capacity(n);
        let mut offsets = Vec::with_capacity(n + 1);
        let mut probs = Vec::with_capacity(chain.nnz());
        offsets.push(0);
        let mut work = KernelWork::new();
        let mut f = [0.0; MAX_STATE];
        let mut dz = Vec::new();
        let mut p = Vec::new();
        for i in 0..n {
            let z = chain.state(i);
            let (cols, _) = chain.row(i);
            model.drift(z, u, &mut f[..d]);
            let ff = chain.diffusion_at(i);
            let fnorm = f[..d].iter().map(|v| v * v).sum::<f64>().sqrt();
            let dnorm = sym_spectral_norm(ff, d);
            let r = chain.radius()[i];
            let chol = chain.chol_at(i);
            if cols.is_empty() || !(r > 0.0) || chol.is_none() || (fnorm == 0.0 && dnorm == 0.0) {
                holding.push(f64::INFINITY);
                offsets.push(probs.len());
                continue;
            }
            let dt = holding_time(r, dnorm, fnorm, cfg.kappa_diffusion, cfg.kappa_drift);
            dz.clear();
            for &j in cols {
                let zj = chain.state(j as usize);
                dz.extend((0..d).map(|c| zj[c] - z[c]));
            }
            p.clear();
            p.resize(cols.len(), 0.0);
            let dynl = LocalDyn {
                f: &f[..d],
                ff,
                chol,
            };
            gaussian(d, &dz, dt, &dynl, &mut work, &mut p);
            holding.push(dt);
            probs.extend_from_slice(&p);
            offsets.push(probs.len());
        }
        ControlKernel {
            holding,
            offsets,
            probs,
        }
    }

    /// min_z Δt(z, u).
    pub fn min_holding(&self) -> f64 {
        self.holding.iter().copied().fold(f64::INFINITY, f64::min)
    }

    /// The equalised one-step row of state `i` over δ (eq. 3.8–3.9):
    /// stay 1 − δ/Δt, jump δ/Δt · p_u; accumulated into `acc` with weight
    /// `w`, new columns pushed to `touched`.
    fn push_step(
        &self,
        chain: &Chain,
        i: usize,
        delta: f64,
        w: f64,
        acc: &mut [f64],
        touched: &mut Vec<u32>,
    ) {
        let mut add = |j: u32, v: f64, acc: &mut [f64]| {
            if acc[j as usize] == 0.0 {
                touched.push(j);
            }
            acc[j as usize] += v;
        };
        let dt = self.holding[i];
        let jump = if dt.is_finite() { delta / dt } else { 0.0 };
        add(i as u32, w * (1.0 - jump), acc);
        if jump > 0.0 {
            let (cols, _) = chain.row(i);
            let ps = &self.probs[self.offsets[i]..self.offsets[i + 1]];
            for (&j, &pj) in cols.iter().zip(ps) {
                add(j, w * jump * pj, acc);
            }
        }
    }

    /// Every state's row of (P^δ_u)^K, entries below `flush` dropped and
    /// the row renormalised.
    pub fn step_rows(
        &self,
        chain: &Chain,
        delta: f64,
        steps: usize,
        flush: f64,
    ) -> Vec<Vec<(u32, f64)>> {
        let n = chain.len();
        let mut acc = vec![0.0; n];
        let mut touched: Vec<u32> = Vec::new();
        let mut cur: Vec<(u32, f64)> = Vec::new();
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            cur.clear();
            cur.push((i as u32, 1.0));
            for _ in 0..steps {
                for &(j, w) in &cur {
                    self.push_step(chain, j as usize, delta, w, &mut acc, &mut touched);
                }
                cur.clear();
                let mut total = 0.0;
                for &j in &touched {
                    let v = std::mem::take(&mut acc[j as usize]);
                    if v >= flush && v > 0.0 {
                        cur.push((j, v));
                        total += v;
                    }
                }
                touched.clear();
                cur.iter_mut().for_each(|e| e.1 /= total);
            }
            out.push(cur.clone());
        }
        out
    }
}
