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

use super::cost::TrackingCost;
use super::implicit::estimator::{
    EstimatorOptions, GateMode, GateSampling, GradientMethod, MapKind, PathSampler,
};
use super::implicit::newton::NewtonOptions;
use super::implicit::path::{PathCost, PathSetup};
use super::{ControlError, ControlInfo, Controller};
use crate::belief::Gaussian;
use crate::model::affine::ControlAffine;
use crate::model::ship::{Ship, ShipParams};
use crate::rng::SimRng;
use crate::{MAX_CONTROL, MAX_STATE};
use rand::RngExt;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Receding or shrinking horizon.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum HorizonMode {
    /// `horizon_steps` steps from every t.
    Receding,
    /// Up to `final_time` (n = ⌈(t_f − t)/Δt⌉, capped at `horizon_steps`).
    Shrinking,
}

/// How the belief enters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum BeliefMode {
    /// Certainty equivalent: ψ at the belief mean.
    Mean,
    /// ψ averaged over `belief_samples` states drawn from the belief.
    Sampled,
}

/// How ∂ₓ log ψ is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum GradientConfig {
    /// Exact derivative of the linear-map estimator (one banded solve per
    /// control direction).
    Analytic,
    /// The paper's central differences with common random numbers.
    FiniteDifference,
    /// The likelihood-ratio form −E_w[∂ₓF] at fixed samples (u Δt ≈
    /// B⁻¹E_w[r₁], the first noise increment under the weights): no solve
    /// per direction, a value pass per sample.
    LikelihoodRatio,
}

/// How the previous plan is moved to the current time before it warm-starts
/// the minimisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum WarmShift {
    /// By the elapsed time in (fractional) path steps, interpolating the
    /// plan between its grid points.
    Interpolate,
    /// By round(elapsed/Δt) whole steps (the earlier behaviour: with a
    /// control period below Δt/2 the plan never moves).
    WholeSteps,
}

/// Which implicit-sampling map.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum MapConfig {
    Linear,
    Random,
}

/// Settings of the path-integral controller.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PathIntegralConfig {
    /// Path steps n of the horizon (the cap for a shrinking horizon).
    pub horizon_steps: usize,
    /// Path time step Δt in seconds.
    pub dt: f64,
    /// Implicit samples M per initial state (0: Laplace / most likely path).
    pub samples: usize,
    /// Antithetic pairs (ξ, −ξ): exact for linear-quadratic problems.
    pub antithetic: bool,
    pub horizon: HorizonMode,
    /// Final time t_f for the shrinking horizon (seconds).
    pub final_time: f64,
    pub belief: BeliefMode,
    /// States drawn from the belief when `belief = "sampled"`.
    pub belief_samples: usize,
    /// r in R = r I (running control cost ½ uᵀRu).
    pub control_cost: f64,
    /// Each control component is clamped to [−u_max, u_max].
    pub u_max: f64,
    /// κ of the soft limit κ·max(0, |u_c| − u_max)² per unit time on the
    /// controls the planned path implies (0: the paper's unconstrained F,
    /// only the final clamp). See `PathSetup::with_control_limit`.
    pub control_limit_weight: f64,
    /// δ of the C² quadratic–cubic blend of that penalty (force units; 0:
    /// the C¹ max(0, e)² kink). See `PathSetup::with_control_limit`.
    pub control_limit_blend: f64,
    /// Newton stops when ½gᵀH⁻¹g (the error of the minimum F to second
    /// order) ≤ newton_tol · max(1, |F|).
    pub newton_tol: f64,
    /// Seed of the sampler's random numbers.
    pub seed: u64,
    /// Per-control compute budget in µs (0: unlimited).
    pub budget_us: f64,
    pub gradient: GradientConfig,
    /// Finite-difference step h (state units), `gradient = "finite_difference"`.
    pub fd_step: f64,
    pub map: MapConfig,
    /// Newton iteration cap per minimisation.
    pub newton_max_iter: usize,
    /// At the cap, use the iterate reached instead of failing (real-time
    /// iteration: the warm start carries the refinement to the next call).
    pub newton_accept_at_cap: bool,
    /// How the previous plan is advanced to the current time.
    pub warm_shift: WarmShift,
}

impl Default for PathIntegralConfig {
    fn default() -> Self {
        Self {
            horizon_steps: 50,
            dt: 0.04,
            samples: 8,
            antithetic: true,
            horizon: HorizonMode::Receding,
            final_time: 0.0,
            belief: BeliefMode::Mean,
            belief_samples: 4,
            control_cost: 0.1,
            u_max: 3.0,
            control_limit_weight: 10.0,
            control_limit_blend: 0.0,
            newton_tol: 1e-9,
            seed: 1,
            budget_us: 500.0,
            gradient: GradientConfig::Analytic,
            fd_step: 1e-4,
            map: MapConfig::Linear,
            newton_max_iter: 30,
            newton_accept_at_cap: false,
            warm_shift: WarmShift::Interpolate,
        }
    }
}

