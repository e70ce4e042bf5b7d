//! Resampling schemes. The weights they read come from
//! [`crate::math::weights`] (log-sum-exp normalisation and the effective
//! sample size, the crate's one copy).
//!
//! Every scheme has one signature (the `particles` habit, `A = scheme(W, M)`):
//! it reads weights `w` (non-negative, any positive sum) and writes
//! `ancestors.len()` ancestor indices into a caller-provided buffer; nothing
//! allocates. All schemes are unbiased: E[#{k : a_k = i}] = M·W_i.
//!
//! - systematic (default): one uniform U, points (k + U)/M;
//! - stratified: one uniform per stratum, points (k + U_k)/M;
//! - multinomial: M i.i.d. uniforms, generated already sorted (the minimum of
//!   M uniforms is 1 − V^{1/M}; the rest are uniform above it);
//! - residual: ⌊M W_i⌋ deterministic copies, the remaining R draws
//!   multinomial on the residuals M W_i − ⌊M W_i⌋.
//!
//! Each scheme maps its sorted points through the inverse CDF of the weights
//! in one linear pass, never selecting a zero-weight index.

use super::FilterError;
use crate::rng::SimRng;
use rand::RngExt;
use serde::{Deserialize, Serialize};

/// A resampling scheme.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum Scheme {
    #[default]
    Systematic,
    Stratified,
    Multinomial,
    Residual,
}

impl Scheme {
    /// Draw `ancestors.len()` ancestor indices from weights `w`.
    pub fn resample(
        self,
        w: &[f64],
        rng: &mut SimRng,
        ancestors: &mut [usize],
    ) -> Result<(), FilterError> {
        match self {
            Scheme::Systematic => systematic(w, rng, ancestors),
            Scheme::Stratified => stratified(w, rng, ancestors),
            Scheme::Multinomial => multinomial(w, rng, ancestors),
            Scheme::Residual => residual(w, rng, ancestors),
        }
    }

    /// The scheme's config name.
    pub fn name(self) -> &'static str {
        match self {
            Scheme::Systematic => "systematic",
            Scheme::Stratified => "stratified",
            Scheme::Multinomial => "multinomial",
            Scheme::Residual => "residual",
        }
    }
}

/// Total weight and last positive index; errors when no weight is positive
/// or a weight is negative or non-finite.
fn check_weights(w: &[f64], m: usize) -> Result<(f64, usize), FilterError> {
    if w.is_empty() && m > 0 {
        return Err(FilterError::Dimension {
            what: "weights",
            got: 0,
            expected: m,
        });
    }
    let mut total = 0.0;
    let mut last = None;
    for (i, &v) in w.iter().enumerate() {
        if !(v >= 0.0) || !v.is_finite() {
            return Err(FilterError::NonFinite("weights"));
        }
        if v > 0.0 {
            total += v;
            last = Some(i);
        }
    }
    match last {
        Some(l) if total.is_finite() => Ok((total, l)),
        _ if m == 0 => Ok((0.0, 0)),
        _ => Err(FilterError::Degenerate),
    }
}

/// Map ascending points `x_k ∈ [0, 1)` (produced by `next`) through the
/// inverse CDF of weights `wf(i)` (total `total`, last positive `last`):
/// a_k = min{ j : Σ_{i≤j} w_i > x_k · total }.
fn inverse_cdf(
    n_out: usize,
    wf: impl Fn(usize) -> f64,
    total: f64,
    last: usize,
    mut next: impl FnMut(usize) -> f64,
    out: &mut [usize],
) {
    let mut j = 0;
    let mut c = wf(0);
    for (k, a) in out.iter_mut().enumerate().take(n_out) {
        let x = next(k) * total;
        while c <= x && j < last {
            j += 1;
            c += wf(j);
        }
        *a = j;
    }
}

/// Systematic resampling: points (k + U)/M with one U ~ U[0, 1).
pub fn systematic(w: &[f64], rng: &mut SimRng, ancestors: &mut [usize]) -> Result<(), FilterError> {
    let m = ancestors.len();
    let (total, last) = check_weights(w, m)?;
    if m == 0 {
        return Ok(());
    }
    let u: f64 = rng.random();
    let inv = 1.0 / m as f64;
    inverse_cdf(
        m,
        |i| w[i],
        total,
        last,
        |k| (k as f64 + u) * inv,
        ancestors,
    );
    Ok(())
}

/// Stratified resampling: points (k + U_k)/M with independent U_k.
pub fn stratified(w: &[f64], rng: &mut SimRng, ancestors: &mut [usize]) -> Result<(), FilterError> {
    let m = ancestors.len();
    let (total, last) = check_weights(w, m)?;
    if m == 0 {
        return Ok(());
    }
    let inv = 1.0 / m as f64;
    inverse_cdf(
        m,
        |i| w[i],
        total,
        last,
        |k| (k as f64 + rng.random::<f64>()) * inv,
        ancestors,
    );
    Ok(())
}

/// Ascending order statistics of `m` i.i.d. U[0, 1) draws, one at a time.
struct SortedUniforms<'a> {
    rng: &'a mut SimRng,
    m: usize,
    /// 1 − (current order statistic).
    rest: f64,
}

impl SortedUniforms<'_> {
    fn next(&mut self, k: usize) -> f64 {
        // The minimum of the remaining m − k uniforms on (x, 1):
        // x + (1 − x)(1 − V^{1/(m−k)}).
        let v: f64 = self.rng.random();
        self.rest *= v.powf(1.0 / (self.m - k) as f64);
        1.0 - self.rest
    }
}

