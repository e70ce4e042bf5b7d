//! One control's transition rows on a chain (thesis Alg. 4.3,
//! `ComputeHoldingTime` and `ComputeTransProb` per sampled control):
//!
//! ```text
//! Δt(z, u) = r(z)² / (κ_F ‖FFᵀ(z)‖₂ + κ_f r(z) ‖f(z, u)‖₂)
//! p_u(z_k | z) ∝ exp(−½ (z_k − z − f(z,u)Δt)ᵀ (FFᵀ Δt)⁻¹ (z_k − z − f(z,u)Δt)),  z_k ∈ Near(z)
//! ```
//!
//! with the chain's r(z), Near(z) (its row's columns), FFᵀ(z) and κ's, so
//! that u = u₀ reproduces the chain's own rows (but for the repaired states
//! below). The one-step equalised row
//! over δ and its K-th power are in [`ControlKernel::step_rows`].
//!
//! **Consistent in the mean** (optional, `match_mean`). Local consistency needs E[Δξ] = f Δt (Alg. 4.3's
//! first condition). A k-NN Near set drawn from uniform samples is
//! sometimes all on one side of z (a gap in the samples on the other):
//! when the drift points into the gap, f Δt lies outside the convex hull
//! of the displacements z_k − z and no weights can reproduce it; the
//! Gaussian kernel then jumps *against* the drift, and a cluster of such
//! states traps the chain (seen on a 320-state LQG chain: at z ≈ 0.86 under
//! u = 0 the chain's mean move over 0.125 s was +0.006 where the SDE's is
//! −0.10). For such a state the row gets the nearest state beyond f Δt
//! along the missing direction as an extra column, and the Gaussian
//! weights are exponentially tilted, p_k ∝ w_k e^{λ·Δz_k}, with λ chosen by
//! Newton's method so that Σ p_k Δz_k = f Δt exactly (the tilt closest to
//! the Gaussian weights in relative entropy). States whose hull contains
//! f Δt keep the chain's weights; where no state lies beyond f Δt (the
//! drift points out of the domain) the row is left as it is.

use beliefbus_core::chain::kernel::{gaussian, holding_time, KernelWork, LocalDyn};
use beliefbus_core::chain::Chain;
use beliefbus_core::math::linalg::sym_spectral_norm;
use beliefbus_core::model::SdeModel;
use beliefbus_core::MAX_STATE;

/// Holding times and jump probabilities of every state under one control.
pub struct ControlKernel {
    /// Δt(z, u) (∞ for an absorbing state).
    pub holding: Vec<f64>,
    /// Jump targets and probabilities, CSR: the chain row's columns, plus
    /// one for a one-sided Near set (module doc).
    pub offsets: Vec<usize>,
    pub cols: Vec<u32>,
    pub probs: Vec<f64>,
    /// States whose row was repaired (module doc).
    pub repaired: usize,
}

impl ControlKernel {
    /// The kernel of control `u` on `chain` (built with the Gaussian kernel).
    pub fn new<M: SdeModel>(chain: &Chain, model: &M, u: &[f64]) -> Self {
        Self::with_mean(chain, model, u, false)
    }

