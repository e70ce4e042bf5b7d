//! Path-integral optimal control by implicit sampling (paper 003 §3) as a
//! [`Controller`] backend — the pipeline's default controller for the ship.
//!
//! For the belief b at time t the controller evaluates
//!
//! ```text
//! u = γ R⁻¹ Gᵀ ∂ₓ log ψ̄,    ψ̄ = ψ(mean b)              (certainty equivalent), or
//!                           ψ̄ = (1/K) Σ_k ψ(x_k), x_k ~ b (belief-averaged)
//! ψ(x, t) from eq. (16): minimise the path functional (15) over the next n
//! steps (Newton, banded Hessian, warm-started from the previous plan), then
//! M linear-map samples with weights (6)
//! ```
//!
//! with running cost V(x) + ½ uᵀRu, R = r I, and terminal cost Φ from the
//! [`TrackingCost`]. Control limits: the paper has none; here the path
//! functional gains a soft penalty on the controls the path implies
//! (`control_limit_weight`, so the plan respects the actuator), and the
//! returned control is clamped to ±`u_max`. Condition (8) is checked at construction: γ = r e² for
//! the ship, whose control and velocity noise share a channel. (The ship's
//! position noise e dw₁, e dw₂ cannot be written in the form (7); the
//! controller's model leaves it out.)
//!
//! Horizon: `receding` (n steps every call, for the pipeline) or `shrinking`
//! (n = (t_f − t)/Δt, the paper's fixed final time).
//!
//! Compute budget: the work of one control is ~K·(c₀ + M) sample-evaluation
//! units (K belief draws, M samples, c₀ ≈ 6 for the minimisation). When a
//! control takes longer than `budget_us`, the next one moves one rung down
//! the ladder (K → 1, then M halved down to 0, the Laplace / most-likely-path
//! control), and moves back up when the measured time, scaled by the work
//! ratio, fits in 70 % of the budget. A control is never abandoned half-way;
//! the ladder bounds the next one.

mod config;
#[cfg(test)]
mod lq_tests;
#[cfg(test)]
mod tests;

pub use config::{
    BeliefMode, GradientConfig, HorizonMode, MapConfig, PathIntegralConfig,
    PathIntegralConfigError, WarmShift, MAX_BELIEF_SAMPLES,
};

use super::cost::TrackingCost;
use super::implicit::estimator::{Estimate, EstimateError, EstimatorOptions, PathSampler};
use super::implicit::path::{PathCost, PathSetup};
use super::{ControlError, ControlInfo, Controller};
use crate::belief::Gaussian;
use crate::model::affine::ControlAffine;
use crate::model::ship::{Ship, ShipParams};
use crate::rng::SimRng;
use crate::{MAX_CONTROL, MAX_STATE};
use rand::RngExt;
use rand_distr::StandardNormal;
use std::time::Instant;

/// Diagnostics of the last control.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PathIntegralStats {
    /// Rung of the degradation ladder (0 = full configuration).
    pub level: usize,
    /// Belief draws and samples used.
    pub belief_samples: usize,
    pub samples: usize,
    /// Wall time of the last control (µs).
    pub compute_us: f64,
    /// Controls that exceeded the budget so far.
    pub over_budget: u64,
    /// Newton iterations in the last control.
    pub newton_iterations: usize,
    /// Horizon steps of the last control.
    pub horizon_steps: usize,
}

/// Implicit-sampling path-integral controller.
pub struct PathIntegralController<M: ControlAffine = Ship, C: PathCost = TrackingCost> {
    cfg: PathIntegralConfig,
    model: M,
    cost: C,
    sampler: PathSampler,
    opts: EstimatorOptions,
    rng: SimRng,
    belief_rng: SimRng,
    /// (belief draws, samples) per rung, most work first.
    ladder: Vec<(usize, usize)>,
    level: usize,
    states: Vec<f64>,
    last_t: Option<f64>,
    last_u: [f64; MAX_CONTROL],
    stats: PathIntegralStats,
}

/// Relative work of a rung: K (c₀ + M) with c₀ ≈ the cost of a warm
/// minimisation in sample evaluations.
fn work(k: usize, m: usize) -> f64 {
    k as f64 * (6.0 + m as f64)
}

impl PathIntegralController<Ship, TrackingCost> {
    /// The pipeline's controller: the ship with a tracking cost.
    pub fn ship(
        params: ShipParams,
        cost: TrackingCost,
        cfg: PathIntegralConfig,
    ) -> Result<Self, ControlError> {
        let ship = Ship::new(params).map_err(ControlError::Model)?;
        Self::new(ship, cost, cfg)
    }
}

