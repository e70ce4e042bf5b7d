//! A continuous-time partially observed control problem turned into a
//! discrete POMDP on a Markov chain (thesis 000 §4.5, Alg. 4.2–4.4):
//!
//! ```text
//! dx = f(x, u) dt + F(x) dw,   y = g(x) + noise,   J = E Σ_k γ^k R(x_k, u_k)
//! S = the chain's states, U = sampled controls, O = sampled observation points
//! Δt(z, u) = r(z)² / (κ_F ‖FFᵀ(z)‖₂ + κ_f r(z) ‖f(z, u)‖₂)          (ComputeHoldingTime)
//! p_u(z_k | z) ∝ N(z_k − z; f(z,u) Δt(z,u), FFᵀ Δt(z,u)),  z_k ∈ Near(z) (ComputeTransProb)
//! p^δ_u(z | z) = 1 − δ/Δt(z,u),  p^δ_u(z_k | z) = δ/Δt(z,u) p_u(z_k | z) (eq. 3.8–3.9)
//! T(·|z, u) = (P^δ_u)^K,  h = K δ,   δ = min_{z,u} Δt(z,u) or δ_max/2^j below it
//! Q(o_j | z) ∝ p(y = o_j | z)  normalised over the sampled points     (ComputeObsProb)
//! R(z, u) = −l(z, u) h,   γ = exp(−ρ h)
//! ```
//!
//! The Near sets, radii and F Fᵀ are the chain's own (built with the
//! Gaussian kernel for the reference control u₀), so for u = u₀ the rows of
//! P^δ_u are exactly the chain filter's p^δ: the belief update
//! ([`ChainPomdp::update`]) with a continuous observation is then the chain
//! filter's predict and update.
//!
//! Choices where the thesis is silent or where we depart from it:
//! - **decision period** h = Kδ, K the smallest power of two with
//!   Kδ ≥ `decision_min`: the thesis decides every Δt_n, which for a few
//!   hundred states is milliseconds and makes the discounted horizon
//!   thousands of steps long; holding the control for K chain steps keeps
//!   the chain's resolution and bounds the horizon (K = 1 recovers the
//!   thesis). `row_flush` drops the far tails of (P^δ)^K.
//! - **discount** γ = exp(−ρh): the same physical discount at every
//!   refinement (notes §2, γ_n = e^{−cΔt_n}); the LQG penalty e^{−2αt} is
//!   ρ = 2α, and γ ≈ 1 − 2αh is the thesis's α ≈ (1 − γ)/(2Δt).
//! - **terminal action** (light-dark's u_goal): an extra action into an
//!   absorbing state with reward `Terminal::reward(z)`.
//!
//! Layout: [`rows`] (holding times, kernels, the K-step rows),
//! [`rows_moment`] (the alternative [`Rows::Moment`]: one row per decision
//! period with the SDE's mean over h exactly and its covariance as closely
//! as the states allow; [`lp`] its linear programs), [`warm`]
//! (carrying a solution to a refined chain), [`cliff`] (the box's edge
//! as a cliff that ends the episode instead of a wall). Alg. 4.4's growth — the chain
//! refined incrementally (Alg. 2.3), U and O grown to ⌊c ln n⌋ points
//! ([`log_count`]) — is the caller's loop; each refined POMDP is rebuilt
//! here and solved from the carried solution.

pub mod cliff;
pub mod lp;
pub mod rows;
pub mod rows_moment;
pub mod warm;

use crate::model::{ModelError, Pomdp, SparseRows};
use beliefbus_core::chain::{Chain, KernelKind};
use beliefbus_core::model::SdeModel;
use thiserror::Error;

/// p(y | z) of the observation model, up to a z-independent factor.
pub trait ObservationModel {
    /// Log-likelihood of observation `y` at state `z` (constants that do
    /// not depend on z may be dropped).
    fn log_likelihood(&self, z: &[f64], y: &[f64]) -> f64;
}

/// The model's own sampled observation y = g(z) + v, v ~ N(0, diag σ²),
/// with σ given (the chain filter's likelihood for a measurement of that
/// σ).
pub struct GaussianObservation<'a, M: SdeModel> {
    pub model: &'a M,
    pub std: Vec<f64>,
}