    /// [`ControlKernel::new`] (the chain's own Near sets and Gaussian
    /// weights), or with `match_mean` every row made consistent in the
    /// mean (module doc): one-sided Near sets repaired and the weights
    /// tilted so that E[Δξ] = f Δt exactly wherever f Δt is inside the
    /// hull of the displacements. The normalised Gaussian
    /// kernel's mean falls short of f Δt when f Δt is comparable to r and
    /// the Near set is lopsided (a 640-state LQG chain moved a quarter of
    /// the drift at z ≈ −0.43).
    pub fn with_mean<M: SdeModel>(chain: &Chain, model: &M, u: &[f64], match_mean: bool) -> Self {
        let d = chain.dim();
        let cfg = chain.config();
        let n = chain.len();
        let mut holding = Vec::with_capacity(n);
        let mut offsets = Vec::with_capacity(n + 1);
        let mut probs = Vec::with_capacity(chain.nnz());
        let mut out_cols: Vec<u32> = Vec::with_capacity(chain.nnz());
        let mut repaired = 0;
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
            let mut row_cols: Vec<u32> = cols.to_vec();
            let target: Vec<f64> = f[..d].iter().map(|v| v * dt).collect();
            let outside = if match_mean {
                outside_hull(d, &dz, &target)
            } else {
                None
            };
            if outside.is_none() && match_mean && tilt_to_mean(d, &dz, &target, &mut p) {
                repaired += 1;
            }
            if let Some(v) = outside {
                if let Some(j) = nearest_beyond(chain, i, &target, &v) {
                    let zj = chain.state(j);
                    dz.extend((0..d).map(|c| zj[c] - z[c]));
                    row_cols.push(j as u32);
                    p.resize(row_cols.len(), 0.0);
                    gaussian(d, &dz, dt, &dynl, &mut work, &mut p);
                    if tilt_to_mean(d, &dz, &target, &mut p) {
                        repaired += 1;
                    } else {
                        // Keep the chain's own row.
                        row_cols.pop();
                        dz.truncate(dz.len() - d);
                        p.truncate(row_cols.len());
                        gaussian(d, &dz, dt, &dynl, &mut work, &mut p);
                    }
                }
            }
            holding.push(dt);
            probs.extend_from_slice(&p);
            out_cols.extend_from_slice(&row_cols);
            offsets.push(probs.len());
        }
        ControlKernel {
            holding,
            offsets,
            cols: out_cols,
            probs,
            repaired,
        }
    }

    /// min_z Δt(z, u).
    pub fn min_holding(&self) -> f64 {
        self.holding.iter().copied().fold(f64::INFINITY, f64::min)
    }

    /// The equalised one-step row of state `i` over δ (eq. 3.8–3.9):
    /// stay 1 − δ/Δt, jump δ/Δt · p_u; accumulated into `acc` with weight
    /// `w`, new columns pushed to `touched`.
    fn push_step(&self, i: usize, delta: f64, w: f64, acc: &mut [f64], touched: &mut Vec<u32>) {
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
            let cols = &self.cols[self.offsets[i]..self.offsets[i + 1]];
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
                    self.push_step(j as usize, delta, w, &mut acc, &mut touched);
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

/// A unit direction v with max_k Δz_k·v < target·v (so the target lies
/// outside the convex hull of the displacements), tried along the target
/// itself and along ± each axis; `None` when none separates.
fn outside_hull(d: usize, dz: &[f64], target: &[f64]) -> Option<Vec<f64>> {
    let norm = target.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut dirs: Vec<Vec<f64>> = Vec::with_capacity(1 + 2 * d);
    if norm > 0.0 {
        dirs.push(target.iter().map(|v| v / norm).collect());
    }
    for c in 0..d {
        for s in [1.0, -1.0] {
            let mut v = vec![0.0; d];
            v[c] = s;
            dirs.push(v);
        }
    }
    dirs.into_iter().find(|v| {
        let t: f64 = target.iter().zip(v).map(|(a, b)| a * b).sum();
        dz.chunks(d)
            .all(|z| z.iter().zip(v).map(|(a, b)| a * b).sum::<f64>() < t)
    })
}

/// The chain state nearest to state `i` among those beyond `target` along
/// `v` ((z_j − z_i)·v > target·v).
fn nearest_beyond(chain: &Chain, i: usize, target: &[f64], v: &[f64]) -> Option<usize> {
    let z = chain.state(i);
    let t: f64 = target.iter().zip(v).map(|(a, b)| a * b).sum();
    (0..chain.len())
        .filter_map(|j| {
            let zj = chain.state(j);
            let along: f64 = zj.iter().zip(z).zip(v).map(|((a, b), c)| (a - b) * c).sum();
            (along > t).then(|| {
                let d2: f64 = zj.iter().zip(z).map(|(a, b)| (a - b) * (a - b)).sum();
                (j, d2)
            })
        })
        .fold(None, |best: Option<(usize, f64)>, x| match best {
            Some(b) if b.1 <= x.1 => Some(b),
            _ => Some(x),
        })
        .map(|b| b.0)
}

/// Tilts `p` to p_k ∝ p_k e^{λ·Δz_k} with Σ p_k Δz_k = `target`: Newton's
/// method on the convex dual log Σ p_k e^{λ·Δz_k} − λ·target (gradient the
/// mean error, Hessian the tilted covariance), with step halving. Returns
/// false (leaving `p` unchanged) if it does not converge.
fn tilt_to_mean(d: usize, dz: &[f64], target: &[f64], p: &mut [f64]) -> bool {
    tilt_to_mean_tol(d, dz, target, p, 1e-9)
}

/// [`tilt_to_mean`] to a mean error of `tol` × max |Δz|.
pub(super) fn tilt_to_mean_tol(
    d: usize,
    dz: &[f64],
    target: &[f64],
    p: &mut [f64],
    tol: f64,
) -> bool {
    let scale = dz
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    // Log weights, floored: Gaussian weights that underflowed to 0 must
    // still be reachable by the tilt, or the hull shrinks to the few
    // neighbours with visible weight.
    let base: Vec<f64> = p.iter().map(|&w| w.max(1e-300).ln()).collect();
    let mut lambda = vec![0.0; d];
    let tilted = |lambda: &[f64], out: &mut [f64]| -> f64 {
        let e: Vec<f64> = dz
            .chunks(d)
            .zip(&base)
            .map(|(z, &lb)| lb + z.iter().zip(lambda).map(|(a, b)| a * b).sum::<f64>())
            .collect();
        let emax = e.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut total = 0.0;
        for (o, &x) in out.iter_mut().zip(&e) {
            *o = (x - emax).exp();
            total += *o;
        }
        out.iter_mut().for_each(|o| *o /= total);
        // The dual objective, for the step-halving test.
        total.ln() + emax - lambda.iter().zip(target).map(|(a, b)| a * b).sum::<f64>()
    };
    let mut q = vec![0.0; base.len()];
    let mut obj = tilted(&lambda, &mut q);
    for _ in 0..300 {
        let mut grad = vec![0.0; d];
        for (z, &w) in dz.chunks(d).zip(&q) {
            for c in 0..d {
                grad[c] += w * z[c];
            }
        }
        for c in 0..d {
            grad[c] -= target[c];
        }
        if grad.iter().all(|g| g.abs() <= tol * scale) {
            p.copy_from_slice(&q);
            return true;
        }
        let mut hess = vec![0.0; d * d];
        for (z, &w) in dz.chunks(d).zip(&q) {
            for a in 0..d {
                for b in 0..d {
                    hess[a * d + b] +=
                        w * (z[a] - grad[a] - target[a]) * (z[b] - grad[b] - target[b]);
                }
            }
        }
        for a in 0..d {
            hess[a * d + a] += 1e-12 * scale * scale;
        }
        let Some(step) = solve_small(d, &mut hess, &grad) else {
            return false;
        };
        let mut t = 1.0;
        loop {
            let trial: Vec<f64> = lambda.iter().zip(&step).map(|(l, s)| l - t * s).collect();
            let o = tilted(&trial, &mut q);
            // Near the optimum the decrease is below the objective's
            // rounding: accept steps that do not increase it beyond that.
            if o <= obj + 8.0 * f64::EPSILON * obj.abs().max(1.0) || t < 1e-12 {
                lambda = trial;
                obj = o;
                break;
            }
            t *= 0.5;
        }
    }
    false
}

/// Solves the d × d system `a x = b` (row-major, overwritten) by Gaussian
/// elimination with partial pivoting.
pub(super) fn solve_small(d: usize, a: &mut [f64], b: &[f64]) -> Option<Vec<f64>> {
    let mut x = b.to_vec();
    for c in 0..d {
        let piv = (c..d).max_by(|&i, &j| a[i * d + c].abs().total_cmp(&a[j * d + c].abs()))?;
        if !(a[piv * d + c].abs() > 0.0) {
            return None;
        }
        for k in 0..d {
            a.swap(c * d + k, piv * d + k);
        }
        x.swap(c, piv);
        for r in c + 1..d {
            let m = a[r * d + c] / a[c * d + c];
            for k in c..d {
                a[r * d + k] -= m * a[c * d + k];
            }
            x[r] -= m * x[c];
        }
    }
    for c in (0..d).rev() {
        let s: f64 = (c + 1..d).map(|k| a[c * d + k] * x[k]).sum();
        x[c] = (x[c] - s) / a[c * d + c];
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tilt_matches_the_mean_inside_the_hull_and_refuses_outside() {
        let dz = [
            -0.0004, -0.00163, 0.00431, -0.00476, 0.0052, -0.00611, -0.0085, 0.00977, 0.01007,
            -0.01081,
        ];
        let w = [
            0.1232, 0.1207, 0.1171, 0.1076, 0.1133, 0.09954, 0.08325, 0.08538, 0.08326, 0.06667,
        ];
        let mut p = w.to_vec();
        assert!(tilt_to_mean(1, &dz, &[0.00079], &mut p));
        let mean: f64 = p.iter().zip(&dz).map(|(a, b)| a * b).sum();
        assert!((mean - 0.00079).abs() < 1e-12, "mean {mean}");
        assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let mut q = w.to_vec();
        assert!(!tilt_to_mean(1, &dz, &[0.02], &mut q));
        assert_eq!(q, w.to_vec());
    }
}
