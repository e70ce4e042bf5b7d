//! The domain's box as a cliff instead of a wall: a path that reaches the
//! box's edge during a decision period ends the episode with a penalty C,
//! instead of stopping there. With walls, pushing into a corner locates the
//! system exactly, whatever it observes; with a cliff that is fatal, so a
//! plan must localise by observing.
//!
//! Per axis i over one period h, Brownian motion with drift μ = f_i(z, u)
//! and diffusion σ_i from x = z_i inside lo < x < hi (first passage by the
//! reflection principle):
//!
//! ```text
//! P↑ = Φ((μh − a)/(σ√h)) + e^{2μa/σ²} Φ(−(a + μh)/(σ√h)),   a = hi − x
//! P↓ = the same with μ → −μ,  a = x − lo
//! P_i = min(1, P↑ + P↓)                  (the two-barrier series less the paths touching both edges in h)
//! p_out = 1 − Π_i (1 − P_i)              (independent axes: diagonal diffusion)
//! T'(·|z,u) = (1 − p_out) T(·|z,u) + p_out δ_end,    R'(z,u) = R(z,u) − C p_out
//! ```
//!
//! The drift is frozen at its value at z over the period (exact for the
//! light-dark's f = u). The surviving mass keeps the row it had (mean the
//! clamped z + f h): for the few rows with a visible p_out this is the
//! approximation, the surviving paths' law being the one conditioned on
//! not crossing. A state on the edge itself (a = 0) leaves with
//! probability 1.

use super::{ChainPomdp, ChainPomdpError};
use crate::model::{Pomdp, SparseRows};
use beliefbus_core::math::truncnorm::ln_erfc;
use std::f64::consts::{FRAC_1_SQRT_2, LN_2};

/// f(z, u) written into the last argument.
pub type Drift<'a> = &'a dyn Fn(&[f64], &[f64], &mut [f64]);

/// ln Φ(x) of the standard normal, accurate in the lower tail.
fn ln_phi(x: f64) -> f64 {
    ln_erfc(-x * FRAC_1_SQRT_2) - LN_2
}

/// P(max_{s ≤ h} (μs + σW_s) ≥ a) for a ≥ 0 (module doc, P↑).
pub fn pass_prob(a: f64, mu: f64, sigma: f64, h: f64) -> f64 {
    if a <= 0.0 {
        return 1.0;
    }
    let s = sigma * h.sqrt();
    let first = ln_phi((mu * h - a) / s).exp();
    // e^{2μa/σ²} Φ(·) in logs: the factor overflows where the product
    // does not.
    let second = (2.0 * mu * a / (sigma * sigma) + ln_phi(-(a + mu * h) / s)).exp();
    (first + second).min(1.0)
}

/// p_out of the module doc at `z` under drift `f` (per axis) with
/// diffusion `sigma` (per axis) over `h` in the box [lo, hi].
pub fn leave_prob(z: &[f64], f: &[f64], sigma: &[f64], h: f64, lo: &[f64], hi: &[f64]) -> f64 {
    let mut stay = 1.0;
    for i in 0..z.len() {
        let up = pass_prob(hi[i] - z[i], f[i], sigma[i], h);
        let down = pass_prob(z[i] - lo[i], -f[i], sigma[i], h);
        stay *= 1.0 - (up + down).min(1.0);
    }
    1.0 - stay
}

/// Makes the box's edge a cliff in `cp` (which must have its terminal
/// action, so that an absorbing state exists): every control's row and
/// reward as in the module doc, `drift(z, u)` the drift at a state,
/// `sigma` the per-axis diffusion, `penalty` the C > 0 paid on leaving.
/// Returns the largest p_out over the chain's states and controls.
pub fn make_cliff(
    cp: &mut ChainPomdp,
    drift: Drift<'_>,
    sigma: &[f64],
    lo: &[f64],
    hi: &[f64],
    penalty: f64,
) -> Result<f64, ChainPomdpError> {
    let d = cp.dim;
    let n = cp.n_chain();
    if cp.offset == 0 || cp.pomdp.n_states() != n + 1 {
        return Err(ChainPomdpError::Spec(
            "a cliff needs the terminal action's absorbing state".into(),
        ));
    }
    if sigma.len() != d || lo.len() != d || hi.len() != d || !(penalty > 0.0) {
        return Err(ChainPomdpError::Spec(format!(
            "a cliff needs σ, lo and hi with {d} entries and a positive penalty"
        )));
    }
    let h = cp.period;
    let ns = n + 1;
    let mut f = vec![0.0; d];
    let mut worst: f64 = 0.0;
    let p = &cp.pomdp;
    let mut trans = Vec::with_capacity(p.n_actions());
    let mut reward = Vec::with_capacity(p.n_actions());
    for a in 0..p.n_actions() {
        let Some(u) = cp.control(a) else {
            trans.push(p.trans[a].clone());
            reward.push(p.reward[a].clone());
            continue;
        };
        let mut rows = Vec::with_capacity(ns);
        let mut r = p.reward[a].clone();
        for s in 0..ns {
            let (cols, vals) = p.trans[a].row(s);
            if s == n {
                rows.push(cols.iter().copied().zip(vals.iter().copied()).collect());
                continue;
            }
            let z = &cp.states[s * d..(s + 1) * d];
            drift(z, u, &mut f);
            let out = leave_prob(z, &f, sigma, h, lo, hi);
            worst = worst.max(out);
            let mut row: Vec<(u32, f64)> = cols
                .iter()
                .zip(vals)
                .filter(|&(&j, _)| j as usize != n)
                .map(|(&j, &v)| (j, v * (1.0 - out)))
                .filter(|&(_, v)| v > 0.0)
                .collect();
            let kept: f64 = cols
                .iter()
                .zip(vals)
                .filter(|&(&j, _)| j as usize == n)
                .map(|(_, &v)| v)
                .sum();
            let end = out + kept * (1.0 - out);
            if end > 0.0 {
                row.push((n as u32, end));
            }
            rows.push(row);
            r[s] -= penalty * out;
        }
        trans.push(SparseRows::from_rows(rows, ns));
        reward.push(r);
    }
    cp.pomdp = Pomdp::new(p.discount, p.start.clone(), trans, p.obs.clone(), reward)?;
    Ok(worst)
}

#[cfg(test)]
#[path = "cliff_tests.rs"]
mod tests;