/// A bad [`PathIntegralConfig`] value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PathIntegralConfigError {
    #[error("{key}: {problem}")]
    Invalid { key: &'static str, problem: String },
}

fn invalid(key: &'static str, problem: impl Into<String>) -> PathIntegralConfigError {
    PathIntegralConfigError::Invalid {
        key,
        problem: problem.into(),
    }
}

/// Most belief draws.
pub const MAX_BELIEF_SAMPLES: usize = 64;

impl PathIntegralConfig {
    /// Check every field.
    pub fn validate(&self) -> Result<(), PathIntegralConfigError> {
        if self.horizon_steps == 0 || self.horizon_steps > 10_000 {
            return Err(invalid("horizon_steps", "must be in 1..=10000"));
        }
        if !(self.dt > 0.0 && self.dt.is_finite()) {
            return Err(invalid("dt", "must be positive and finite"));
        }
        if self.samples > 100_000 {
            return Err(invalid("samples", "at most 100000"));
        }
        if self.belief_samples == 0 || self.belief_samples > MAX_BELIEF_SAMPLES {
            return Err(invalid(
                "belief_samples",
                format!("must be in 1..={MAX_BELIEF_SAMPLES}"),
            ));
        }
        if self.horizon == HorizonMode::Shrinking
            && !(self.final_time > 0.0 && self.final_time.is_finite())
        {
            return Err(invalid(
                "final_time",
                "a shrinking horizon needs a positive final time",
            ));
        }
        if !(self.control_cost > 0.0 && self.control_cost.is_finite()) {
            return Err(invalid("control_cost", "must be positive and finite"));
        }
        if !(self.u_max > 0.0) || self.u_max.is_nan() {
            return Err(invalid("u_max", "must be positive"));
        }
        if !(self.control_limit_weight >= 0.0 && self.control_limit_weight.is_finite()) {
            return Err(invalid("control_limit_weight", "must be ≥ 0 and finite"));
        }
        if !(self.control_limit_blend >= 0.0 && self.control_limit_blend.is_finite()) {
            return Err(invalid("control_limit_blend", "must be ≥ 0 and finite"));
        }
        if !(self.newton_tol > 0.0 && self.newton_tol < 1.0) {
            return Err(invalid("newton_tol", "must be in (0, 1)"));
        }
        if !(self.budget_us >= 0.0 && self.budget_us.is_finite()) {
            return Err(invalid("budget_us", "must be ≥ 0 (0: unlimited)"));
        }
        if !(self.fd_step > 0.0 && self.fd_step.is_finite()) {
            return Err(invalid("fd_step", "must be positive"));
        }
        if self.gradient != GradientConfig::FiniteDifference && self.map == MapConfig::Random {
            return Err(invalid(
                "gradient",
                "the analytic and likelihood-ratio gradients need map = \"linear\"",
            ));
        }
        if self.newton_max_iter == 0 {
            return Err(invalid("newton_max_iter", "must be ≥ 1"));
        }
        Ok(())
    }

