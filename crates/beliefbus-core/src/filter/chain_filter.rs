//! The Markov-chain filter (thesis §3.3, eq. 3.6; paper 001 eq. 4) on the
//! time-equalised chain M_n^δ:
//!
//! ```text
//! predict over Δ:  φ ← ((P^δ)ᵀ)^{⌊Δ/δ⌋} φ, then a fraction θ = frac(Δ/δ) of one step
//! update:          φ(z) ∝ p(y | z) φ(z),   p(y | z) = Π_{i∈mask} N(y_i; g_i(z), σ_i²)
//! estimate:        x̂ = Σ_z z φ(z),  P̂ = Σ_z (z − x̂)(z − x̂)ᵀ φ(z)
//! ```
//!
//! To build one from a model and a prior alone — δ, state budget and
//! placement derived from the model — use
//! [`crate::filter::chain_spec::ChainFilterSpec`]`::build`, the same
//! `XxxConfig { .. }.build(model, &prior, t0)` pattern as the PF, EKF and
//! UKF configs; [`ChainFilter::new`] takes a chain built by hand.
//!
//! Observations are the crate's *sampled* measurements (see
//! [`crate::model`]): the papers' continuous `dy = g dt + G dv` observed as
//! increments over Δ is `y = Δy/Δ` with σ = G/√Δ, whose likelihood is the
//! Gaussian on the increment N(Δy; gΔ, GGᵀΔ) of the notes' derived form up to
//! a z-independent factor. The per-state observation means g(z) are
//! precomputed for each chain version.
//!
//! Choices where the thesis is silent:
//! - **Prior on the chain**: φ(z) ∝ N(z; x̂₀, P₀) · vol(z) with
//!   vol(z) = r(z)^d/|Near(z)| ([`Chain::cell_volume`]), so that a chain
//!   sampled non-uniformly (concentrated around a belief) represents the
//!   prior density and not the sampling density.
//! - **States added while filtering** ([`ChainFilter::grow`]): the density
//!   φ/vol of each new state is the average over its Near set (the thesis's
//!   `ApproximateDensity`, §3.5, applied to densities), reconnected states
//!   keep their density while their volume shrinks, then φ is renormalised.
//! - **Controls**: the chain is built for a reference control u₀
//!   (`ChainConfig::control`, 0 as in the thesis). For u ≠ u₀, rebuilding
//!   holding times and kernels is too costly per step, so the kernel is
//!   *tilted*: p_u(z'|z) ∝ p(z'|z) exp(θ(z)ᵀ(z' − z)) with
//!   θ = (FFᵀ)⁻¹ (f(z,u) − f(z,u₀)). For the Gaussian kernel this is exactly
//!   shifting its mean by (f(z,u) − f(z,u₀))Δt; for any kernel whose
//!   covariance is FFᵀΔt it shifts the mean by that amount to first order.
//!   Holding times stay those of u₀. The tilt (n drift evaluations, nnz
//!   exponentials) is recomputed only when u changes; predict with u = u₀
//!   uses the untilted kernel. States where FFᵀ is singular are not tilted.
//! - **Flush** (not in the thesis; it keeps the sparse support bounded):
//!   after each update, the smallest posterior masses are set to zero,
//!   at most ε of the (normalised) mass in total, ε = [`FLUSH_MASS`] by
//!   default ([`ChainFilter::set_flush_mass`]). The cut is found from a
//!   histogram of the weights' binary exponents built in the update's
//!   weighting pass: with `H_b` the mass of weights in [2^{b−1023}, 2^{b−1022})
//!   the flush zeroes every weight below 2^{b*−1023} for the largest b* with
//!   Σ_{b<b*} H_b ≤ ε, so the discarded mass D satisfies D ≤ ε (exactly,
//!   up to rounding) and the cut is within a factor 2 of the exact
//!   "smallest masses summing to ε". Consequences for the step's output:
//!   the flushed belief φ' = φ·1{kept}/(1 − D) is within total variation
//!   D ≤ ε of φ, so any moment of a function bounded by B moves by at most
//!   2εB (the mean by at most 2ε·max_z‖z − x̂‖). The per-update D is
//!   reported by [`ChainFilter::last_discarded`] and summed in
//!   [`ChainFilter::discarded_total`]. ε = 1e-9 is far below both the
//!   Monte-Carlo error of any experiment and the chain's own bias, and it
//!   removes the far tails that prediction keeps spreading (without it the
//!   support of a 10⁴-state chain never shrinks below a few thousand
//!   states, and the filter step is ≈ 20× slower). An absolute threshold
//!   is still available ([`ChainFilter::set_flush`]).
//! - predict/update allocate nothing: all buffers are sized when the chain
//!   version is installed.

use std::cell::Cell;

use crate::belief::{Gaussian, WeightedMoments};
use crate::chain::linalg::{backward_sub_t, cholesky, forward_sub};
use crate::chain::{Chain, ChainError, PropagationKernel, Sampler, TimeEqualized};
use crate::filter::{check_measurement, check_predict, BayesFilter, FilterError, UpdateInfo};
use crate::model::{Dims, Measurement, SdeModel};
use crate::rng::SimRng;
use crate::{MAX_CONTROL, MAX_OBS, MAX_STATE};

