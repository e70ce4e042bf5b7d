//! The rollouts of MPPI, K at a time in structure-of-arrays layout, and
//! the smoothing and weighting arithmetic they feed.

use crate::model::path_cost::PathCost;
use crate::model::SdeModel;
use crate::MAX_CONTROL;

/// 5-point quadratic Savitzky–Golay weights (×35): interior, first and
/// second point (the last two mirror them).
const SG_MID: [f64; 5] = [-3.0, 12.0, 17.0, 12.0, -3.0];
const SG_FIRST: [f64; 5] = [31.0, 9.0, -3.0, -5.0, 3.0];
const SG_SECOND: [f64; 5] = [9.0, 13.0, 12.0, 6.0, -5.0];

/// Smooth a T × c time-major sequence `src` into `dst` per component with
/// the quadratic SG filter (exact on quadratics, including the ends).
pub(super) fn savitzky_golay(src: &[f64], dst: &mut [f64], steps: usize, c: usize) {
    if steps < 5 {
        dst.copy_from_slice(src);
        return;
    }
    for j in 0..c {
        let at = |t: usize| src[t * c + j];
        for t in 0..steps {
            let (w, base, rev) = match t {
                0 => (&SG_FIRST, 0, false),
                1 => (&SG_SECOND, 0, false),
                _ if t == steps - 1 => (&SG_FIRST, steps - 5, true),
                _ if t == steps - 2 => (&SG_SECOND, steps - 5, true),
                _ => (&SG_MID, t - 2, false),
            };
            let mut s = 0.0;
            for (i, wi) in w.iter().enumerate() {
                let idx = if rev { base + 4 - i } else { base + i };
                s += wi * at(idx);
            }
            dst[t * c + j] = s / 35.0;
        }
    }
}

/// Σ a_k b_k with four independent partial sums (a single running sum is a
/// chain of dependent adds the CPU cannot overlap).
pub(super) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            acc[l] += x[l] * y[l];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

/// What a rollout reads.
pub(super) struct RolloutParams<'a, C: PathCost> {
    pub(super) d: usize,
    pub(super) c: usize,
    pub(super) k: usize,
    pub(super) steps: usize,
    pub(super) dt: f64,
    pub(super) r: f64,
    pub(super) u_min: &'a [f64; MAX_CONTROL],
    pub(super) u_max: &'a [f64; MAX_CONTROL],
    pub(super) u_nom: &'a [f64],
    pub(super) cost: &'a C,
}

/// What a rollout writes (all structure-of-arrays, K per component).
pub(super) struct RolloutBuffers<'a> {
    pub(super) x: &'a mut [f64],
    pub(super) f: &'a mut [f64],
    pub(super) v: &'a mut [f64],
    pub(super) eps: &'a mut [f64],
    pub(super) costs: &'a mut [f64],
}

/// [`rollout_soa`] compiled for AVX2 + FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) fn rollout_avx2<M: SdeModel, C: PathCost>(
    model: &M,
    p: &RolloutParams<C>,
    b: &mut RolloutBuffers,
    x0: &[f64],
) {
    rollout_soa(model, p, b, x0)
}

/// The K rollouts in lockstep, one Euler step of all of them at a time:
/// v_k = clamp(u_t + ε_{t,k}), x_k ← x_k + f(x_k, v_k) Δt,
/// S_k += (q(x_k) + r |v_k|²) Δt, then S_k += φ(x_k) at the horizon.
/// Every inner loop runs over k on contiguous arrays, without branches, so
/// the compiler vectorises it.
#[inline(always)]
pub(super) fn rollout_soa<M: SdeModel, C: PathCost>(
    model: &M,
    p: &RolloutParams<C>,
    b: &mut RolloutBuffers,
    x0: &[f64],
) {
    let (d, c, k) = (p.d, p.c, p.k);
    for i in 0..d {
        b.x[i * k..(i + 1) * k].fill(x0[i]);
    }
    b.costs.fill(0.0);
    let cost = p.cost;
    for t in 0..p.steps {
        let u = &p.u_nom[t * c..(t + 1) * c];
        let eps_t = &mut b.eps[t * k * c..(t + 1) * k * c];
        for j in 0..c {
            let (lo, hi, uj) = (p.u_min[j], p.u_max[j], u[j]);
            let e = &mut eps_t[j * k..(j + 1) * k];
            let v = &mut b.v[j * k..(j + 1) * k];
            let s = &mut b.costs[..k];
            let rdt = p.r * p.dt;
            for n in 0..k {
                let vj = (uj + e[n]).max(lo).min(hi);
                e[n] = vj - uj;
                v[n] = vj;
                s[n] += rdt * (vj * vj);
            }
        }
        model.drift_soa(k, b.x, b.v, b.f);
        for (x, f) in b.x.iter_mut().zip(b.f.iter()) {
            *x += f * p.dt;
        }
        cost.add_running_soa(p.dt, k, b.x, b.costs);
    }
    cost.add_terminal_soa(1.0, k, b.x, b.costs);
    for s in b.costs.iter_mut() {
        if !s.is_finite() {
            *s = f64::INFINITY;
        }
    }
}
