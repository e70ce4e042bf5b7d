//! The update φ(z) ∝ p(y | z) φ(z) over the sparse support in one
//! weighting pass, the mass-bounded flush from a histogram of the
//! weights' binary exponents, and the moments in the flush pass (see the
//! module doc of [`super`]).

use super::{ChainFilter, Flush};
use crate::belief::WeightedMoments;
use crate::filter::live_chain::mass::ObsTerms;
use crate::filter::{check_measurement, FilterError, UpdateInfo};
use crate::model::{Measurement, SdeModel};
use crate::MAX_OBS;

/// Number of exponent buckets of the flush histogram: weights are ≤ 1
/// (φ ≤ 1 times a likelihood factor exp(l − shift) ≤ 1), so biased
/// exponents are ≤ 1023.
pub(super) const EXP_BUCKETS: usize = 1024;

/// Below this sum of unshifted weights φ·exp(l) the update redoes the pass
/// shifted by max l (the unshifted products lose precision as they near
/// the subnormal range).
const MIN_UNSHIFTED_SUM: f64 = 1e-250;

/// What the weighting pass of an update found.
struct Weighed {
    sum: f64,
    /// Σφ over the support and Σ w·exp(l − shift) = Σφ p² (scaled like
    /// w²): with `sum` the fraction of effective support kept.
    mass: f64,
    sq: f64,
    wmax: f64,
    lmax: f64,
    /// Range of histogram buckets touched (empty when lo > hi).
    lo: usize,
    hi: usize,
}

impl<M: SdeModel> ChainFilter<M> {
    /// Condition on `meas` (the [`crate::filter::BayesFilter::update`] of
    /// the filter).
    pub(super) fn update_step(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        let m = self.dims.obs;
        let (lik, cst) = ObsTerms::new(&self.model, meas);
        let y = &meas.y[..m];
        // One pass: w = φ(z) exp(l(z)) with l = −q/2 ≤ 0, so exp(l) ≤ 1 and
        // no max-shift is needed unless every likelihood underflows (then
        // the max-shifted pass below). ll is indexed by position in
        // `active` (contiguous, not by slot).
        let mut shift = 0.0;
        let mut w = self.weigh(y, &lik, shift);
        // Also when Σφp² underflows (every likelihood beyond ≈ 24σ): the
        // collapse test needs it, and the shifted pass gives the same
        // posterior.
        if !(w.sum > MIN_UNSHIFTED_SUM && w.sum.is_finite() && w.sq > MIN_UNSHIFTED_SUM) {
            if !w.lmax.is_finite() {
                self.collapses += 1;
                return Err(FilterError::Degenerate);
            }
            self.clear_hist(&w);
            shift = w.lmax;
            w = self.weigh(y, &lik, shift);
        }
        let sum = w.sum;
        if !(sum > 0.0 && sum.is_finite()) {
            self.clear_hist(&w);
            self.collapses += 1;
            return Err(FilterError::Degenerate);
        }
        if sum * sum < self.collapse_fraction * w.mass * w.sq {
            self.collapses += 1;
        }
        // The cut, in the unnormalised weights' units.
        let cut = match self.flush {
            Flush::Below(tau) => tau * sum,
            Flush::Mass(eps) => {
                let budget = eps * sum;
                let mut cum = 0.0;
                // buckets below `lo` are empty
                let mut b = w.lo;
                while b <= w.hi {
                    let h = self.exp_hist[b] + self.exp_hist[EXP_BUCKETS + b];
                    if cum + h > budget {
                        break;
                    }
                    cum += h;
                    b += 1;
                }
                // every weight with biased exponent < b, i.e. below 2^(b−1023)
                f64::from_bits((b.min(EXP_BUCKETS - 1) as u64) << 52)
            }
        }
        .min(w.wmax); // the largest mass always stays
        self.clear_hist(&w);
        let inv = 1.0 / sum;
        // The belief's moments in the same pass (what `moments` computes,
        // in the same order, so `belief` after an update is free).
        let d = self.dims.state;
        let (dropped, s2, keep, acc) = match d {
            1 => self.flush_pass::<1>(cut, inv),
            2 => self.flush_pass::<2>(cut, inv),
            3 => self.flush_pass::<3>(cut, inv),
            4 => self.flush_pass::<4>(cut, inv),
            _ => self.flush_pass::<0>(cut, inv),
        };
        self.discarded_last = dropped * inv;
        self.discarded_total += self.discarded_last;
        self.active.truncate(keep);
        self.support_sum += keep as u64;
        self.updates += 1;
        self.belief.set(Some(acc.gaussian()));
        Ok(UpdateInfo {
            log_evidence: shift + sum.ln() + cst,
            ess: 1.0 / s2,
            resampled: false,
        })
    }