/// Multinomial resampling: M i.i.d. draws from the weights.
pub fn multinomial(
    w: &[f64],
    rng: &mut SimRng,
    ancestors: &mut [usize],
) -> Result<(), FilterError> {
    let m = ancestors.len();
    let (total, last) = check_weights(w, m)?;
    if m == 0 {
        return Ok(());
    }
    let mut su = SortedUniforms { rng, m, rest: 1.0 };
    inverse_cdf(m, |i| w[i], total, last, |k| su.next(k), ancestors);
    Ok(())
}

/// Residual resampling: ⌊M W_i⌋ copies of each i, then multinomial draws on
/// the residual weights for the remaining slots.
pub fn residual(w: &[f64], rng: &mut SimRng, ancestors: &mut [usize]) -> Result<(), FilterError> {
    let m = ancestors.len();
    let (total, _) = check_weights(w, m)?;
    if m == 0 {
        return Ok(());
    }
    let scale = m as f64 / total;
    let mut filled = 0;
    for (i, &v) in w.iter().enumerate() {
        let copies = ((v * scale).floor() as usize).min(m - filled);
        ancestors[filled..filled + copies].fill(i);
        filled += copies;
    }
    let r = m - filled;
    if r == 0 {
        return Ok(());
    }
    let resid = |i: usize| {
        let x = w[i] * scale;
        (x - x.floor()).max(0.0)
    };
    let mut rtotal = 0.0;
    let mut last = None;
    for i in 0..w.len() {
        let v = resid(i);
        if v > 0.0 {
            rtotal += v;
            last = Some(i);
        }
    }
    let Some(last) = last else {
        // Rounding left slots but no residual mass: fill by systematic.
        return systematic(w, rng, &mut ancestors[filled..]);
    };
    let mut su = SortedUniforms {
        rng,
        m: r,
        rest: 1.0,
    };
    inverse_cdf(
        r,
        resid,
        rtotal,
        last,
        |k| su.next(k),
        &mut ancestors[filled..],
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn degenerate_weights_are_reported() {
        let mut rng = crate::rng::stream(1, 1);
        let mut a = [0usize; 3];
        for s in [
            Scheme::Systematic,
            Scheme::Stratified,
            Scheme::Multinomial,
            Scheme::Residual,
        ] {
            assert_eq!(
                s.resample(&[0.0, 0.0], &mut rng, &mut a),
                Err(FilterError::Degenerate)
            );
            assert!(s.resample(&[0.5, -0.1], &mut rng, &mut a).is_err());
            assert!(s.resample(&[], &mut rng, &mut a).is_err());
        }
    }

    /// Unbiasedness: over R repetitions the mean offspring count of particle
    /// i is M·W_i within 5 standard errors (multinomial variance M W (1−W)
    /// bounds every scheme's; 1/4 floors the rounding schemes').
    #[test]
    fn all_schemes_are_unbiased() {
        let w = [0.02, 0.0, 0.31, 0.07, 0.15, 0.0, 0.25, 0.2];
        let total: f64 = w.iter().sum();
        let reps = 4000;
        for m in [8usize, 13] {
            for (si, s) in [
                Scheme::Systematic,
                Scheme::Stratified,
                Scheme::Multinomial,
                Scheme::Residual,
            ]
            .into_iter()
            .enumerate()
            {
                let mut rng = crate::rng::stream(42, si as u64 + 10 * m as u64);
                let mut a = vec![0usize; m];
                let mut counts = [0f64; 8];
                for _ in 0..reps {
                    s.resample(&w, &mut rng, &mut a).unwrap();
                    let mut c = [0usize; 8];
                    for &i in &a {
                        c[i] += 1;
                    }
                    for i in 0..8 {
                        counts[i] += c[i] as f64;
                        let mw = m as f64 * w[i] / total;
                        if w[i] == 0.0 {
                            assert_eq!(c[i], 0, "{s:?} picked a zero weight");
                        }
                        if s == Scheme::Systematic {
                            // Systematic gives ⌊MW⌋ or ⌈MW⌉ copies.
                            assert!(
                                (c[i] as f64 - mw).abs() < 1.0 + 1e-9,
                                "{s:?}: {} copies for MW = {mw}",
                                c[i]
                            );
                        }
                        if s == Scheme::Residual {
                            assert!(c[i] as f64 >= mw.floor());
                        }
                    }
                }
                for i in 0..8 {
                    let wi = w[i] / total;
                    let mw = m as f64 * wi;
                    let mean = counts[i] / reps as f64;
                    let sd = ((m as f64 * wi * (1.0 - wi)).max(0.25) / reps as f64).sqrt();
                    assert!(
                        (mean - mw).abs() < 5.0 * sd,
                        "{s:?} M={m} i={i}: mean {mean} vs {mw} (sd {sd})"
                    );
                }
            }
        }
    }

    #[test]
    fn sorted_uniforms_are_uniform_order_statistics() {
        // E[U_(k)] = k/(M+1) for the k-th smallest of M uniforms.
        let m = 4;
        let reps = 20_000;
        let mut rng = crate::rng::stream(3, 3);
        let mut sums = [0.0; 4];
        for _ in 0..reps {
            let mut su = SortedUniforms {
                rng: &mut rng,
                m,
                rest: 1.0,
            };
            let mut prev = 0.0;
            for (k, s) in sums.iter_mut().enumerate() {
                let x = su.next(k);
                assert!(x >= prev && x < 1.0);
                prev = x;
                *s += x;
            }
        }
        for (k, s) in sums.iter().enumerate() {
            let want = (k + 1) as f64 / (m + 1) as f64;
            // Var U_(k) ≤ 1/(4(M+2)).
            let se = (0.25 / (m + 2) as f64 / reps as f64).sqrt();
            assert!((s / reps as f64 - want).abs() < 5.0 * se);
        }
    }
}