const HALF_LOG_2PI: f64 = 0.918_938_533_204_672_8;
/// Default bound ε on the posterior mass an update's flush discards (see
/// the module doc).
pub const FLUSH_MASS: f64 = 1e-9;

/// Number of exponent buckets of the flush histogram: weights are ≤ 1
/// (φ ≤ 1 times a likelihood factor exp(l − shift) ≤ 1), so biased
/// exponents are ≤ 1023.
const EXP_BUCKETS: usize = 1024;

/// Below this sum of unshifted weights φ·exp(l) the update redoes the pass
/// shifted by max l (the unshifted products lose precision as they near
/// the subnormal range).
const MIN_UNSHIFTED_SUM: f64 = 1e-250;

/// The observed components and their inverse variances.
struct ObsTerms {
    idx: [usize; MAX_OBS],
    inv_var: [f64; MAX_OBS],
    nm: usize,
}

/// What the weighting pass of an update found.
struct Weighed {
    sum: f64,
    wmax: f64,
    lmax: f64,
    /// Range of histogram buckets touched (empty when lo > hi).
    lo: usize,
    hi: usize,
}

/// How an update flushes small posterior masses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Flush {
    /// Zero the smallest masses, at most this total (normalised) mass.
    Mass(f64),
    /// Zero every normalised mass below this threshold.
    Below(f64),
}

/// What [`ChainFilter::grow`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GrowInfo {
    pub added: usize,
    pub reconnected: usize,
    /// Whether exponential backup halved δ (full recomputation of p^δ).
    pub delta_halved: bool,
    pub delta: f64,
}

/// The Markov-chain filter.
pub struct ChainFilter<M: SdeModel> {
    model: M,
    dims: Dims,
    chain: Chain,
    eq: TimeEqualized,
    kern: PropagationKernel,
    obs_mean: Vec<f64>,
    phi: Vec<f64>,
    tmp: Vec<f64>,
    ll: Vec<f64>,
    t: f64,
    u_last: [f64; MAX_CONTROL],
    tilt_probs: Vec<f64>,
    belief: Cell<Option<Gaussian>>,
    prior: Gaussian,
    steps: u64,
    /// Slots with φ > 0 (the support), for sparse propagation.
    active: Vec<u32>,
    next: Vec<u32>,
    /// Epoch stamps of the sparse step (see
    /// [`PropagationKernel::forward_sparse`]) and the current epoch.
    seen: Vec<u32>,
    epoch: u32,
    flush: Flush,
    /// Mass per binary exponent of the update's weights (flush cut), in
    /// two interleaved halves (even and odd positions of the support, so
    /// consecutive weights of one exponent do not chain their additions
    /// through memory); the bucket's mass is the sum of both.
    exp_hist: Box<[f64; 2 * EXP_BUCKETS]>,
    discarded_last: f64,
    discarded_total: f64,
    /// Σ over updates of the support after the update's flush, and the
    /// number of updates (for [`ChainFilter::mean_support`]).
    support_sum: u64,
    updates: u64,
}

impl<M: SdeModel> ChainFilter<M> {
    /// A filter on `chain` with δ ≤ `delta_max` (use the observation period
    /// so Δ/δ is an integer). The belief starts uniform over the chain's
    /// states at time 0; call [`BayesFilter::reset`] to set a prior.
    pub fn new(model: M, mut chain: Chain, delta_max: f64) -> Result<Self, ChainError> {
        let dims = model.dims();
        if chain.dim() != dims.state {
            return Err(ChainError::Dimension(chain.dim()));
        }
        let mut eq = TimeEqualized::new(delta_max)?;
        eq.fit(chain.holding());
        let view = chain.view();
        let kern = PropagationKernel::build(&view, eq.delta(), true);
        let n = chain.len();
        let mut u_last = [0.0; MAX_CONTROL];
        u_last[..dims.control].copy_from_slice(chain.reference_control());
        let mut f = Self {
            model,
            dims,
            chain,
            eq,
            kern,
            obs_mean: vec![],
            phi: vec![1.0 / n.max(1) as f64; n],
            tmp: vec![0.0; n],
            ll: vec![0.0; n],
            t: 0.0,
            u_last,
            tilt_probs: vec![],
            belief: Cell::new(None),
            prior: Gaussian::zeros(dims.state),
            steps: 0,
            active: {
                let mut a = Vec::with_capacity(n + 1);
                a.extend(0..n as u32);
                a
            },
            next: Vec::with_capacity(n + 1),
            seen: vec![0; n],
            epoch: 0,
            flush: Flush::Mass(FLUSH_MASS),
            exp_hist: Box::new([0.0; 2 * EXP_BUCKETS]),
            discarded_last: 0.0,
            discarded_total: 0.0,
            support_sum: 0,
            updates: 0,
        };
        f.refresh_obs_means(0);
        f.tilt_probs.resize(f.chain.nnz(), 0.0);
        Ok(f)
    }