impl<M: SdeModel> ObservationModel for GaussianObservation<'_, M> {
    fn log_likelihood(&self, z: &[f64], y: &[f64]) -> f64 {
        let m = self.std.len();
        let mut g = [0.0; beliefbus_core::MAX_OBS];
        let mut r = [0.0; beliefbus_core::MAX_OBS];
        self.model.obs_mean(z, &mut g[..m]);
        self.model.obs_residual(y, &g[..m], &mut r[..m]);
        -0.5 * (0..m).map(|k| (r[k] / self.std[k]).powi(2)).sum::<f64>()
    }
}

/// The terminal ("declare") action: reward per chain state, then the
/// episode ends in an absorbing state.
#[derive(Clone, Debug)]
pub struct Terminal {
    pub reward: Vec<f64>,
}

/// Settings of [`build`].
#[derive(Clone, Debug)]
pub struct ChainPomdpSpec {
    /// The sampled controls U (each of the model's control dimension).
    pub controls: Vec<Vec<f64>>,
    /// The sampled observation points O (each of the observation dimension).
    pub observations: Vec<Vec<f64>>,
    /// Upper bound δ_max of the chain step (δ = δ_max/2^j); infinite:
    /// δ = min_{z,u} Δt(z,u) exactly (the thesis's Δt_n).
    pub delta_max: f64,
    /// The decision period h = Kδ is the first power-of-two multiple of δ
    /// at or above this (0: K = 1, the thesis).
    pub decision_min: f64,
    /// ρ in γ = exp(−ρh), per second.
    pub discount_rate: f64,
    /// b₀ over the chain's states.
    pub start: Vec<f64>,
    /// Drop entries of a K-step row below this probability.
    pub row_flush: f64,
    /// Drop Q(o|z) below this fraction of the row's largest entry.
    pub obs_flush: f64,
    /// Make every row consistent in the mean, E[Δξ] = f Δt ([`rows`]
    /// module doc: one-sided Near sets repaired, weights tilted); false
    /// keeps the chain's Near sets and Gaussian weights, so that u₀'s rows
    /// are the chain filter's.
    pub match_mean: bool,
    pub terminal: Option<Terminal>,
}

/// Why a chain POMDP could not be built.
#[derive(Debug, Error, PartialEq)]
pub enum ChainPomdpError {
    #[error("chain POMDP: {0}")]
    Spec(String),
    #[error("chain POMDP: the chain must use the Gaussian kernel without a fixed step (per-control kernels are rebuilt from its Near sets)")]
    ChainKind,
    #[error(transparent)]
    Model(#[from] ModelError),
}

/// A POMDP built on a chain, with what is needed to map it back.
#[derive(Clone, Debug)]
pub struct ChainPomdp {
    pub pomdp: Pomdp,
    /// Chain step δ and decision period h = Kδ.
    pub delta: f64,
    pub steps: usize,
    pub period: f64,
    /// Chain states (flat n × d); a terminal problem adds one absorbing
    /// state after them.
    pub states: Vec<f64>,
    pub dim: usize,
    /// Action a is `controls[a − offset]`; action 0 is the terminal action
    /// when there is one (offset 1), so actions keep their indices when
    /// controls are appended.
    pub controls: Vec<Vec<f64>>,
    pub offset: usize,
    pub observations: Vec<Vec<f64>>,
}

impl ChainPomdp {
    /// Chain states (without the absorbing one).
    pub fn n_chain(&self) -> usize {
        self.states.len() / self.dim
    }

    /// State `i`'s coordinates.
    pub fn state(&self, i: usize) -> &[f64] {
        &self.states[i * self.dim..(i + 1) * self.dim]
    }

    /// The control of action `a` (`None` for the terminal action).
    pub fn control(&self, a: usize) -> Option<&[f64]> {
        a.checked_sub(self.offset)
            .map(|c| self.controls[c].as_slice())
    }

