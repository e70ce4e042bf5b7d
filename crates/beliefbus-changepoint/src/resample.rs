//! Resampling schemes with one signature: normalised weights in, M ancestor
//! indices out, into caller-owned buffers (nothing allocates).
//!
//! Chen, Lai & Wu (§2.2 step b) only say "resample with probabilities
//! proportional to the weights"; the bound-0 column of their Table 1 is
//! sensitive to the scheme, so all three classical unbiased schemes are
//! offered: each gives E[offspring of i] = M·w_i.
//! - multinomial: M i.i.d. draws from w (ordered uniforms by normalised
//!   exponential spacings, O(M));
//! - residual: ⌊M w_i⌋ copies, the rest multinomial on the remainders;
//! - systematic: one uniform u, points (u + k)/M, k = 0..M−1.

use crate::error::ChangepointError;
use rand::{Rng, RngExt};
use std::str::FromStr;

/// Which resampling scheme to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
pub enum Scheme {
    Multinomial,
    Residual,
    #[default]
    Systematic,
}

impl Scheme {
    /// All schemes, for sweeps and tests.
    pub const ALL: [Scheme; 3] = [Scheme::Multinomial, Scheme::Residual, Scheme::Systematic];

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Scheme::Multinomial => "multinomial",
            Scheme::Residual => "residual",
            Scheme::Systematic => "systematic",
        }
    }
}

impl FromStr for Scheme {
    type Err = ChangepointError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "multinomial" => Ok(Scheme::Multinomial),
            "residual" => Ok(Scheme::Residual),
            "systematic" => Ok(Scheme::Systematic),
            other => Err(ChangepointError::UnknownScheme(other.to_string())),
        }
    }
}

/// Draw `anc.len()` ancestors from normalised weights `w` (same length).
/// `scratch` must have the same length (it holds residual weights).
pub fn resample<R: Rng + ?Sized>(
    scheme: Scheme,
    w: &[f64],
    rng: &mut R,
    anc: &mut [usize],
    scratch: &mut [f64],
) {
    debug_assert_eq!(w.len(), anc.len());
    debug_assert_eq!(w.len(), scratch.len());
    match scheme {
        Scheme::Multinomial => multinomial(w, 1.0, rng, anc),
        Scheme::Systematic => {
            let m = anc.len();
            let u: f64 = rng.random::<f64>() / m as f64;
            let step = 1.0 / m as f64;
            let mut cum = w[0];
            let mut i = 0;
            for (k, a) in anc.iter_mut().enumerate() {
                let p = u + k as f64 * step;
                while p > cum && i + 1 < m {
                    i += 1;
                    cum += w[i];
                }
                *a = i;
            }
        }
        Scheme::Residual => {
            let m = anc.len();
            let mf = m as f64;
            let mut k = 0;
            let mut rest = 0.0;
            for (i, &wi) in w.iter().enumerate() {
                let n = (mf * wi).floor();
                for _ in 0..n as usize {
                    if k < m {
                        anc[k] = i;
                        k += 1;
                    }
                }
                scratch[i] = mf * wi - n;
                rest += scratch[i];
            }
            if k < m {
                if rest > 0.0 {
                    multinomial(scratch, rest, rng, &mut anc[k..]);
                } else {
                    // Remainders lost to rounding: give the slots to the
                    // heaviest particle (a measure-zero event in exact
                    // arithmetic).
                    let best = argmax(w);
                    anc[k..].fill(best);
                }
            }
        }
    }
}

/// `out.len()` i.i.d. draws from unnormalised weights `w` summing to `total`,
/// returned in increasing order. The ordered uniforms come from the
/// sequential construction 1 − U₍ₖ₊₁₎ = (1 − U₍ₖ₎)·V^{1/(n−k)}, V ~ U(0,1),
/// so no sort and no buffer is needed.
fn multinomial<R: Rng + ?Sized>(w: &[f64], total: f64, rng: &mut R, out: &mut [usize]) {
    let n = out.len();
    let mut remaining = 1.0;
    let mut i = 0;
    let mut cum = w[0] / total;
    for (k, o) in out.iter_mut().enumerate() {
        let v: f64 = rng.random::<f64>();
        remaining *= v.powf(1.0 / (n - k) as f64);
        let u = 1.0 - remaining;
        while u > cum && i + 1 < w.len() {
            i += 1;
            cum += w[i] / total;
        }
        *o = i;
    }
}

fn argmax(w: &[f64]) -> usize {
    let mut best = 0;
    for (i, &x) in w.iter().enumerate() {
        if x > w[best] {
            best = i;
        }
    }
    best
}

/// Copy `x[anc[k]]` into `x[k]` for all k, through `scratch`.
pub fn gather<T: Copy>(x: &mut [T], scratch: &mut [T], anc: &[usize]) {
    for (s, &a) in scratch.iter_mut().zip(anc) {
        *s = x[a];
    }
    x.copy_from_slice(scratch);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng;

    /// Each scheme is unbiased: over N independent resamplings the mean
    /// offspring count of particle i is M·w_i within 5 standard errors
    /// (the s.e. estimated from the same N counts).
    #[test]
    fn every_scheme_has_expected_offspring_m_times_w() {
        let w_raw = [0.31, 0.02, 0.17, 0.005, 0.095, 0.2, 0.11, 0.09];
        let total: f64 = w_raw.iter().sum();
        let w: Vec<f64> = w_raw.iter().map(|x| x / total).collect();
        let m = w.len();
        let n = 40_000;
        for scheme in Scheme::ALL {
            let mut r = rng::stream(11, scheme as u64);
            let (mut anc, mut scratch) = (vec![0; m], vec![0.0; m]);
            let mut sum = vec![0.0; m];
            let mut sum2 = vec![0.0; m];
            for _ in 0..n {
                resample(scheme, &w, &mut r, &mut anc, &mut scratch);
                let mut c = vec![0.0; m];
                for &a in &anc {
                    c[a] += 1.0;
                }
                for i in 0..m {
                    sum[i] += c[i];
                    sum2[i] += c[i] * c[i];
                }
            }
            for i in 0..m {
                let mean = sum[i] / n as f64;
                let var = (sum2[i] / n as f64 - mean * mean).max(0.0);
                let se = (var / n as f64).sqrt();
                let target = m as f64 * w[i];
                assert!(
                    (mean - target).abs() <= 5.0 * se + 1e-9,
                    "{}: particle {i} mean {mean} vs M·w {target} (se {se})",
                    scheme.name()
                );
            }
        }
    }

    /// The schemes differ in variance as theory says: residual and
    /// systematic never give fewer than ⌊M w_i⌋ copies, multinomial can.
    #[test]
    fn residual_and_systematic_keep_the_integer_part() {
        let w = [0.5, 0.25, 0.125, 0.125];
        for scheme in [Scheme::Residual, Scheme::Systematic] {
            let mut r = rng::stream(3, 0);
            let (mut anc, mut scratch) = ([0; 4], [0.0; 4]);
            for _ in 0..1000 {
                resample(scheme, &w, &mut r, &mut anc, &mut scratch);
                let c0 = anc.iter().filter(|&&a| a == 0).count();
                let c1 = anc.iter().filter(|&&a| a == 1).count();
                assert!(c0 >= 2 && c1 >= 1, "{}", scheme.name());
            }
        }
    }
}