impl<M: ControlAffine, C: PathCost> PathIntegralController<M, C> {
    /// A controller for `model` with state cost `cost`. Fails with
    /// [`ControlError::Model`] if condition (8) does not hold or the config
    /// is invalid.
    pub fn new(model: M, cost: C, cfg: PathIntegralConfig) -> Result<Self, ControlError> {
        cfg.validate()
            .map_err(|e| ControlError::Model(e.to_string()))?;
        let p = model.control_dim();
        let mut r = [0.0; MAX_CONTROL * MAX_CONTROL];
        for i in 0..p.min(MAX_CONTROL) {
            r[i + i * p] = cfg.control_cost;
        }
        let setup = PathSetup::new(&model, &r[..p * p], cfg.dt)
            .and_then(|s| {
                s.with_control_limit(cfg.u_max, cfg.control_limit_weight, cfg.control_limit_blend)
            })
            .map_err(|e| ControlError::Model(e.to_string()))?;
        let k = match cfg.belief {
            BeliefMode::Mean => 1,
            BeliefMode::Sampled => cfg.belief_samples,
        };
        let sampler = PathSampler::new(setup, cfg.horizon_steps, cfg.samples, k);
        let mut ladder = vec![(k, cfg.samples)];
        if k > 1 {
            ladder.push((1, cfg.samples));
        }
        let mut m = cfg.samples;
        while m > 0 {
            m /= 2;
            if m % 2 == 1 && cfg.antithetic && m > 1 {
                m -= 1;
            }
            ladder.push((1, m));
        }
        let opts = cfg.estimator_options(cfg.samples);
        let states = vec![0.0; k * model.state_dim()];
        Ok(Self {
            rng: crate::rng::stream(cfg.seed, 0x5041_5448),
            belief_rng: crate::rng::stream(cfg.seed, 0x4245_4c46),
            model,
            cost,
            sampler,
            opts,
            ladder,
            level: 0,
            states,
            last_t: None,
            last_u: [0.0; MAX_CONTROL],
            stats: PathIntegralStats::default(),
            cfg,
        })
    }

    /// γ of condition (8).
    pub fn gamma(&self) -> f64 {
        self.sampler.setup().gamma
    }

    /// Diagnostics of the last control.
    pub fn stats(&self) -> PathIntegralStats {
        self.stats
    }

    /// The configuration.
    pub fn config(&self) -> &PathIntegralConfig {
        &self.cfg
    }

    /// The most likely path of the last control (path variables).
    pub fn plan(&self) -> &[f64] {
        self.sampler.warm_start()
    }

    fn horizon(&self, t: f64) -> usize {
        match self.cfg.horizon {
            HorizonMode::Receding => self.cfg.horizon_steps,
            HorizonMode::Shrinking => {
                let n = ((self.cfg.final_time - t) / self.cfg.dt - 1e-9).ceil();
                if n <= 0.0 {
                    0
                } else {
                    (n as usize).min(self.cfg.horizon_steps)
                }
            }
        }
    }

    /// Fill `states` with the belief mean or K draws from it.
    fn initial_states(&mut self, belief: &Gaussian, k: usize) {
        let m = self.model.state_dim();
        if k == 1 {
            self.states[..m].copy_from_slice(belief.mean());
            return;
        }
        // Cholesky of the covariance (a tiny jitter keeps a singular one usable).
        let mut l = [0.0; MAX_STATE * MAX_STATE];
        let scale = (0..m)
            .map(|i| belief.cov_at(i, i).abs())
            .fold(0.0, f64::max)
            .max(1e-300);
        let jitter = 1e-12 * scale;
        for j in 0..m {
            let mut d = belief.cov_at(j, j) + jitter;
            for kk in 0..j {
                d -= l[j + kk * m] * l[j + kk * m];
            }
            let ljj = if d > 0.0 { d.sqrt() } else { 0.0 };
            l[j + j * m] = ljj;
            for i in j + 1..m {
                let mut v = 0.5 * (belief.cov_at(i, j) + belief.cov_at(j, i));
                for kk in 0..j {
                    v -= l[i + kk * m] * l[j + kk * m];
                }
                l[i + j * m] = if ljj > 0.0 { v / ljj } else { 0.0 };
            }
        }
        let mut xi = [0.0; MAX_STATE];
        for s in 0..k {
            for v in xi[..m].iter_mut() {
                *v = self.belief_rng.sample(StandardNormal);
            }
            let x = &mut self.states[s * m..(s + 1) * m];
            for i in 0..m {
                let mut v = belief.mean[i];
                for j in 0..=i {
                    v += l[i + j * m] * xi[j];
                }
                x[i] = v;
            }
        }
    }