    /// Build a chain of `n` states from `sampler` (batch, Alg. 2.1) and a
    /// filter on it.
    pub fn from_samples(
        model: M,
        cfg: crate::chain::ChainConfig,
        sampler: &Sampler,
        n: usize,
        delta_max: f64,
        rng: &mut SimRng,
    ) -> Result<Self, ChainError> {
        let chain = Chain::sample_batch(&model, cfg, sampler, n, rng)?;
        Self::new(model, chain, delta_max)
    }

    fn refresh_obs_means(&mut self, from: usize) {
        let m = self.dims.obs;
        let n = self.chain.len();
        self.obs_mean.resize(n * m, 0.0);
        for i in from..n {
            let (x, g) = (self.chain.state(i), &mut self.obs_mean[i * m..(i + 1) * m]);
            self.model.obs_mean(x, g);
        }
    }

    /// The chain.
    pub fn chain(&self) -> &Chain {
        &self.chain
    }
    /// The model.
    pub fn model(&self) -> &M {
        &self.model
    }
    /// The equalised time step δ.
    pub fn delta(&self) -> f64 {
        self.eq.delta()
    }
    /// The belief φ over the chain's slots.
    pub fn weights(&self) -> &[f64] {
        &self.phi
    }
    /// Overwrite φ (normalised here).
    pub fn set_weights(&mut self, w: &[f64]) {
        self.phi.copy_from_slice(w);
        normalise(&mut self.phi);
        self.rebuild_active();
        self.belief.set(None);
    }

    /// Zero every normalised mass below `flush` after each update (an
    /// absolute threshold: the discarded mass is then bounded only by
    /// `flush` × support). 0 keeps every non-zero mass. Ignored unless
    /// finite and ≥ 0.
    pub fn set_flush(&mut self, flush: f64) {
        if flush.is_finite() && flush >= 0.0 {
            self.flush = Flush::Below(flush);
        }
    }

    /// Zero the smallest masses after each update, at most `eps` of the
    /// normalised mass in total (the default, ε = [`FLUSH_MASS`]; see the
    /// module doc). Ignored unless 0 ≤ eps < 1.
    pub fn set_flush_mass(&mut self, eps: f64) {
        if (0.0..1.0).contains(&eps) {
            self.flush = Flush::Mass(eps);
        }
    }

    /// The flush rule in use.
    pub fn flush(&self) -> Flush {
        self.flush
    }

    /// Normalised mass the last update's flush discarded.
    pub fn last_discarded(&self) -> f64 {
        self.discarded_last
    }

    /// Sum of [`Self::last_discarded`] over every update since construction.
    pub fn discarded_total(&self) -> f64 {
        self.discarded_total
    }

    /// Number of states carrying mass.
    pub fn support(&self) -> usize {
        self.active.len()
    }

    /// Mean support after an update's flush over every update since
    /// construction (what the per-step cost scales with).
    pub fn mean_support(&self) -> f64 {
        self.support_sum as f64 / self.updates.max(1) as f64
    }

    fn rebuild_active(&mut self) {
        self.active.clear();
        // capacity n + 1: `active` and `next` swap in the sparse step
        self.active.reserve(self.phi.len() + 1);
        self.active.extend(
            self.phi
                .iter()
                .enumerate()
                .filter(|(_, w)| **w != 0.0)
                .map(|(i, _)| i as u32),
        );
        self.tmp.iter_mut().for_each(|v| *v = 0.0);
    }

    /// One (fraction of a) δ step, sparse over the support when it is
    /// small, dense otherwise. Keeps `tmp` all zero between calls.
    fn step(&mut self, theta: f64) {
        let n = self.phi.len();
        if self.active.len() * 4 < n {
            self.epoch = self.epoch.wrapping_add(1);
            if self.epoch == 0 {
                self.seen.fill(0);
                self.epoch = 1;
            }
            // consumes φ (all zero on return): `tmp` stays all zero
            self.kern.forward_sparse(
                theta,
                &mut self.phi,
                &self.active,
                &mut self.tmp,
                &mut self.next,
                &mut self.seen,
                self.epoch,
            );
            std::mem::swap(&mut self.phi, &mut self.tmp);
            std::mem::swap(&mut self.active, &mut self.next);
        } else {
            if theta >= 1.0 {
                self.kern.forward(&self.phi, &mut self.tmp);
            } else {
                self.kern.forward_fraction(theta, &self.phi, &mut self.tmp);
            }
            std::mem::swap(&mut self.phi, &mut self.tmp);
            self.rebuild_active();
        }
    }
    /// The propagation kernel P^δ currently in use.
    pub fn kernel(&self) -> &PropagationKernel {
        &self.kern
    }
    /// Number of δ sub-steps run so far.
    pub fn substeps(&self) -> u64 {
        self.steps
    }