    fn estimator_options(&self, samples: usize) -> EstimatorOptions {
        EstimatorOptions {
            samples,
            antithetic: self.antithetic,
            map: match self.map {
                MapConfig::Linear => MapKind::Linear,
                MapConfig::Random => MapKind::Random,
            },
            gradient: match self.gradient {
                GradientConfig::Analytic => GradientMethod::Analytic,
                GradientConfig::FiniteDifference => {
                    GradientMethod::FiniteDifference { h: self.fd_step }
                }
                GradientConfig::LikelihoodRatio => GradientMethod::LikelihoodRatio,
            },
            gate_mode: GateMode::AllBasins,
            gate_sampling: GateSampling::Marginal,
            newton: NewtonOptions {
                max_iter: self.newton_max_iter,
                tol_decrement: self.newton_tol,
                reuse_factor: true,
                accept_at_cap: self.newton_accept_at_cap,
                ..NewtonOptions::default()
            },
        }
    }
}

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
        let n = self.horizon(t);
        if n == 0 {
            u[..p].fill(0.0);
            return Ok(ControlInfo::default());
        }
        // Warm start: advance the previous plan by the time elapsed (a
        // fraction of a path step at a control period below Δt), resize to n.
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
        let (k, ms) = self.ladder[self.level];
        self.initial_states(belief, k);
        self.opts.samples = ms;
        let states = &self.states[..k * m];
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
        let est = est.map_err(|e| {
            self.sampler.reset_warm_start();
            ControlError::Numerical(match e {
                super::implicit::EstimateError::Newton(_) => "path minimisation failed",
                super::implicit::EstimateError::NoMass => "no sample has positive weight",
                _ => "path-integral estimate failed",
            })
        })?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::cost::DiscBarrier;
    use crate::model::affine::LinearAffine;
    use crate::model::affine::PathStructure;

    fn ship_cost() -> TrackingCost {
        TrackingCost::new(
            &[1.0, 1.0, 0.1, 0.1],
            &[5.0, 5.0, 1.0, 1.0],
            Some(DiscBarrier {
                axes: (0, 1),
                radius: 8.0,
                weight: 50.0,
            }),
        )
    }

    #[test]
    fn config_round_trips_and_rejects_unknown_keys() {
        let cfg = PathIntegralConfig::default();
        let s = toml::to_string(&cfg).unwrap();
        let back: PathIntegralConfig = toml::from_str(&s).unwrap();
        assert_eq!(cfg, back);
        assert!(toml::from_str::<PathIntegralConfig>("samples = 4\nbogus = 1").is_err());
        let partial: PathIntegralConfig =
            toml::from_str("belief = \"sampled\"\nhorizon = \"shrinking\"\nfinal_time = 3.0")
                .unwrap();
        assert_eq!(partial.belief, BeliefMode::Sampled);
        assert_eq!(partial.dt, 0.04);
        let bad = PathIntegralConfig {
            dt: 0.0,
            ..cfg.clone()
        };
        assert!(bad.validate().is_err());
        let bad = PathIntegralConfig {
            horizon: HorizonMode::Shrinking,
            ..cfg
        };
        assert!(bad.validate().is_err());
    }

    #[test]
    fn rejects_models_violating_condition_8_and_bad_beliefs() {
        // Noise on a channel the control cannot reach.
        let m = LinearAffine {
            m: 2,
            p: 2,
            r: 2,
            a: vec![0.0; 4],
            g: vec![1.0, 0.0, 0.0, 1.0],
            q: vec![1.0, 0.0, 0.0, 3.0],
            structure: PathStructure::Full,
        };
        let cost = crate::control::implicit::DiagonalQuadraticCost::new(&[1.0, 1.0], &[1.0, 1.0]);
        let err = PathIntegralController::new(m, cost, PathIntegralConfig::default())
            .err()
            .unwrap();
        assert!(
            matches!(err, ControlError::Model(ref s) if s.contains("condition (8)")),
            "{err:?}"
        );
        let mut c = PathIntegralController::ship(
            ShipParams::paper(0.01),
            ship_cost(),
            PathIntegralConfig::default(),
        )
        .unwrap();
        let mut u = [0.0; 2];
        assert!(matches!(
            c.compute(0.0, &Gaussian::zeros(3), &mut u),
            Err(ControlError::Dimension { .. })
        ));
        let mut b = Gaussian::zeros(4);
        b.mean[0] = f64::NAN;
        assert_eq!(c.compute(0.0, &b, &mut u), Err(ControlError::NonFinite));
    }

    /// The ship controller drives the true (noisy) ship from rest to a goal
    /// and holds it there.
    #[test]
    fn ship_reaches_a_goal_in_closed_loop() {
        let params = ShipParams::paper(0.01);
        let ship = Ship::new(params.clone()).unwrap();
        for belief in [BeliefMode::Mean, BeliefMode::Sampled] {
            let cfg = PathIntegralConfig {
                belief,
                budget_us: 0.0,
                ..PathIntegralConfig::default()
            };
            let mut c = PathIntegralController::ship(params.clone(), ship_cost(), cfg).unwrap();
            c.set_goal(&[4.0, -3.0, 0.0, 0.0]);
            let mut x = [-3.0, 2.0, 0.0, 0.0];
            let mut rng = crate::rng::stream(9, 1);
            let mut u = [0.0; 2];
            let dt = 0.02;
            let mut b = Gaussian::diagonal(&x, &[0.05, 0.05, 0.05, 0.05]);
            for step in 0..400 {
                b.mean_mut().copy_from_slice(&x);
                c.compute(step as f64 * dt, &b, &mut u).unwrap();
                let mut next = [0.0; 4];
                crate::model::em_step(&ship, &x, &u, dt, &mut rng, &mut next);
                x = next;
            }
            let d = (x[0] - 4.0).hypot(x[1] + 3.0);
            assert!(d < 0.6, "{belief:?}: final distance {d}, state {x:?}");
        }
    }

    /// Over budget, the controller steps down its ladder (fewer samples) and
    /// still returns a control.
    #[test]
    fn degrades_gracefully_when_over_budget() {
        let cfg = PathIntegralConfig {
            samples: 32,
            belief: BeliefMode::Sampled,
            belief_samples: 8,
            budget_us: 1e-3, // impossible: every control is over budget
            ..PathIntegralConfig::default()
        };
        let mut c =
            PathIntegralController::ship(ShipParams::paper(0.01), ship_cost(), cfg).unwrap();
        c.set_goal(&[2.0, 0.0, 0.0, 0.0]);
        let b = Gaussian::diagonal(&[0.0, 0.0, 0.0, 0.0], &[0.1; 4]);
        let mut u = [0.0; 2];
        let mut levels = vec![];
        for i in 0..10 {
            c.compute(i as f64 * 0.01, &b, &mut u).unwrap();
            levels.push((c.stats().belief_samples, c.stats().samples));
            assert!(u[0] > 0.0, "pushes toward the goal");
        }
        assert_eq!(levels[0], (8, 32));
        assert_eq!(*levels.last().unwrap(), (1, 0));
        assert!(levels
            .windows(2)
            .all(|w| w[1].0 * (6 + w[1].1) <= w[0].0 * (6 + w[0].1)));
        assert_eq!(c.stats().over_budget, 10);
    }
}

