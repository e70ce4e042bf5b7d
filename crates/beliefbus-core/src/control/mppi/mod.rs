//! Model-predictive path-integral control, MPPI (Williams et al., "Information
//! theoretic MPC for model-based reinforcement learning", ICRA 2017), laid
//! out like nav2's `nav2_mppi_controller`: generate noised control
//! sequences, roll them out, score them, update the nominal sequence by a
//! softmax-weighted average, then smooth and clamp; the shifted previous
//! solution warm-starts the next call.
//!
//! With nominal sequence u₀..u_{T−1}, K noise sequences ε⁽ᵏ⁾ (ε⁽⁰⁾ ≡ 0, the
//! nominal itself is always a candidate), step Δ = `dt` and the belief mean
//! as the initial state:
//!
//! ```text
//! v⁽ᵏ⁾_t   = clamp(u_t + ε⁽ᵏ⁾_t, u_min, u_max)        (ε⁽ᵏ⁾_t ← v⁽ᵏ⁾_t − u_t)
//! x_{t+1}  = x_t + f(x_t, v⁽ᵏ⁾_t) Δ                    (deterministic Euler rollout)
//! S⁽ᵏ⁾     = Σ_t [ q(x_{t+1}) + r ‖v⁽ᵏ⁾_t‖² ] Δ + φ(x_T)
//! w⁽ᵏ⁾     = exp(−(S⁽ᵏ⁾ − min S)/λ) / η,    ESS = 1/Σ w²
//! u_t     ← clamp(u_t + SG(Σ_k w⁽ᵏ⁾ ε⁽ᵏ⁾)_t)
//! ```
//!
//! q and φ are the running and terminal costs of any [`PathCost`] (the
//! pipeline's is [`TrackingCost`], scored branch-free in batches), r the
//! `control_weight`. SG is a 5-point quadratic Savitzky–Golay filter applied
//! to the update (nav2 smooths the sequence; smoothing the increment keeps
//! a converged nominal sequence exactly fixed when the update is zero).
//! Because the clamped perturbations are averaged, u + Σ w ε is a convex
//! combination of admissible sequences; the final clamp only catches the
//! smoother's overshoot.
//!
//! Warm start: the nominal sequence is shifted by (t − t_prev)/Δ steps
//! (fractional shifts interpolate linearly; the tail holds the last value),
//! so any call rate works with any Δ.
//!
//! Hot path: `compute` does not allocate (all buffers are sized at
//! construction, structure-of-arrays: time-major noise `eps[t][k][j]`,
//! per-sample states, costs, weights). Noise for the *next* call is drawn by
//! [`Mppi::prepare`], which the control stage calls after publishing the
//! control — off the sensor→control critical path. If `prepare` was not
//! called, `compute` draws the noise itself (correct, only slower).

mod config;
mod rollout;
#[cfg(test)]
mod tests;

use config::bad;
pub use config::{MppiConfig, MppiConfigError};
#[cfg(target_arch = "x86_64")]
use rollout::rollout_avx2;
use rollout::{dot, rollout_soa, savitzky_golay, RolloutBuffers, RolloutParams};

use super::cost::TrackingCost;
use super::{ControlError, ControlInfo, Controller};
use crate::belief::Gaussian;
use crate::model::path_cost::PathCost;
use crate::model::SdeModel;
use crate::rng::{self, SimRng};
use crate::{MAX_CONTROL, MAX_STATE};
use rand::RngExt;
use rand_distr::StandardNormal;

/// RNG stream id of MPPI's noise generator.
pub const MPPI_STREAM: u64 = 0x4d50_5049; // "MPPI"

/// MPPI controller on a model `M` with a state cost `C`.
pub struct Mppi<M: SdeModel, C: PathCost = TrackingCost> {
    model: M,
    cost: C,
    cfg: MppiConfig,
    d: usize,
    c: usize,
    k: usize,
    steps: usize,
    noise_std: [f64; MAX_CONTROL],
    u_min: [f64; MAX_CONTROL],
    u_max: [f64; MAX_CONTROL],
    /// Nominal sequence, time-major T × c.
    u_nom: Vec<f64>,
    /// Scratch T × c (shift, update increment, smoothed increment).
    scratch: Vec<f64>,
    delta: Vec<f64>,
    /// Perturbations, time-major and structure-of-arrays:
    /// eps[(t·c + j)·K + k].
    eps: Vec<f64>,
    /// Rollout states, structure-of-arrays: x[i·K + k].
    x: Vec<f64>,
    /// Drift of every rollout (d × K) and applied controls (c × K) of one step.
    f: Vec<f64>,
    v: Vec<f64>,
    /// Sample costs and weights.
    costs: Vec<f64>,
    weights: Vec<f64>,
    noise_ready: bool,
    t_prev: Option<f64>,
    rng: SimRng,
}