    /// The belief, time and output buffer fit the model; (m, p).
    fn check_inputs(
        &self,
        t: f64,
        belief: &Gaussian,
        u: &[f64],
    ) -> Result<(usize, usize), ControlError> {
        let (m, p) = (self.model.state_dim(), self.model.control_dim());
        if belief.dim != m {
            return Err(ControlError::Dimension {
                got: belief.dim,
                expected: m,
            });
        }
        if !belief.is_finite() || !t.is_finite() {
            return Err(ControlError::NonFinite);
        }
        if u.len() < p {
            return Err(ControlError::Dimension {
                got: u.len(),
                expected: p,
            });
        }
        Ok((m, p))
    }

    /// Warm start: advance the previous plan by the time elapsed (a
    /// fraction of a path step at a control period below Δt), resize to n.
    fn advance_plan(&mut self, t: f64, n: usize) {
        let steps = match self.last_t {
            Some(t0) if t >= t0 => {
                let s = (t - t0) / self.cfg.dt;
                match self.cfg.warm_shift {
                    WarmShift::Interpolate => s,
                    WarmShift::WholeSteps => s.round(),
                }
            }
            _ => 0.0,
        };
        if self.sampler.warm_steps() > 0 {
            self.sampler.advance_warm_start(steps, n);
        }
    }

    /// ψ̄ and the control from the first `len` entries of the drawn initial
    /// states over `n` steps, retrying once from a cold start.
    fn estimate(&mut self, len: usize, n: usize) -> Result<Estimate, ControlError> {
        let states = &self.states[..len];
        let mut est = self.sampler.estimate(
            &self.model,
            &self.cost,
            states,
            n,
            None,
            &self.opts,
            &mut self.rng,
        );
        if est.is_err() {
            // A stale warm start can lead Newton astray: retry from scratch.
            self.sampler.reset_warm_start();
            est = self.sampler.estimate(
                &self.model,
                &self.cost,
                states,
                n,
                None,
                &self.opts,
                &mut self.rng,
            );
        }
        est.map_err(|e| {
            self.sampler.reset_warm_start();
            ControlError::Numerical(match e {
                EstimateError::Newton(_) => "path minimisation failed",
                EstimateError::NoMass => "no sample has positive weight",
                _ => "path-integral estimate failed",
            })
        })
    }

    fn adapt(&mut self, elapsed_us: f64) {
        let budget = self.cfg.budget_us;
        if budget <= 0.0 {
            return;
        }
        if elapsed_us > budget {
            self.stats.over_budget += 1;
            if self.level + 1 < self.ladder.len() {
                self.level += 1;
            }
        } else if self.level > 0 {
            let (k, m) = self.ladder[self.level];
            let (ku, mu) = self.ladder[self.level - 1];
            if elapsed_us * work(ku, mu) / work(k, m) < 0.7 * budget {
                self.level -= 1;
            }
        }
    }
}

impl<M: ControlAffine + 'static, C: PathCost + 'static> Controller
    for PathIntegralController<M, C>
{
    fn name(&self) -> &'static str {
        "implicit"
    }

    fn control_dim(&self) -> usize {
        self.model.control_dim()
    }

    fn set_goal(&mut self, goal: &[f64]) {
        self.cost.set_goal(goal);
    }

    fn reset(&mut self) {
        self.sampler.reset_warm_start();
        self.last_t = None;
        self.last_u = [0.0; MAX_CONTROL];
    }

    fn compute(
        &mut self,
        t: f64,
        belief: &Gaussian,
        u: &mut [f64],
    ) -> Result<ControlInfo, ControlError> {
        let start = Instant::now();
        let (m, p) = self.check_inputs(t, belief, u)?;
        let n = self.horizon(t);
        if n == 0 {
            u[..p].fill(0.0);
            return Ok(ControlInfo::default());
        }
        self.advance_plan(t, n);
        let (k, ms) = self.ladder[self.level];
        self.initial_states(belief, k);
        self.opts.samples = ms;
        let est = self.estimate(k * m, n)?;
        let lim = self.cfg.u_max;
        for i in 0..p {
            let v = est.u[i];
            u[i] = if v.is_finite() {
                v.clamp(-lim, lim)
            } else {
                0.0
            };
            self.last_u[i] = u[i];
        }
        self.last_t = Some(t);
        let elapsed = start.elapsed().as_secs_f64() * 1e6;
        self.stats = PathIntegralStats {
            level: self.level,
            belief_samples: k,
            samples: ms,
            compute_us: elapsed,
            over_budget: self.stats.over_budget,
            newton_iterations: est.newton_iterations,
            horizon_steps: n,
        };
        self.adapt(elapsed);
        Ok(ControlInfo {
            cost: est.phi * self.sampler.setup().gamma,
            samples: k * ms.max(1),
            ess: est.ess,
        })
    }
}