#[cfg(test)]
mod lq_tests {
    use super::*;
    use crate::control::implicit::DiagonalQuadraticCost;
    use crate::model::affine::{LinearAffine, PathStructure};
    use nalgebra::{Matrix2, Vector2};

    fn double_integrator() -> LinearAffine {
        LinearAffine {
            m: 2,
            p: 1,
            r: 1,
            a: vec![0.0, 0.0, 1.0, 0.0],
            g: vec![0.0, 1.0],
            q: vec![1.0],
            structure: PathStructure::SecondOrder,
        }
    }

    /// Acceptance test at the controller level: receding horizon on ẍ = u
    /// with V = ½x₁², R = 1 gives the LQR law u = −(x₁ + √2 x₂) within 2 %
    /// (Euler with Δt = 0.01 shifts the gain by O(Δt)), for both gradients.
    #[test]
    fn receding_controller_gives_the_lqr_control() {
        for gradient in [GradientConfig::Analytic, GradientConfig::FiniteDifference] {
            let cfg = PathIntegralConfig {
                horizon_steps: 1000,
                dt: 0.01,
                control_cost: 1.0,
                u_max: 100.0,
                budget_us: 0.0,
                gradient,
                ..PathIntegralConfig::default()
            };
            let cost = DiagonalQuadraticCost::new(&[1.0, 0.0], &[0.0, 0.0]);
            let mut c = PathIntegralController::new(double_integrator(), cost, cfg).unwrap();
            let mut u = [0.0];
            for (i, x) in [[1.0, 0.5], [-0.7, 0.2], [0.3, -1.0]].iter().enumerate() {
                c.compute(i as f64 * 0.01, &Gaussian::diagonal(x, &[0.0, 0.0]), &mut u)
                    .unwrap();
                let lqr = -(x[0] + 2f64.sqrt() * x[1]);
                assert!(
                    (u[0] - lqr).abs() < 0.02 * lqr.abs(),
                    "{gradient:?} x={x:?}: {} vs {lqr}",
                    u[0]
                );
            }
        }
    }

