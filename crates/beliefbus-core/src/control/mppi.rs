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

use super::cost::TrackingCost;
use super::{ControlError, ControlInfo, Controller};
use crate::belief::Gaussian;
use crate::model::path_cost::PathCost;
use crate::model::SdeModel;
use crate::rng::{self, SimRng};
use crate::{MAX_CONTROL, MAX_STATE};
use rand::RngExt;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// RNG stream id of MPPI's noise generator.
pub const MPPI_STREAM: u64 = 0x4d50_5049; // "MPPI"

/// Settings of MPPI (defaults suit the ship: force limits ±3, 2 s horizon).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct MppiConfig {
    /// Number of sampled control sequences K.
    pub samples: usize,
    /// Horizon length T in steps.
    pub horizon_steps: usize,
    /// Rollout step Δ (seconds).
    pub dt: f64,
    /// Temperature λ of the softmax weights (in cost units).
    pub temperature: f64,
    /// σ of the control noise, one per control component.
    pub noise_std: Vec<f64>,
    /// Lower control limits, one per component.
    pub u_min: Vec<f64>,
    /// Upper control limits, one per component.
    pub u_max: Vec<f64>,
    /// Weight r of the quadratic control cost r‖v‖² per unit time.
    pub control_weight: f64,
    /// Savitzky–Golay smoothing of the update (needs horizon_steps ≥ 5).
    pub smoothing: bool,
    /// Seed of the noise stream.
    pub seed: u64,
}

impl Default for MppiConfig {
    fn default() -> Self {
        Self {
            samples: 512,
            horizon_steps: 50,
            dt: 0.04,
            temperature: 1.0,
            noise_std: vec![1.5, 1.5],
            u_min: vec![-3.0, -3.0],
            u_max: vec![3.0, 3.0],
            control_weight: 0.05,
            smoothing: true,
            seed: 0,
        }
    }
}

/// An invalid MPPI setting; `key` is the field inside the config section.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {problem}")]
pub struct MppiConfigError {
    pub key: &'static str,
    pub problem: String,
}

fn bad(key: &'static str, problem: impl Into<String>) -> MppiConfigError {
    MppiConfigError {
        key,
        problem: problem.into(),
    }
}

impl MppiConfig {
    /// Check every field for a model with `control_dim` controls.
    pub fn validate(&self, control_dim: usize) -> Result<(), MppiConfigError> {
        if self.samples == 0 {
            return Err(bad("samples", "must be at least 1"));
        }
        if self.horizon_steps == 0 {
            return Err(bad("horizon_steps", "must be at least 1"));
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(bad("dt", format!("must be positive, got {}", self.dt)));
        }
        if !(self.temperature.is_finite() && self.temperature > 0.0) {
            return Err(bad(
                "temperature",
                format!("must be positive, got {}", self.temperature),
            ));
        }
        if !(self.control_weight.is_finite() && self.control_weight >= 0.0) {
            return Err(bad(
                "control_weight",
                format!("must be non-negative, got {}", self.control_weight),
            ));
        }
        for (key, v) in [
            ("noise_std", &self.noise_std),
            ("u_min", &self.u_min),
            ("u_max", &self.u_max),
        ] {
            if v.len() != control_dim {
                return Err(bad(
                    key,
                    format!(
                        "needs {control_dim} entries (the model's control dimension), got {}",
                        v.len()
                    ),
                ));
            }
            if v.iter().any(|x| !x.is_finite()) {
                return Err(bad(key, "entries must be finite"));
            }
        }
        if self.noise_std.iter().any(|&s| s < 0.0) {
            return Err(bad("noise_std", "entries must be non-negative"));
        }
        if self.u_min.iter().zip(&self.u_max).any(|(lo, hi)| lo > hi) {
            return Err(bad("u_min", "must not exceed u_max"));
        }
        Ok(())
    }
}