    /// Grow the chain by `count` states from `sampler` while filtering
    /// (Alg. 2.3 with reconnection), give new states neighbour-averaged
    /// density, run exponential backup over every touched state, and
    /// install the new version (kernel, observation means, buffers).
    pub fn grow(
        &mut self,
        sampler: &Sampler,
        count: usize,
        rng: &mut SimRng,
    ) -> Result<GrowInfo, ChainError> {
        let n_old = self.chain.len();
        let d = self.dims.state;
        // densities of the old states
        let mut rho: Vec<f64> = (0..n_old)
            .map(|i| self.phi[i] / self.chain.cell_volume(i).max(1e-300))
            .collect();
        let mut touched = Vec::with_capacity(count * 16);
        self.chain
            .grow(&self.model, sampler, count, rng, &mut touched)?;
        let n = self.chain.len();
        let mut near = Vec::new();
        for i in n_old..n {
            let x: [f64; MAX_STATE] = {
                let mut a = [0.0; MAX_STATE];
                a[..d].copy_from_slice(self.chain.state(i));
                a
            };
            let k = self.chain.near_count()[i].max(1) as usize;
            self.chain.nearest(&x[..d], k + 1, &mut near);
            let (mut s, mut c) = (0.0, 0usize);
            for &(j, _) in &near {
                if (j as usize) < i {
                    s += rho[j as usize];
                    c += 1;
                }
            }
            rho.push(if c > 0 { s / c as f64 } else { 0.0 });
        }
        self.phi.resize(n, 0.0);
        for i in 0..n {
            self.phi[i] = rho[i] * self.chain.cell_volume(i);
        }
        if !normalise(&mut self.phi) {
            self.phi.fill(1.0 / n as f64);
        }
        let halved = self.eq.backup(self.chain.holding(), &touched);
        self.install();
        self.refresh_obs_means(n_old);
        Ok(GrowInfo {
            added: n - n_old,
            reconnected: touched.len().saturating_sub(n - n_old),
            delta_halved: halved,
            delta: self.eq.delta(),
        })
    }

    /// Rebuild P^δ and size every buffer for the current chain.
    fn install(&mut self) {
        let n = self.chain.len();
        let delta = self.eq.delta();
        let view = self.chain.view();
        self.kern.rebuild(&view, delta, true);
        self.tmp.resize(n, 0.0);
        self.seen.resize(n, 0);
        // scratch of the sparse step (capacity n + 1, see forward_sparse)
        self.next.clear();
        self.next.reserve(n + 1);
        self.rebuild_active();
        self.ll.resize(n, 0.0);
        self.tilt_probs.resize(self.chain.nnz(), 0.0);
        // force re-tilting on the next predict
        self.u_last[..self.dims.control].copy_from_slice(self.chain.reference_control());
        self.belief.set(None);
    }