    /// Shrinking horizon: at time t the control uses n = (t_f − t)/Δt steps and
    /// equals the discrete Riccati control of the remaining problem.
    #[test]
    fn shrinking_controller_follows_the_finite_horizon_riccati_control() {
        let (dt, tf, r) = (0.05, 2.0, 0.5);
        let cfg = PathIntegralConfig {
            horizon: HorizonMode::Shrinking,
            final_time: tf,
            horizon_steps: 100,
            dt,
            control_cost: r,
            u_max: 100.0,
            budget_us: 0.0,
            ..PathIntegralConfig::default()
        };
        let cost = DiagonalQuadraticCost::new(&[1.0, 0.2], &[3.0, 1.0]);
        let mut c = PathIntegralController::new(double_integrator(), cost, cfg).unwrap();
        let mut u = [0.0];
        for (k, x) in [(0usize, [1.3, -0.4]), (10, [0.6, -0.3]), (39, [0.1, 0.05])] {
            let t = k as f64 * dt;
            c.compute(t, &Gaussian::diagonal(&x, &[0.0, 0.0]), &mut u)
                .unwrap();
            let n = 40 - k;
            assert_eq!(c.stats().horizon_steps, n);
            // Discrete Riccati of the Euler problem (see the estimator tests).
            let ad = Matrix2::new(1.0, dt, 0.0, 1.0);
            let bd = Vector2::new(0.0, dt);
            let w = Matrix2::new(1.0, 0.0, 0.0, 0.2);
            let mut p = Matrix2::new(3.0, 0.0, 0.0, 1.0) + w * (dt / 2.0);
            for i in (0..n).rev() {
                let ci = if i == 0 { dt / 2.0 } else { dt };
                let s = dt * r + (bd.transpose() * p * bd)[(0, 0)];
                let kk = (bd.transpose() * p * ad) / s;
                p = w * ci + ad.transpose() * p * ad - (ad.transpose() * p * bd) * kk;
            }
            let expect = -(p * Vector2::new(x[0], x[1]))[1] / r;
            assert!(
                (u[0] - expect).abs() < 1e-6 * (1.0 + expect.abs()),
                "t={t}: {} vs {expect}",
                u[0]
            );
        }
        // Past the final time there is nothing left to control.
        c.compute(
            tf + 0.1,
            &Gaussian::diagonal(&[1.0, 0.0], &[0.0, 0.0]),
            &mut u,
        )
        .unwrap();
        assert_eq!(u[0], 0.0);
    }

    /// Belief-averaged ψ on a linear-quadratic problem: with ψ(x) ∝
    /// exp(−xᵀPx/(2γ)) and x ~ N(m, Σ), ∂ log E[ψ] = −(P/γ)(I + ΣP/γ)⁻¹ m, so
    /// u = −R⁻¹GᵀP(I + ΣP/γ)⁻¹m — not the certainty-equivalent −R⁻¹GᵀPm.
    #[test]
    fn belief_averaged_control_matches_the_gaussian_expectation() {
        let (dt, n, r) = (0.05, 40, 0.5);
        let model = double_integrator();
        let cost = DiagonalQuadraticCost::new(&[1.0, 0.2], &[3.0, 1.0]);
        let cfg = PathIntegralConfig {
            horizon_steps: n,
            dt,
            control_cost: r,
            u_max: 100.0,
            budget_us: 0.0,
            belief: BeliefMode::Sampled,
            belief_samples: MAX_BELIEF_SAMPLES,
            samples: 0,
            ..PathIntegralConfig::default()
        };
        let gamma = r; // Q = 1
        let mut c = PathIntegralController::new(model, cost, cfg).unwrap();
        // P₀ of the discretised problem (as above).
        let ad = Matrix2::new(1.0, dt, 0.0, 1.0);
        let bd = Vector2::new(0.0, dt);
        let w = Matrix2::new(1.0, 0.0, 0.0, 0.2);
        let mut p = Matrix2::new(3.0, 0.0, 0.0, 1.0) + w * (dt / 2.0);
        for i in (0..n).rev() {
            let ci = if i == 0 { dt / 2.0 } else { dt };
            let s = dt * r + (bd.transpose() * p * bd)[(0, 0)];
            let kk = (bd.transpose() * p * ad) / s;
            p = w * ci + ad.transpose() * p * ad - (ad.transpose() * p * bd) * kk;
        }
        let m = Vector2::new(0.8, -0.3);
        let sd = [0.1, 0.1];
        let sigma = Matrix2::new(sd[0] * sd[0], 0.0, 0.0, sd[1] * sd[1]);
        let expect = -(p
            * (Matrix2::identity() + sigma * p / gamma)
                .try_inverse()
                .unwrap()
            * m)[1]
            / r;
        let ce = -(p * m)[1] / r;
        let mut u = [0.0];
        let mut us = vec![];
        for i in 0..40 {
            c.compute(
                i as f64 * 1e-3,
                &Gaussian::diagonal(m.as_slice(), &sd),
                &mut u,
            )
            .unwrap();
            us.push(u[0]);
        }
        let mean = us.iter().sum::<f64>() / us.len() as f64;
        let sdev =
            (us.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (us.len() - 1) as f64).sqrt();
        let se = sdev / (us.len() as f64).sqrt();
        assert!(
            (mean - expect).abs() < 4.0 * se + 1e-3,
            "mean {mean} ± {se} vs {expect}"
        );
        // The belief matters here: certainty equivalence is clearly different.
        assert!(
            (ce - expect).abs() > 6.0 * se,
            "CE {ce} vs averaged {expect} (se {se})"
        );
    }
}