/// 5-point quadratic Savitzky–Golay weights (×35): interior, first and
/// second point (the last two mirror them).
const SG_MID: [f64; 5] = [-3.0, 12.0, 17.0, 12.0, -3.0];
const SG_FIRST: [f64; 5] = [31.0, 9.0, -3.0, -5.0, 3.0];
const SG_SECOND: [f64; 5] = [9.0, 13.0, 12.0, 6.0, -5.0];

/// Smooth a T × c time-major sequence `src` into `dst` per component with
/// the quadratic SG filter (exact on quadratics, including the ends).
fn savitzky_golay(src: &[f64], dst: &mut [f64], steps: usize, c: usize) {
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
fn dot(a: &[f64], b: &[f64]) -> f64 {
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
struct RolloutParams<'a, C: PathCost> {
    d: usize,
    c: usize,
    k: usize,
    steps: usize,
    dt: f64,
    r: f64,
    u_min: &'a [f64; MAX_CONTROL],
    u_max: &'a [f64; MAX_CONTROL],
    u_nom: &'a [f64],
    cost: &'a C,
}

/// What a rollout writes (all structure-of-arrays, K per component).
struct RolloutBuffers<'a> {
    x: &'a mut [f64],
    f: &'a mut [f64],
    v: &'a mut [f64],
    eps: &'a mut [f64],
    costs: &'a mut [f64],
}