impl<M: SdeModel, C: PathCost> Mppi<M, C> {
    /// Build MPPI on `model` with state cost `cost`.
    pub fn new(model: M, cost: C, cfg: &MppiConfig) -> Result<Self, MppiConfigError> {
        let dims = model.dims();
        let c = dims.control;
        if c == 0 || c > MAX_CONTROL {
            return Err(bad(
                "model",
                format!("control dimension {c} must be in 1..={MAX_CONTROL}"),
            ));
        }
        if dims.state > MAX_STATE {
            return Err(bad(
                "model",
                format!("state dimension {} exceeds {MAX_STATE}", dims.state),
            ));
        }
        cost.check_state_dim(dims.state)
            .map_err(|e| bad("cost", e))?;
        cfg.validate(c)?;
        let (k, steps, d) = (cfg.samples, cfg.horizon_steps, dims.state);
        let arr = |v: &[f64]| {
            let mut a = [0.0; MAX_CONTROL];
            a[..c].copy_from_slice(v);
            a
        };
        let (noise_std, u_min, u_max) = (arr(&cfg.noise_std), arr(&cfg.u_min), arr(&cfg.u_max));
        let mut m = Self {
            model,
            cost,
            cfg: cfg.clone(),
            d,
            c,
            k,
            steps,
            noise_std,
            u_min,
            u_max,
            u_nom: vec![0.0; steps * c],
            scratch: vec![0.0; steps * c],
            delta: vec![0.0; steps * c],
            eps: vec![0.0; steps * k * c],
            x: vec![0.0; k * d],
            f: vec![0.0; k * d],
            v: vec![0.0; k * c],
            costs: vec![0.0; k],
            weights: vec![0.0; k],
            noise_ready: false,
            t_prev: None,
            rng: rng::stream(cfg.seed, MPPI_STREAM),
        };
        m.reset();
        Ok(m)
    }

    /// Draw the perturbations for the next `compute` (K·T·c normals). Call
    /// it after publishing a control so the draw is off the critical path.
    pub fn prepare(&mut self) {
        let (k, c) = (self.k, self.c);
        for block in self.eps.chunks_exact_mut(k * c) {
            for (j, e) in block.chunks_exact_mut(k).enumerate() {
                // Sample 0 is the unperturbed nominal sequence.
                e[0] = 0.0;
                for ej in e[1..].iter_mut() {
                    let z: f64 = self.rng.sample(StandardNormal);
                    *ej = self.noise_std[j] * z;
                }
            }
        }
        self.noise_ready = true;
    }

    /// Whether noise for the next call is already drawn.
    pub fn is_prepared(&self) -> bool {
        self.noise_ready
    }

    /// The nominal control sequence, time-major T × c.
    pub fn nominal(&self) -> &[f64] {
        &self.u_nom
    }

    /// Replace the nominal sequence (clamped to the limits); e.g. a plan
    /// from another optimiser.
    pub fn set_nominal(&mut self, seq: &[f64]) -> Result<(), ControlError> {
        if seq.len() != self.u_nom.len() {
            return Err(ControlError::Dimension {
                got: seq.len(),
                expected: self.u_nom.len(),
            });
        }
        if seq.iter().any(|v| !v.is_finite()) {
            return Err(ControlError::NonFinite);
        }
        self.u_nom.copy_from_slice(seq);
        self.clamp_nominal();
        Ok(())
    }

    /// The state cost.
    pub fn cost(&self) -> &C {
        &self.cost
    }

    /// The config.
    pub fn config(&self) -> &MppiConfig {
        &self.cfg
    }