    /// Tilt the kernel for control u (see module doc).
    fn apply_control(&mut self, u: &[f64]) {
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

    /// The update's weighting pass over the support: `ll[j]` ← w =
    /// φ(z) exp(l(z) − shift), with the mass histogram of the weights'
    /// exponents when the flush is mass-bounded.
    fn weigh(&mut self, y: &[f64], lik: &ObsTerms, shift: f64) -> Weighed {
        let m = self.dims.obs;
        let mass_rule = matches!(self.flush, Flush::Mass(_));
        let mut r = [0.0; MAX_OBS];
        let mut out = Weighed {
            sum: 0.0,
            wmax: 0.0,
            lmax: f64::NEG_INFINITY,
            lo: EXP_BUCKETS,
            hi: 0,
        };
        for (j, &zi) in self.active.iter().enumerate() {
            let z = zi as usize;
            let g = &self.obs_mean[z * m..(z + 1) * m];
            self.model.obs_residual(y, g, &mut r[..m]);
            let mut q = 0.0;
            for k in 0..lik.nm {
                let ri = r[lik.idx[k]];
                q += ri * ri * lik.inv_var[k];
            }
            let l = -0.5 * q;
            out.lmax = out.lmax.max(l);
            let a = l - shift;
            // exp(−700) ≈ 1e-304: below that the result is zero or subnormal.
            let w = if a > -700.0 {
                self.phi[z] * a.exp()
            } else {
                0.0
            };
            self.ll[j] = w;
            out.sum += w;
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

    fn moments(&self) -> Gaussian {
        let d = self.dims.state;
        // Offsets from the prior mean, for numerical stability.
        let mut acc = WeightedMoments::new(&self.prior.mean[..d]);
        for &zi in &self.active {
            let i = zi as usize;
            let w = self.phi[i];
            if w != 0.0 {
                acc.add(w, self.chain.state(i));
            }
        }
        acc.gaussian()
    }
}

/// The prior N(mean, cov) as a mass function on the chain's states:
/// φ(z) ∝ N(z; mean, cov) · vol(z) (see the module doc). A singular
/// covariance puts all mass on the state nearest the mean. `scratch` has
/// the length of `out` (= chain.len()).
pub fn prior_weights(chain: &Chain, prior: &Gaussian, out: &mut [f64], scratch: &mut [f64]) {
    let d = chain.dim();
    let n = chain.len();
    let mut l = [0.0; MAX_STATE * MAX_STATE];
    l[..d * d].copy_from_slice(prior.cov());
    if !cholesky(&mut l[..d * d], d) {
        let mut near = Vec::with_capacity(1);
        chain.nearest(prior.mean(), 1, &mut near);
        out.fill(0.0);
        if let Some(&(j, _)) = near.first() {
            out[j as usize] = 1.0;
        }
        return;
    }
    let mut lmax = f64::NEG_INFINITY;
    for i in 0..n {
        let z = chain.state(i);
        let mut y = [0.0; MAX_STATE];
        for a in 0..d {
            y[a] = z[a] - prior.mean[a];
        }
        forward_sub(&l[..d * d], d, &mut y[..d]);
        let q: f64 = y[..d].iter().map(|v| v * v).sum();
        let lw = -0.5 * q + chain.cell_volume(i).max(1e-300).ln();
        scratch[i] = lw;
        lmax = lmax.max(lw);
    }
    for i in 0..n {
        out[i] = (scratch[i] - lmax).exp();
    }
    normalise(out);
}

/// log p(y | z) up to the constant Σ(−log σ_i − ½ log 2π), for every state
/// from its precomputed observation mean (`obs_mean`, n × m), into `out`.
/// Returns the maximum.
pub fn log_likelihoods<M: SdeModel>(
    model: &M,
    obs_mean: &[f64],
    meas: &Measurement,
    out: &mut [f64],
) -> f64 {
    let m = model.dims().obs;
    let mut std = [0.0; MAX_OBS];
    match meas.std {
        Some(s) => std[..m].copy_from_slice(&s[..m]),
        None => model.obs_std(&mut std[..m]),
    }
    let mut idx = [0usize; MAX_OBS];
    let mut inv_var = [0.0; MAX_OBS];
    let mut nm = 0;
    for i in meas.mask.iter().take_while(|&i| i < m) {
        idx[nm] = i;
        inv_var[nm] = 1.0 / (std[i] * std[i]);
        nm += 1;
    }
    let mut r = [0.0; MAX_OBS];
    let mut lmax = f64::NEG_INFINITY;
    for (z, o) in out.iter_mut().enumerate() {
        model.obs_residual(&meas.y[..m], &obs_mean[z * m..(z + 1) * m], &mut r[..m]);
        let mut q = 0.0;
        for j in 0..nm {
            let ri = r[idx[j]];
            q += ri * ri * inv_var[j];
        }
        *o = -0.5 * q;
        lmax = lmax.max(*o);
    }
    lmax
}

/// Observation means g(z) of every state, n × m.
pub fn observation_means<M: SdeModel>(model: &M, states: &[f64], d: usize) -> Vec<f64> {
    let m = model.dims().obs;
    let n = states.len() / d;
    let mut g = vec![0.0; n * m];
    for i in 0..n {
        model.obs_mean(&states[i * d..(i + 1) * d], &mut g[i * m..(i + 1) * m]);
    }
    g
}

/// Normalise to sum 1; false if the sum is not positive and finite.
pub(crate) fn normalise(w: &mut [f64]) -> bool {
    let s: f64 = w.iter().sum();
    if !(s > 0.0 && s.is_finite()) {
        return false;
    }
    let inv = 1.0 / s;
    for v in w.iter_mut() {
        *v *= inv;
    }
    true
}

impl<M: SdeModel> BayesFilter for ChainFilter<M> {
    fn name(&self) -> &'static str {
        "chain"
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.t
    }

    fn reset(&mut self, t: f64, prior: &Gaussian) {
        self.t = t;
        self.prior = *prior;
        prior_weights(&self.chain, prior, &mut self.phi, &mut self.tmp);
        self.rebuild_active();
        self.belief.set(None);
    }

    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        check_predict(self.t, t, u, self.dims)?;
        let dt = t - self.t;
        if dt == 0.0 {
            return Ok(());
        }
        self.apply_control(u);
        let (whole, frac) = self.eq.steps(dt);
        for _ in 0..whole {
            self.step(1.0);
        }
        if frac > 0.0 {
            self.step(frac);
        }
        self.steps += whole as u64 + (frac > 0.0) as u64;
        self.t = t;
        self.belief.set(None);
        Ok(())
    }

    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        let m = self.dims.obs;
        let mut std = [0.0; MAX_OBS];
        match meas.std {
            Some(s) => std[..m].copy_from_slice(&s[..m]),
            None => self.model.obs_std(&mut std[..m]),
        }
        // The mask as a short index list (ObsMask::iter scans 32 bits).
        let mut lik = ObsTerms {
            idx: [0usize; MAX_OBS],
            inv_var: [0.0; MAX_OBS],
            nm: 0,
        };
        let mut cst = 0.0;
        for i in meas.mask.iter().take_while(|&i| i < m) {
            lik.idx[lik.nm] = i;
            lik.inv_var[lik.nm] = 1.0 / (std[i] * std[i]);
            lik.nm += 1;
            cst -= std[i].ln() + HALF_LOG_2PI;
        }
        let y = &meas.y[..m];
        // One pass: w = φ(z) exp(l(z)) with l = −q/2 ≤ 0, so exp(l) ≤ 1 and
        // no max-shift is needed unless every likelihood underflows (then
        // the max-shifted pass below). ll is indexed by position in
        // `active` (contiguous, not by slot).
        let mut shift = 0.0;
        let mut w = self.weigh(y, &lik, shift);
        if !(w.sum > MIN_UNSHIFTED_SUM && w.sum.is_finite()) {
            if !w.lmax.is_finite() {
                return Err(FilterError::Degenerate);
            }
            self.clear_hist(&w);
            shift = w.lmax;
            w = self.weigh(y, &lik, shift);
        }
        let sum = w.sum;
        if !(sum > 0.0 && sum.is_finite()) {
            self.clear_hist(&w);
            return Err(FilterError::Degenerate);
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

    fn belief(&self) -> Gaussian {
        if let Some(g) = self.belief.get() {
            return g;
        }
        let g = self.moments();
        self.belief.set(Some(g));
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chain::ChainConfig;
    use crate::filter::kalman::Kalman;
    use crate::model::linear::LinearSde;
    use crate::model::{simulate_observation, Bounds};
    use nalgebra::DMatrix;

    fn ou2() -> LinearSde {
        // dx = A x dt + F dw, y = x + v, σ = 0.2 each.
        LinearSde::new(
            "ou2",
            DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.5, -1.0]),
            DMatrix::zeros(2, 0),
            DMatrix::from_row_slice(2, 2, &[0.5, 0.0, 0.0, 0.5]),
            DMatrix::identity(2, 2),
            vec![0.2, 0.2],
            Bounds::new_box(&[-2.5, -2.5], &[2.5, 2.5]).unwrap(),
        )
    }

    /// RMS over steps of (mean error, cov error) of the chain filter against
    /// the exact Kalman filter on the same observation record.
    fn gap_to_kalman(n: usize, seed: u64) -> (f64, f64) {
        gap_to_kalman_with(n, seed, ChainConfig::moment_matched(2))
    }

    fn gap_to_kalman_with(n: usize, seed: u64, cfg: ChainConfig) -> (f64, f64) {
        let model = ou2();
        let dt = 0.05;
        let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
        let mut rng = crate::rng::stream(seed, 0);
        let mut kf = Kalman::new(model.clone(), &prior, 0.0).unwrap();
        let mut cf = ChainFilter::from_samples(
            model.clone(),
            cfg,
            &Sampler::Uniform,
            n,
            dt,
            &mut crate::rng::stream(seed, 1),
        )
        .unwrap();
        cf.reset(0.0, &prior);
        let mut x = [0.8, -0.4];
        let (mut em, mut ec) = (0.0, 0.0);
        let steps = 40;
        for k in 1..=steps {
            let t = k as f64 * dt;
            crate::model::discrete::em_integrate(&model, &mut x, &[], dt, 1e-3, &mut rng);
            let mut y = [0.0; 2];
            simulate_observation(&model, &x, &mut rng, &mut y);
            for f in [&mut kf as &mut dyn BayesFilter, &mut cf] {
                f.predict(t, &[]).unwrap();
                f.update(&Measurement::full(&y)).unwrap();
            }
            let (a, b) = (kf.belief(), cf.belief());
            em += (0..2).map(|i| (a.mean[i] - b.mean[i]).powi(2)).sum::<f64>();
            ec += (0..4).map(|i| (a.cov[i] - b.cov[i]).powi(2)).sum::<f64>();
        }
        ((em / steps as f64).sqrt(), (ec / steps as f64).sqrt())
    }

    #[test]
    fn control_tilt_follows_the_controlled_kalman_answer() {
        // dx = (−x + u) dt + 0.5 dw, y = x + 0.2 v; chain built for u₀ = 0,
        // filtered with u = 1.5 held: the tilted kernel must carry the
        // control's drift (the uncontrolled answer is ≈ 1.5 away).
        let model = LinearSde::new(
            "ctl",
            DMatrix::from_element(1, 1, -1.0),
            DMatrix::from_element(1, 1, 1.0),
            DMatrix::from_element(1, 1, 0.5),
            DMatrix::from_element(1, 1, 1.0),
            vec![0.5],
            Bounds::new_box(&[-4.0], &[4.0]).unwrap(),
        );
        let dt = 0.05;
        let prior = Gaussian::diagonal(&[0.0], &[0.3]);
        let mut cf = ChainFilter::from_samples(
            model.clone(),
            ChainConfig::moment_matched(1),
            &Sampler::Uniform,
            1500,
            dt,
            &mut crate::rng::stream(3, 1),
        )
        .unwrap();
        cf.reset(0.0, &prior);
        let mut kf = Kalman::new(model.clone(), &prior, 0.0).unwrap();
        let mut k0 = Kalman::new(model.clone(), &prior, 0.0).unwrap();
        let mut rng = crate::rng::stream(3, 0);
        let mut x = [0.0];
        let u = [1.5];
        let (mut gap, mut gap0) = (0.0f64, 0.0f64);
        for k in 1..=60 {
            let t = k as f64 * dt;
            crate::model::discrete::em_integrate(&model, &mut x, &u, dt, 1e-3, &mut rng);
            let mut y = [0.0];
            simulate_observation(&model, &x, &mut rng, &mut y);
            cf.predict(t, &u).unwrap();
            kf.predict(t, &u).unwrap();
            k0.predict(t, &[0.0]).unwrap();
            for f in [&mut cf as &mut dyn BayesFilter, &mut kf, &mut k0] {
                f.update(&Measurement::full(&y)).unwrap();
            }
            gap = gap.max((cf.belief().mean[0] - kf.belief().mean[0]).abs());
            gap0 = gap0.max((k0.belief().mean[0] - kf.belief().mean[0]).abs());
        }
        eprintln!("tilted chain vs Kalman {gap:.4}, uncontrolled Kalman vs Kalman {gap0:.4}");
        assert!(gap0 > 0.2, "control must matter: {gap0}");
        assert!(
            gap < 0.25 * gap0,
            "tilted chain vs Kalman: {gap} (uncontrolled {gap0})"
        );
        // back to u₀: the untilted kernel is restored
        cf.predict(3.1, &[0.0]).unwrap();
    }

    #[test]
    fn flush_discards_at_most_eps_and_moves_the_mean_within_its_bound() {
        // Two filters on the same chain and observations: `full` keeps
        // every mass, `cut` the default mass-bounded flush. Before each
        // update `cut` gets `full`'s predicted φ, so each update is compared
        // on the same input: the discarded mass D must be ≤ ε, and the mean
        // may move by at most 2D·max_z‖z − x̂‖ (total variation D).
        let model = ou2();
        let dt = 0.05;
        let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
        let make = || {
            ChainFilter::from_samples(
                model.clone(),
                ChainConfig::moment_matched(2),
                &Sampler::Uniform,
                3000,
                dt,
                &mut crate::rng::stream(21, 1),
            )
            .unwrap()
        };
        let (mut full, mut cut) = (make(), make());
        assert_eq!(cut.flush(), Flush::Mass(FLUSH_MASS));
        full.set_flush(0.0);
        full.reset(0.0, &prior);
        let mut rng = crate::rng::stream(21, 0);
        let mut x = [0.8, -0.4];
        let (mut acted, mut total) = (0, 0.0);
        for k in 1..=40 {
            let t = k as f64 * dt;
            crate::model::discrete::em_integrate(&model, &mut x, &[], dt, 1e-3, &mut rng);
            let mut y = [0.0; 2];
            simulate_observation(&model, &x, &mut rng, &mut y);
            full.predict(t, &[]).unwrap();
            cut.set_weights(full.weights());
            cut.t = t;
            let support_before = cut.support();
            full.update(&Measurement::full(&y)).unwrap();
            cut.update(&Measurement::full(&y)).unwrap();
            let dm = cut.last_discarded();
            assert!(dm <= FLUSH_MASS * (1.0 + 1e-9), "step {k}: dropped {dm}");
            let kept: f64 = cut.weights().iter().sum();
            assert!((kept - (1.0 - dm)).abs() < 1e-12, "{kept} vs 1 − {dm}");
            let (a, b) = (full.belief(), cut.belief());
            let radius = (0..cut.chain().len())
                .map(|i| {
                    let z = cut.chain().state(i);
                    ((z[0] - a.mean[0]).powi(2) + (z[1] - a.mean[1]).powi(2)).sqrt()
                })
                .fold(0.0, f64::max);
            let gap = ((a.mean[0] - b.mean[0]).powi(2) + (a.mean[1] - b.mean[1]).powi(2)).sqrt();
            assert!(
                gap <= 2.0 * dm * radius * (1.0 + 1e-6) + 1e-15,
                "step {k}: mean moved {gap}, bound {}",
                2.0 * dm * radius
            );
            if dm > 0.0 && cut.support() < support_before {
                acted += 1;
            }
            total += dm;
        }
        // the flush does act: it removes states in (nearly) every update
        assert!(acted >= 30, "flush acted in {acted} of 40 updates");
        assert!((cut.discarded_total() - total).abs() < 1e-18);
        assert!(
            cut.support() < full.support() / 2,
            "{} vs {}",
            cut.support(),
            full.support()
        );
    }

    #[test]
    fn update_belief_and_evidence_match_direct_sums() {
        // The fused update (unshifted weights, and the max-shifted pass when
        // every likelihood underflows) against direct sums over the slots:
        // the cached belief equals `moments` bit for bit, and the log
        // evidence equals log Σ_z φ⁻(z) N(y; g(z), σ²I) by log-sum-exp.
        let model = ou2();
        let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
        let make = || {
            ChainFilter::from_samples(
                model.clone(),
                ChainConfig::moment_matched(2),
                &Sampler::Uniform,
                2000,
                0.05,
                &mut crate::rng::stream(5, 1),
            )
            .unwrap()
        };
        let mut cf = make();
        cf.set_flush(0.0);
        cf.reset(0.0, &prior);
        // the same updates under the default mass-bounded flush
        let mut cm = make();
        cm.reset(0.0, &prior);
        // y near the prior, then y ≈ 60σ away (every exp(l) underflows)
        for (k, y) in [[0.7, -0.3], [0.9, -0.5], [12.0, -12.0]].iter().enumerate() {
            cf.predict(0.05 * (k + 1) as f64, &[]).unwrap();
            let phi = cf.weights().to_vec();
            let mut lse = f64::NEG_INFINITY;
            let mut terms = vec![];
            for (i, &p) in phi.iter().enumerate() {
                if p > 0.0 {
                    let z = cf.chain().state(i);
                    let q: f64 = (0..2).map(|a| ((y[a] - z[a]) / 0.2).powi(2)).sum();
                    let l = p.ln() - 0.5 * q - 2.0 * (0.2f64.ln() + HALF_LOG_2PI);
                    terms.push(l);
                    lse = lse.max(l);
                }
            }
            let direct = lse + terms.iter().map(|t| (t - lse).exp()).sum::<f64>().ln();
            cm.set_weights(&phi);
            cm.t = cf.t;
            let im = cm.update(&Measurement::full(y)).unwrap();
            assert!((im.log_evidence - direct).abs() < 1e-9 * direct.abs().max(1.0));
            assert!(cm.last_discarded() <= FLUSH_MASS * (1.0 + 1e-9));
            let info = cf.update(&Measurement::full(y)).unwrap();
            assert!(
                (info.log_evidence - direct).abs() < 1e-9 * direct.abs().max(1.0),
                "step {k}: {} vs {direct}",
                info.log_evidence
            );
            let (cached, fresh) = (cf.belief(), cf.moments());
            assert_eq!(cached.mean, fresh.mean, "step {k}");
            assert_eq!(cached.cov, fresh.cov, "step {k}");
        }
    }

    #[test]
    fn sparse_prediction_equals_the_dense_map() {
        // Once the flush has shrunk the support below n/4, predict runs the
        // sparse push over the support; it must give what the dense
        // gather (P^δ)ᵀ applied Δ/δ times gives to the same φ, for the
        // thesis chain (several δ steps per Δ) and the advected chain (one).
        let model = ou2();
        let dt = 0.05;
        let prior = Gaussian::diagonal(&[0.8, -0.4], &[0.3, 0.3]);
        for cfg in [
            ChainConfig::moment_matched(2),
            ChainConfig::moment_matched(2).with_step(dt),
        ] {
            let mut cf = ChainFilter::from_samples(
                model.clone(),
                cfg,
                &Sampler::Uniform,
                4000,
                dt,
                &mut crate::rng::stream(8, 1),
            )
            .unwrap();
            cf.set_flush_mass(1e-6);
            cf.reset(0.0, &prior);
            let n = cf.chain().len();
            let mut sparse_steps = 0;
            for (k, y) in [[0.8, -0.4], [0.7, -0.3], [0.75, -0.35], [0.6, -0.3]]
                .iter()
                .enumerate()
            {
                cf.update(&Measurement::full(y)).unwrap();
                let before = cf.weights().to_vec();
                let support = cf.support();
                assert_eq!(
                    support,
                    before.iter().filter(|&&w| w != 0.0).count(),
                    "support lists exactly the slots with mass"
                );
                let t = dt * (k + 1) as f64;
                let steps0 = cf.substeps();
                cf.predict(t, &[]).unwrap();
                let steps = (cf.substeps() - steps0) as usize;
                assert!(steps >= 1);
                let mut dense = before.clone();
                let mut tmp = vec![0.0; n];
                for _ in 0..steps {
                    cf.kernel().forward(&dense, &mut tmp);
                    std::mem::swap(&mut dense, &mut tmp);
                }
                let got = cf.weights();
                for z in 0..n {
                    assert!(
                        // rounding only: the two sum in different orders
                        (got[z] - dense[z]).abs() <= 1e-15 * steps as f64,
                        "slot {z}: {} vs {}",
                        got[z],
                        dense[z]
                    );
                }
                assert_eq!(
                    cf.support(),
                    got.iter().filter(|&&w| w != 0.0).count(),
                    "support after predict"
                );
                if support * 4 < n {
                    sparse_steps += 1;
                }
            }
            assert!(sparse_steps >= 3, "sparse path ran {sparse_steps} times");
        }
    }

    #[test]
    fn converges_to_kalman_as_n_grows() {
        let mut last = (f64::INFINITY, f64::INFINITY);
        for n in [300usize, 3000, 30000] {
            // average over 3 seeds to keep the comparison about n, not luck
            let mut g = (0.0, 0.0);
            for s in 0..3 {
                let e = gap_to_kalman(n, 10 + s);
                g.0 += e.0 / 3.0;
                g.1 += e.1 / 3.0;
            }
            eprintln!("n={n}: mean gap {:.4}, cov gap {:.5}", g.0, g.1);
            assert!(g.0 < last.0 && g.1 < last.1, "n={n}: {g:?} vs {last:?}");
            last = g;
        }
        // At 30,000 states the posterior mean is within a few percent of the
        // posterior std (≈ 0.13) of the exact answer.
        assert!(last.0 < 0.02, "{last:?}");
    }

    #[test]
    fn advected_chain_filter_converges_to_kalman_as_n_grows() {
        // The advected construction (Δt = δ = τ = the observation period):
        // same Kalman–Bucy check as above.
        let mut last = (f64::INFINITY, f64::INFINITY);
        for n in [300usize, 3000, 30000] {
            let mut g = (0.0, 0.0);
            for s in 0..3 {
                let cfg = ChainConfig::moment_matched(2).with_step(0.05);
                let e = gap_to_kalman_with(n, 10 + s, cfg);
                g.0 += e.0 / 3.0;
                g.1 += e.1 / 3.0;
            }
            eprintln!("advected n={n}: mean gap {:.4}, cov gap {:.5}", g.0, g.1);
            assert!(g.0 < last.0 && g.1 < last.1, "n={n}: {g:?} vs {last:?}");
            last = g;
        }
        assert!(last.0 < 0.02, "{last:?}");
    }
}