    /// The update's weighting pass over the support: `ll[j]` ← w =
    /// φ(z) exp(l(z) − shift), with the mass histogram of the weights'
    /// exponents when the flush is mass-bounded.
    fn weigh(&mut self, y: &[f64], lik: &ObsTerms, shift: f64) -> Weighed {
        let m = self.dims.obs;
        let mass_rule = matches!(self.flush, Flush::Mass(_));
        let mut r = [0.0; MAX_OBS];
        let mut out = Weighed {
            sum: 0.0,
            mass: 0.0,
            sq: 0.0,
            wmax: 0.0,
            lmax: f64::NEG_INFINITY,
            lo: EXP_BUCKETS,
            hi: 0,
        };
        for (j, &zi) in self.active.iter().enumerate() {
            let z = zi as usize;
            let g = &self.obs_mean[z * m..(z + 1) * m];
            let l = lik.log_lik(&self.model, y, g, &mut r[..m]);
            out.lmax = out.lmax.max(l);
            let a = l - shift;
            // exp(−700) ≈ 1e-304: below that the result is zero or subnormal.
            let e = if a > -700.0 { a.exp() } else { 0.0 };
            let w = self.phi[z] * e;
            self.ll[j] = w;
            out.sum += w;
            out.mass += self.phi[z];
            out.sq += w * e;
            out.wmax = out.wmax.max(w);
            if mass_rule {
                // w ≤ 1: biased exponent ≤ 1023
                let b = ((w.to_bits() >> 52) as usize).min(EXP_BUCKETS - 1);
                self.exp_hist[b + (j & 1) * EXP_BUCKETS] += w;
                out.lo = out.lo.min(b);
                out.hi = out.hi.max(b);
            }
        }
        out
    }

    /// Zero the histogram buckets a weighting pass touched (the histogram
    /// is all zero between updates).
    fn clear_hist(&mut self, w: &Weighed) {
        if w.lo <= w.hi {
            self.exp_hist[w.lo..=w.hi].fill(0.0);
            self.exp_hist[EXP_BUCKETS + w.lo..=EXP_BUCKETS + w.hi].fill(0.0);
        }
    }

    /// The update's last pass: normalise, flush weights below `cut`,
    /// compact the support and accumulate the moments. `D` is the state
    /// dimension (0: any, read at run time). Returns the dropped
    /// (unnormalised) mass, Σ w², the kept support size and the moments
    /// (centred at the prior mean, as in `moments`; a local accumulator, so
    /// its sums can live in registers).
    fn flush_pass<const D: usize>(
        &mut self,
        cut: f64,
        inv: f64,
    ) -> (f64, f64, usize, WeightedMoments) {
        let mut acc = WeightedMoments::new(&self.prior.mean[..self.dims.state]);
        let mut s2 = 0.0;
        let mut dropped = 0.0;
        let mut keep = 0;
        for j in 0..self.active.len() {
            let z = self.active[j] as usize;
            let wu = self.ll[j];
            let mut w = wu * inv;
            // Zeroing negligible mass keeps predict's products out of
            // subnormal range (≈100× slower) and the support, hence both
            // predict and update, on the states that matter.
            if wu < cut || w == 0.0 {
                dropped += wu;
                w = 0.0;
            } else {
                self.active[keep] = z as u32;
                keep += 1;
                if D == 0 {
                    acc.add(w, self.chain.state(z));
                } else {
                    acc.add_fixed::<D>(w, self.chain.state(z));
                }
            }
            self.phi[z] = w;
            s2 += w * w;
        }
        (dropped, s2, keep, acc)
    }
}