    /// Weights of the last call's samples.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    fn clamp_nominal(&mut self) {
        let c = self.c;
        for u in self.u_nom.chunks_exact_mut(c) {
            for j in 0..c {
                u[j] = u[j].clamp(self.u_min[j], self.u_max[j]);
            }
        }
    }

    /// Shift the nominal sequence forward by `s ≥ 0` steps (fractional:
    /// linear interpolation; beyond the end: hold the last value).
    fn shift(&mut self, s: f64) {
        if !(s > 0.0) {
            return;
        }
        let (steps, c) = (self.steps, self.c);
        let last = steps - 1;
        let whole = s.floor();
        let frac = s - whole;
        let whole = whole.min(steps as f64) as usize;
        for t in 0..steps {
            let i0 = (t + whole).min(last);
            let i1 = (i0 + 1).min(last);
            for j in 0..c {
                let a = self.u_nom[i0 * c + j];
                let b = self.u_nom[i1 * c + j];
                self.scratch[t * c + j] = a + frac * (b - a);
            }
        }
        self.u_nom.copy_from_slice(&self.scratch);
    }

    /// Roll out every sample from `x0`, clamping perturbations in place;
    /// fills `costs`. Dispatches to a copy of [`rollout_soa`] compiled for
    /// AVX2 + FMA when the CPU has them (4 rollouts per instruction instead
    /// of SSE2's 2); both copies compute the same arithmetic (no fused
    /// multiply–add is introduced without fast-math), so results agree.
    fn rollout(&mut self, x0: &[f64]) {
        let mut b = RolloutBuffers {
            x: &mut self.x,
            f: &mut self.f,
            v: &mut self.v,
            eps: &mut self.eps,
            costs: &mut self.costs,
        };
        let p = RolloutParams {
            d: self.d,
            c: self.c,
            k: self.k,
            steps: self.steps,
            dt: self.cfg.dt,
            r: self.cfg.control_weight,
            u_min: &self.u_min,
            u_max: &self.u_max,
            u_nom: &self.u_nom,
            cost: &self.cost,
        };
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the CPU supports the features the copy is compiled for.
                unsafe { rollout_avx2(&self.model, &p, &mut b, x0) };
                return;
            }
        }
        rollout_soa(&self.model, &p, &mut b, x0);
    }

    /// Softmax weights of the costs; returns (Σ w S, ESS), or `None` when
    /// every rollout failed.
    fn weigh(&mut self) -> Option<(f64, f64)> {
        let min = self.costs.iter().copied().fold(f64::INFINITY, f64::min);
        if !min.is_finite() {
            return None;
        }
        let inv_lambda = 1.0 / self.cfg.temperature;
        let mut eta = 0.0;
        for (w, &s) in self.weights.iter_mut().zip(&self.costs) {
            *w = (-(s - min) * inv_lambda).exp();
            eta += *w;
        }
        let (mut sq, mut expected) = (0.0, 0.0);
        for (w, &s) in self.weights.iter_mut().zip(&self.costs) {
            *w /= eta;
            sq += *w * *w;
            if *w > 0.0 {
                expected += *w * s;
            }
        }
        Some((expected, 1.0 / sq))
    }

    /// u ← clamp(u + SG(Σ_k w_k ε_k)).
    fn update_nominal(&mut self) {
        let (c, k) = (self.c, self.k);
        for (t, dt_slot) in self.delta.chunks_exact_mut(c).enumerate() {
            let eps_t = &self.eps[t * k * c..(t + 1) * k * c];
            for (j, slot) in dt_slot.iter_mut().enumerate() {
                *slot = dot(&eps_t[j * k..(j + 1) * k], &self.weights);
            }
        }
        let inc = if self.cfg.smoothing {
            savitzky_golay(&self.delta, &mut self.scratch, self.steps, c);
            &self.scratch
        } else {
            &self.delta
        };
        for (u, du) in self.u_nom.iter_mut().zip(inc) {
            *u += du;
        }
        self.clamp_nominal();
    }
}

impl<M: SdeModel, C: PathCost> Controller for Mppi<M, C> {
    fn prepare(&mut self) {
        Mppi::prepare(self)
    }

    fn name(&self) -> &'static str {
        "mppi"
    }
    fn control_dim(&self) -> usize {
        self.c
    }
    fn set_goal(&mut self, goal: &[f64]) {
        self.cost.set_goal(goal);
    }
    fn reset(&mut self) {
        self.u_nom.fill(0.0);
        self.clamp_nominal();
        self.t_prev = None;
    }

    fn compute(
        &mut self,
        t: f64,
        belief: &Gaussian,
        u: &mut [f64],
    ) -> Result<ControlInfo, ControlError> {
        if belief.dim != self.d {
            return Err(ControlError::Dimension {
                got: belief.dim,
                expected: self.d,
            });
        }
        if u.len() != self.c {
            return Err(ControlError::Dimension {
                got: u.len(),
                expected: self.c,
            });
        }
        if !t.is_finite() || !belief.mean().iter().all(|v| v.is_finite()) {
            return Err(ControlError::NonFinite);
        }
        if let Some(tp) = self.t_prev {
            self.shift((t - tp) / self.cfg.dt);
        }
        if !self.noise_ready {
            self.prepare();
        }
        self.noise_ready = false;
        self.rollout(belief.mean());
        let Some((cost, ess)) = self.weigh() else {
            return Err(ControlError::Numerical("every rollout diverged"));
        };
        self.update_nominal();
        self.t_prev = Some(t);
        u.copy_from_slice(&self.u_nom[..self.c]);
        Ok(ControlInfo {
            cost,
            samples: self.k,
            ess,
        })
    }
}