/// [`rollout_soa`] compiled for AVX2 + FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn rollout_avx2<M: SdeModel, C: PathCost>(
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
fn rollout_soa<M: SdeModel, C: PathCost>(
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::linear::LinearSde;
    use crate::model::Bounds;
    use nalgebra::DMatrix;

    /// Double integrator p̈ = u + s ẇ.
    fn double_integrator(s: f64) -> LinearSde {
        LinearSde::new(
            "di",
            DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]),
            DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
            DMatrix::from_row_slice(2, 1, &[0.0, s]),
            DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            vec![0.1],
            Bounds::new_box(&[-10.0, -10.0], &[10.0, 10.0]).unwrap(),
        )
    }

    fn di_config() -> MppiConfig {
        MppiConfig {
            samples: 256,
            horizon_steps: 40,
            dt: 0.05,
            temperature: 0.1,
            noise_std: vec![1.0],
            u_min: vec![-2.0],
            u_max: vec![2.0],
            control_weight: 0.01,
            smoothing: true,
            seed: 1,
        }
    }

    fn di_cost() -> TrackingCost {
        TrackingCost::new(&[10.0, 1.0], &[20.0, 5.0], None)
    }

    #[test]
    fn savitzky_golay_is_exact_on_quadratics() {
        let steps = 9;
        let src: Vec<f64> = (0..steps)
            .flat_map(|t| {
                let t = t as f64;
                [1.0 - 0.5 * t + 0.25 * t * t, 3.0 * t]
            })
            .collect();
        let mut dst = vec![0.0; src.len()];
        savitzky_golay(&src, &mut dst, steps, 2);
        for (a, b) in src.iter().zip(&dst) {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
        // And it damps an alternating (noise-like) sequence.
        let alt: Vec<f64> = (0..steps)
            .map(|t| if t % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        let mut out = vec![0.0; steps];
        savitzky_golay(&alt, &mut out, steps, 1);
        assert!(out[2..steps - 2].iter().all(|v| v.abs() < 0.5));
    }

    /// Closed loop on a double integrator with process noise (s = 0.05),
    /// driven from rest at p = 0 to the goal p = 1, 50 Hz control, four
    /// seeds: within 2 s the position is within 0.05 of the goal, and over
    /// the last second (t ∈ [4, 5] s) it stays within 0.05 with speed within
    /// 0.2 (the plant's velocity noise has σ = 0.05 over one second).
    #[test]
    fn closed_loop_reaches_and_holds_a_goal() {
        for seed in 0..4 {
            let plant = double_integrator(0.05);
            let cfg = MppiConfig {
                seed,
                ..di_config()
            };
            let mut mppi = Mppi::new(double_integrator(0.0), di_cost(), &cfg).unwrap();
            mppi.set_goal(&[1.0, 0.0]);
            let mut rng = rng::stream(seed, 77);
            let mut x = [0.0, 0.0];
            let mut u = [0.0];
            let period = 0.02;
            let mut reached = None;
            let mut worst_late: (f64, f64) = (0.0, 0.0);
            for i in 0..250 {
                let t = i as f64 * period;
                let b = Gaussian::diagonal(&x, &[0.01, 0.01]);
                mppi.compute(t, &b, &mut u).unwrap();
                mppi.prepare();
                crate::model::discrete::em_integrate(&plant, &mut x, &u, period, 1e-3, &mut rng);
                let t = t + period;
                if reached.is_none() && (x[0] - 1.0).abs() < 0.05 {
                    reached = Some(t);
                }
                if t >= 4.0 {
                    worst_late.0 = worst_late.0.max((x[0] - 1.0).abs());
                    worst_late.1 = worst_late.1.max(x[1].abs());
                }
            }
            assert!(
                reached.is_some_and(|t| t < 2.0),
                "seed {seed}: reached at {reached:?}"
            );
            assert!(
                worst_late.0 < 0.05,
                "seed {seed}: position error {}",
                worst_late.0
            );
            assert!(
                worst_late.1 < 0.2,
                "seed {seed}: speed error {}",
                worst_late.1
            );
        }
    }

    #[test]
    fn control_limits_are_always_respected() {
        let cfg = MppiConfig {
            noise_std: vec![5.0],
            u_min: vec![-0.5],
            u_max: vec![1.5],
            ..di_config()
        };
        let mut mppi = Mppi::new(double_integrator(0.0), di_cost(), &cfg).unwrap();
        let mut rng = rng::stream(5, 0);
        let mut u = [0.0];
        for i in 0..200 {
            let x = [rng.random_range(-8.0..8.0), rng.random_range(-4.0..4.0)];
            if i % 7 == 0 {
                mppi.set_goal(&[rng.random_range(-8.0..8.0), 0.0]);
            }
            mppi.compute(
                i as f64 * 0.013,
                &Gaussian::diagonal(&x, &[0.1, 0.1]),
                &mut u,
            )
            .unwrap();
            assert!((-0.5..=1.5).contains(&u[0]), "u = {}", u[0]);
            assert!(mppi.nominal().iter().all(|v| (-0.5..=1.5).contains(v)));
        }
        // Saturating goals drive the control to the limits.
        mppi.reset();
        mppi.set_goal(&[100.0, 0.0]);
        mppi.compute(0.0, &Gaussian::diagonal(&[0.0, 0.0], &[0.1, 0.1]), &mut u)
            .unwrap();
        assert!(u[0] > 1.0, "u = {}", u[0]);
    }

    /// With one sample and zero noise the only candidate is the nominal
    /// sequence: MPPI returns it unchanged, and the warm start shifts it by
    /// the elapsed time (whole and fractional steps).
    #[test]
    fn one_noiseless_sample_reproduces_the_nominal_sequence() {
        let cfg = MppiConfig {
            samples: 1,
            noise_std: vec![0.0],
            ..di_config()
        };
        let mut mppi = Mppi::new(double_integrator(0.0), di_cost(), &cfg).unwrap();
        let seq: Vec<f64> = (0..cfg.horizon_steps)
            .map(|t| 1.5 * (0.3 * t as f64).sin())
            .collect();
        mppi.set_nominal(&seq).unwrap();
        let b = Gaussian::diagonal(&[0.3, -0.2], &[0.1, 0.1]);
        let mut u = [0.0];
        let info = mppi.compute(1.0, &b, &mut u).unwrap();
        assert_eq!(u[0], seq[0]);
        assert_eq!(mppi.nominal(), &seq[..]);
        assert_eq!(info.ess, 1.0);
        // One step later: the sequence shifted by one.
        mppi.compute(1.0 + cfg.dt, &b, &mut u).unwrap();
        assert!((u[0] - seq[1]).abs() < 1e-12);
        // Half a step later: halfway between seq[1] and seq[2].
        mppi.compute(1.0 + 1.5 * cfg.dt, &b, &mut u).unwrap();
        assert!((u[0] - 0.5 * (seq[1] + seq[2])).abs() < 1e-12);
        let n = mppi.nominal();
        assert!((n[cfg.horizon_steps - 1] - seq[cfg.horizon_steps - 1]).abs() < 1e-12);
    }

    /// The weighted update improves the plan: starting from a zero nominal,
    /// the cost of the returned nominal sequence (one noiseless rollout)
    /// decreases over repeated calls at the same state.
    #[test]
    fn iterations_reduce_the_nominal_cost() {
        let cfg = di_config();
        let mut mppi = Mppi::new(double_integrator(0.0), di_cost(), &cfg).unwrap();
        mppi.set_goal(&[1.0, 0.0]);
        let b = Gaussian::diagonal(&[0.0, 0.0], &[0.1, 0.1]);
        let nominal_cost = |m: &Mppi<LinearSde>| {
            let probe_cfg = MppiConfig {
                samples: 1,
                noise_std: vec![0.0],
                ..m.config().clone()
            };
            let mut probe = Mppi::new(double_integrator(0.0), *m.cost(), &probe_cfg).unwrap();
            probe.set_nominal(m.nominal()).unwrap();
            let mut u = [0.0];
            probe.compute(0.0, &b, &mut u).unwrap().cost
        };
        let c0 = nominal_cost(&mppi);
        let mut u = [0.0];
        for _ in 0..20 {
            mppi.compute(0.0, &b, &mut u).unwrap();
        }
        let c20 = nominal_cost(&mppi);
        assert!(c20 < 0.5 * c0, "cost {c0} -> {c20}");
    }

    #[test]
    fn same_seed_same_controls_and_prepare_is_equivalent() {
        let run = |use_prepare: bool| {
            let mut m = Mppi::new(double_integrator(0.0), di_cost(), &di_config()).unwrap();
            m.set_goal(&[1.0, 0.0]);
            let mut out = vec![];
            let mut u = [0.0];
            for i in 0..5 {
                let b = Gaussian::diagonal(&[0.1 * i as f64, 0.0], &[0.1, 0.1]);
                m.compute(0.02 * i as f64, &b, &mut u).unwrap();
                if use_prepare {
                    m.prepare();
                }
                out.push(u[0]);
            }
            out
        };
        assert_eq!(run(true), run(true));
        // Drawing the noise in prepare() or inside compute() consumes the
        // same stream in the same order.
        assert_eq!(run(true), run(false));
    }

    #[test]
    fn config_and_inputs_are_validated() {
        let ok = di_config();
        assert!(ok.validate(1).is_ok());
        assert_eq!(ok.validate(2).unwrap_err().key, "noise_std");
        for (cfg, key) in [
            (
                MppiConfig {
                    samples: 0,
                    ..di_config()
                },
                "samples",
            ),
            (
                MppiConfig {
                    temperature: 0.0,
                    ..di_config()
                },
                "temperature",
            ),
            (
                MppiConfig {
                    u_min: vec![3.0],
                    ..di_config()
                },
                "u_min",
            ),
            (
                MppiConfig {
                    noise_std: vec![-1.0],
                    ..di_config()
                },
                "noise_std",
            ),
        ] {
            assert_eq!(
                Mppi::new(double_integrator(0.0), di_cost(), &cfg)
                    .err()
                    .unwrap()
                    .key,
                key
            );
        }
        let parsed: MppiConfig = toml::from_str("samples = 64\nnoise_std = [0.5]").unwrap();
        assert_eq!(parsed.samples, 64);
        assert!(toml::from_str::<MppiConfig>("sample = 64").is_err());
        let mut m = Mppi::new(double_integrator(0.0), di_cost(), &ok).unwrap();
        let mut u = [0.0];
        assert!(matches!(
            m.compute(0.0, &Gaussian::zeros(3), &mut u),
            Err(ControlError::Dimension { .. })
        ));
        assert!(matches!(
            m.compute(
                0.0,
                &Gaussian::diagonal(&[f64::NAN, 0.0], &[1.0, 1.0]),
                &mut u
            ),
            Err(ControlError::NonFinite)
        ));
    }
}