    /// Bayes update of a dense belief with action `a` and a continuous
    /// observation `y`: `out(z') ∝ p(y|z') Σ_z b(z) T(z'|z,a)` — the chain
    /// filter's predict-then-update over one decision period.
    /// Returns false (and leaves the prediction in `out`) when every
    /// likelihood underflows.
    pub fn update(
        &self,
        b: &[f64],
        a: usize,
        y: &[f64],
        obs: &dyn ObservationModel,
        out: &mut [f64],
    ) -> bool {
        self.predict(b, a, out);
        let n = self.n_chain();
        let mut lmax = f64::NEG_INFINITY;
        let mut ll = vec![f64::NEG_INFINITY; out.len()];
        for z in 0..n {
            if out[z] > 0.0 {
                ll[z] = obs.log_likelihood(self.state(z), y);
                lmax = lmax.max(ll[z]);
            }
        }
        let mut total = 0.0;
        let mut post = vec![0.0; out.len()];
        for z in 0..n {
            if out[z] > 0.0 {
                post[z] = out[z] * (ll[z] - lmax).exp();
                total += post[z];
            }
        }
        if !(total > 0.0 && total.is_finite()) {
            return false;
        }
        for (o, p) in out.iter_mut().zip(&post) {
            *o = p / total;
        }
        true
    }

    /// `out(z') = Σ_z b(z) T(z'|z,a)`.
    pub fn predict(&self, b: &[f64], a: usize, out: &mut [f64]) {
        out.fill(0.0);
        let t = &self.pomdp.trans[a];
        for (z, &bz) in b.iter().enumerate() {
            if bz == 0.0 {
                continue;
            }
            let (cols, vals) = t.row(z);
            for (&j, &p) in cols.iter().zip(vals) {
                out[j as usize] += bz * p;
            }
        }
    }
}

/// How the transition rows over a decision period are made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Rows {
    /// The thesis's: the K-th power of the chain's equalised kernel rows
    /// (module doc).
    #[default]
    Kernel,
    /// One row per period h with mean exactly z + f(z,u) h and covariance
    /// trace tr(FFᵀ h) where the states allow, else the least achievable
    /// ([`rows_moment`]); δ, K and h are chosen as for `Kernel`.
    Moment,
}

/// Builds the POMDP of the module doc on `chain` (see [`ChainPomdpSpec`]);
/// `cost_rate(z, u)` is the running cost l per second.
pub fn build<M: SdeModel>(
    chain: &Chain,
    model: &M,
    obs: &dyn ObservationModel,
    cost_rate: &dyn Fn(&[f64], &[f64]) -> f64,
    spec: &ChainPomdpSpec,
) -> Result<ChainPomdp, ChainPomdpError> {
    build_with(chain, model, obs, cost_rate, spec, Rows::Kernel)
}

