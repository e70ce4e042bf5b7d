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
//!   uses the untilted kernel. Where FFᵀ is singular on noise-free
//!   coordinates the tilt acts on the noisy block ([`control`]); states
//!   where it cannot act are counted ([`ChainFilter::control_unapplied`]).
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
//!
//! Layout: [`grow`] (states added while filtering), [`control`] (the
//! kernel's tilt), [`update`] (weighting pass, flush, moments),
//! [`weights`] (prior on the chain and the likelihood helpers the smoother
//! and decoders share); the likelihood and Gaussian terms of one state are
//! [`crate::filter::live_chain::mass`]'s, shared with the live filter.

use std::cell::Cell;

use crate::belief::{Gaussian, WeightedMoments};
use crate::chain::{Chain, ChainError, PropagationKernel, Sampler, TimeEqualized};
use crate::filter::{check_predict, BayesFilter, FilterError, UpdateInfo};
use crate::model::{Dims, Measurement, SdeModel};
use crate::rng::SimRng;
use crate::MAX_CONTROL;

mod control;
mod grow;
pub mod recentred;
pub mod recentred_spec;
mod update;
mod weights;

use update::EXP_BUCKETS;

pub(crate) use weights::normalise;
pub use weights::{log_likelihoods, observation_means, prior_weights};

/// Default bound ε on the posterior mass an update's flush discards (see
/// the module doc).
pub const FLUSH_MASS: f64 = 1e-9;

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
    /// Updates that collapsed (refused, or kept less than
    /// `collapse_fraction` of the effective support; see
    /// [`crate::filter::regularise`]).
    collapses: u64,
    collapse_fraction: f64,
    /// Rows left untilted under a control ≠ u₀ (see [`control`]).
    control_unapplied: u64,
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
            collapses: 0,
            collapse_fraction: crate::filter::regularise::DEFAULT_COLLAPSE_FRACTION,
            control_unapplied: 0,
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

    /// Rows whose control tilt could not be applied, summed over control
    /// changes (0 when every row follows the control; see [`control`]).
    pub fn control_unapplied(&self) -> u64 {
        self.control_unapplied
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

    /// Updates that collapsed since construction: refused (no state with
    /// mass explains y), or kept less than the collapse fraction of the
    /// predicted mass's effective support, ρ = (Σφp)²/(Σφ·Σφp²)
    /// (see [`crate::filter::regularise`]).
    pub fn collapses(&self) -> u64 {
        self.collapses
    }

    /// The collapse fraction f (default 0.01; clamped to [0, 1]).
    pub fn set_collapse_fraction(&mut self, f: f64) {
        self.collapse_fraction = if f.is_finite() {
            f.clamp(0.0, 1.0)
        } else {
            0.0
        };
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
        self.update_step(meas)
    }

    fn belief(&self) -> Gaussian {
        if let Some(g) = self.belief.get() {
            return g;
        }
        let g = self.moments();
        self.belief.set(Some(g));
        g
    }

    fn ess_collapses(&self) -> Option<u64> {
        Some(self.collapses)
    }
}

#[cfg(test)]
mod recentred_tests;
#[cfg(test)]
mod tests;