/// [`build`] with the transition rows made by `rows`.
pub fn build_with<M: SdeModel>(
    chain: &Chain,
    model: &M,
    obs: &dyn ObservationModel,
    cost_rate: &dyn Fn(&[f64], &[f64]) -> f64,
    spec: &ChainPomdpSpec,
    rows: Rows,
) -> Result<ChainPomdp, ChainPomdpError> {
    let row_kind = rows;
    let cfg = chain.config();
    if cfg.kernel != KernelKind::Gaussian || cfg.step.is_some() {
        return Err(ChainPomdpError::ChainKind);
    }
    let n = chain.len();
    let d = chain.dim();
    let c = model.dims().control;
    if n == 0 || spec.controls.is_empty() || spec.observations.is_empty() {
        return Err(ChainPomdpError::Spec(
            "needs states, controls and observation points".into(),
        ));
    }
    if spec.controls.iter().any(|u| u.len() != c) {
        return Err(ChainPomdpError::Spec(format!(
            "every control must have {c} components"
        )));
    }
    if spec.start.len() != n {
        return Err(ChainPomdpError::Spec(format!(
            "start has {} entries for {n} states",
            spec.start.len()
        )));
    }
    let positive = |x: f64| x > 0.0 && x.is_finite();
    let ok = (positive(spec.delta_max) || spec.delta_max == f64::INFINITY)
        && positive(spec.discount_rate)
        && spec.decision_min >= 0.0
        && spec.decision_min.is_finite();
    if !ok {
        return Err(ChainPomdpError::Spec(
            "δ_max and ρ must be positive, decision_min non-negative".into(),
        ));
    }
    if let Some(t) = &spec.terminal {
        if t.reward.len() != n || t.reward.iter().any(|r| !r.is_finite()) {
            return Err(ChainPomdpError::Spec(
                "terminal reward needs one finite value per state".into(),
            ));
        }
    }
    let kernels: Vec<rows::ControlKernel> = spec
        .controls
        .iter()
        .map(|u| rows::ControlKernel::with_mean(chain, model, u, spec.match_mean))
        .collect();
    let min_dt = kernels
        .iter()
        .map(rows::ControlKernel::min_holding)
        .fold(f64::INFINITY, f64::min);
    let mut delta = spec.delta_max;
    if delta.is_infinite() {
        if !min_dt.is_finite() {
            return Err(ChainPomdpError::Spec(
                "every state is absorbing under every control: no time step".into(),
            ));
        }
        delta = min_dt;
    }
    while min_dt.is_finite() && delta > min_dt {
        delta *= 0.5;
    }
    let mut steps = 1usize;
    while (steps as f64) * delta < spec.decision_min * (1.0 - 1e-12) {
        steps *= 2;
    }
    let period = steps as f64 * delta;
    let terminal = spec.terminal.is_some();
    let ns = n + usize::from(terminal);
    let offset = usize::from(terminal);
    let mut trans = Vec::with_capacity(offset + kernels.len());
    let mut reward = Vec::with_capacity(offset + kernels.len());
    if let Some(t) = &spec.terminal {
        trans.push(SparseRows::from_rows(
            (0..ns).map(|_| vec![(n as u32, 1.0)]).collect(),
            ns,
        ));
        let mut r = t.reward.clone();
        r.push(0.0);
        reward.push(r);
    }
    for (k, u) in kernels.iter().zip(&spec.controls) {
        let mut rows = match row_kind {
            Rows::Kernel => k.step_rows(chain, delta, steps, spec.row_flush),
            Rows::Moment => rows_moment::moment_rows(chain, model, u, period).rows,
        };
        if terminal {
            rows.push(vec![(n as u32, 1.0)]);
        }
        trans.push(SparseRows::from_rows(rows, ns));
        let mut r: Vec<f64> = (0..n)
            .map(|i| -cost_rate(chain.state(i), u) * period)
            .collect();
        if terminal {
            r.push(0.0);
        }
        reward.push(r);
    }
    let q = observation_rows(chain, obs, &spec.observations, spec.obs_flush, terminal);
    let q = SparseRows::from_rows(q, spec.observations.len());
    let mut start = spec.start.clone();
    if terminal {
        start.push(0.0);
    }
    let pomdp = Pomdp::new(
        (-spec.discount_rate * period).exp(),
        start,
        trans,
        vec![q; offset + kernels.len()],
        reward,
    )?;
    Ok(ChainPomdp {
        pomdp,
        delta,
        steps,
        period,
        states: chain.states().to_vec(),
        dim: d,
        controls: spec.controls.clone(),
        offset,
        observations: spec.observations.clone(),
    })
}

/// Q(o_j | z) ∝ p(o_j | z) normalised over the points, entries below
/// `flush` × the row's largest dropped; the absorbing state emits o₀.
fn observation_rows(
    chain: &Chain,
    obs: &dyn ObservationModel,
    points: &[Vec<f64>],
    flush: f64,
    terminal: bool,
) -> Vec<Vec<(u32, f64)>> {
    let mut out = Vec::with_capacity(chain.len() + 1);
    let mut ll = vec![0.0; points.len()];
    for i in 0..chain.len() {
        let z = chain.state(i);
        for (l, o) in ll.iter_mut().zip(points) {
            *l = obs.log_likelihood(z, o);
        }
        let lmax = ll.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut row: Vec<(u32, f64)> = ll
            .iter()
            .enumerate()
            .map(|(j, &l)| (j as u32, (l - lmax).exp()))
            .filter(|&(_, w)| w >= flush)
            .collect();
        let total: f64 = row.iter().map(|e| e.1).sum();
        row.iter_mut().for_each(|e| e.1 /= total);
        out.push(row);
    }
    if terminal {
        out.push(vec![(0, 1.0)]);
    }
    out
}

/// ⌊c ln n⌋, at least 1: the number of controls (and observation points)
/// for n states (Alg. 4.4 with the erratum: a control is added whenever
/// ⌊c log n⌋ increments).
pub fn log_count(c: f64, n: usize) -> usize {
    ((c * (n.max(1) as f64).ln()).floor() as usize).max(1)
}

#[cfg(test)]
mod tests;
