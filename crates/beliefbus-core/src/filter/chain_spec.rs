//! [`ChainFilterSpec`]: a Markov-chain filter built from a model and a
//! prior alone, with δ, the state budget and the state placement derived
//! from the model instead of tuned per model.
//!
//! A chain filter needs a state set S_n (where), a time step δ (how far one
//! transition reaches) and a number of states n (how fine). The rules:
//!
//! ```text
//! time scale:  ρ₅₀ = median of max_i |λ_i(∂f/∂x)| over trajectories from the prior
//!              (model::scale::probe, run over the horizon)
//! δ:           δ = Δ_call / 2^j, the largest with ρ₅₀ δ ≤ 1          (CHAIN_RATE_STEP)
//! EM step:     h = min(Δ_call, build::em_step_bound)  (rate and drift-error bounds)
//! spread:      s_i = RMS over the updates of the posterior std of x_i right after the
//!              update, from a pilot bootstrap PF (PILOT_PARTICLES) on PILOT_RECORDS
//!              simulated records
//! cells:       side c_i = s_i / RESOLUTION; C = number of cells holding 99 % of
//!              COUNT_POINTS prior-predictive points (placement law without its uniform share)
//! budget:      n = ⌈C / (1 − uniform_fraction)⌉, clamped to [min_states, max_states]
//! placement:   predictive_even (chain::placement): oversample·n predictive points over the
//!              horizon, thinned to n by weighted sample elimination, Hilbert-ordered
//! chain:       advected moment-matched construction (ChainConfig::moment_matched.with_step(δ)),
//!              k = ⌈knn_c log n⌉ neighbours, flush bound flush_mass
//! ```
//!
//! Why these rules.
//! - **δ from ρ₅₀.** The advected chain moves every state by the RK4 flow
//!   over δ and spreads it by F Fᵀ δ (thesis eq. 2.5–2.7 with a common
//!   holding time). The kernel ignores how the flow's Jacobian shapes the
//!   covariance within one step, a relative error O(ρδ); ρ₅₀δ ≤ 1 keeps
//!   one step within about one e-fold of the typical rate. A *larger* δ is
//!   otherwise better: every step must land on existing states and adds
//!   numerical variance of order the state spacing squared, so fewer steps
//!   add less, and the cost per unit time is ∝ 1/δ. Evidence (Lorenz-63,
//!   5805 states, 50 runs): error 1.455 at δ = 0.025 s (ρ₅₀δ = 0.37),
//!   1.378 at 0.05 s (0.74), 1.480 at 0.1 s (1.47; 1.473 with twice the
//!   states, so the step, not the states, limits it). The thesis's
//!   per-state holding times Δt(z) = r²/(‖FFᵀ‖ + r‖f‖) (eq. 2.8) instead
//!   make δ ≤ min_z Δt(z) tiny (≈ r²/‖FFᵀ‖ on a fine chain), which is why a
//!   chain built with the bare [`crate::chain::ChainConfig`] defaults is
//!   slow. On Van der Pol the rule gives δ = Δ_call = 0.1 s (ρ₅₀ ≈ 3 /s),
//!   the hand-tuned value of the `vanderpol` experiment.
//! - **n from the posterior's spread after an update.** The filter's
//!   error cannot be below the posterior's spread, and states much finer
//!   than it are wasted: the cost per step is the support (states carrying
//!   posterior mass) times the out-degree. The narrowest posterior is the
//!   one right after an update, where the likelihood multiplies φ; its
//!   spread depends on the observation noise and period and the dynamics
//!   between observations, which the pilot PF measures on the model's own
//!   simulated records (data-free; the thesis suggests an EKF prediction
//!   for the same purpose, §3.3.3, but an EKF loses track on multimodal
//!   predictions). The chain needs cells of a fixed fraction of that spread
//!   over the whole region the prior predictive visits, hence the count of
//!   occupied cells. `RESOLUTION` = 1.5 cells per posterior standard
//!   deviation: on Van der Pol (the `vanderpol` experiment's setting, 50
//!   runs against PF-300) 1 gives 676 states and an error above PF-300's
//!   (+0.0105 ± 0.0088), 1.5 gives 1464 states and PF-300's error
//!   (+0.003 ± 0.011) at 0.27× its CPU, 2 gives 2513 states and no smaller
//!   error at 0.64×. Lorenz-63 was not used to choose it.
//!
//! The measured figures (chain built with these defaults against a
//! 300-particle PF on Van der Pol and stochastic Lorenz-63) are in
//! `docs/chain-defaults.md` and come from `beliefbus experiment
//! chain-defaults`.

use crate::belief::Gaussian;
use crate::chain::placement::{draw_prior, predictive_even, predictive_points, prior_sampler};
use crate::chain::{Chain, ChainConfig, ChainError, NearRule};
use crate::filter::build::{self, BuildError};
use crate::filter::chain_filter::ChainFilter;
use crate::filter::pf::PfConfig;
use crate::filter::BayesFilter;
use crate::model::discrete::em_integrate;
use crate::model::scale::{self, ScaleError, TimeScales};
use crate::model::{simulate_observation, Measurement, SdeModel};
use crate::rng::stream;
use std::collections::HashMap;

/// Largest ρ·δ of the chain's step (see the module doc).
pub const CHAIN_RATE_STEP: f64 = 1.0;
/// Cells per posterior standard deviation along each axis.
pub const RESOLUTION: f64 = 1.5;
/// Particles of the pilot PF that measures the posterior's spread.
pub const PILOT_PARTICLES: usize = 1000;
/// Simulated records the pilot PF runs.
pub const PILOT_RECORDS: usize = 2;
/// Prior-predictive points whose occupied cells set the budget.
pub const COUNT_POINTS: usize = 40_000;
/// Share of those points the counted cells must hold.
pub const COUNT_MASS: f64 = 0.99;

/// RNG streams of the spec (mixed with its seed).
const PROBE: u64 = 0xc5_01;
const PILOT: u64 = 0xc5_02;
const COUNT: u64 = 0xc5_03;
const PLACE: u64 = 0xc5_04;

/// Why a chain filter could not be built from a spec.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpecError {
    /// A field of the spec is out of range.
    #[error("chain filter spec: {0}")]
    Config(#[from] build::ConfigError),
    /// The model's time scales could not be measured.
    #[error(transparent)]
    Scale(#[from] ScaleError),
    /// The pilot particle filter could not run.
    #[error("chain filter spec: pilot PF: {0}")]
    Pilot(#[from] BuildError),
    /// Chain construction failed.
    #[error(transparent)]
    Chain(#[from] ChainError),
}

/// What a library user states to get a chain filter: the time between
/// the filter's calls, how long it will run, and optional overrides of
/// every derived value. `Default` has period 0.1 s and horizon 10 s.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainFilterSpec {
    /// Time between the filter's calls (predict and/or update), Δ_call
    /// (s): δ is Δ_call / 2^j, so every call is a whole number of steps.
    pub period: f64,
    /// An observation every `obs_every`-th call (the pilot PF's schedule;
    /// the filter itself takes updates whenever they come).
    pub obs_every: usize,
    /// How long the filter runs from the prior (s): the states cover the
    /// prior predictive up to this time.
    pub horizon: f64,
    /// δ instead of the derived one.
    pub delta: Option<f64>,
    /// Number of states instead of the derived one.
    pub states: Option<usize>,
    /// Cells per posterior standard deviation ([`RESOLUTION`]).
    pub resolution: f64,
    /// Candidates per kept state of the placement.
    pub oversample: usize,
    /// Share of the states uniform on S (exploration; thesis §3.3.3).
    pub uniform_fraction: f64,
    /// k = ⌈knn_c log n⌉ neighbours per state.
    pub knn_c: f64,
    /// Posterior mass an update may flush (see [`ChainFilter`]).
    pub flush_mass: f64,
    /// Bounds of the derived state budget.
    pub min_states: usize,
    pub max_states: usize,
    /// Seed of every random draw of the construction.
    pub seed: u64,
}

impl Default for ChainFilterSpec {
    fn default() -> Self {
        Self {
            period: 0.1,
            obs_every: 1,
            horizon: 10.0,
            delta: None,
            states: None,
            resolution: RESOLUTION,
            oversample: 3,
            uniform_fraction: 0.1,
            knn_c: 1.5,
            flush_mass: 1e-4,
            min_states: 200,
            max_states: 200_000,
            seed: 0,
        }
    }
}

/// The values a spec resolved to for one model and prior.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainPlan {
    /// The chain's step δ (s).
    pub delta: f64,
    /// Number of states n.
    pub states: usize,
    /// Euler–Maruyama step of the placement trajectories and the pilot (s).
    pub sim_dt: f64,
    /// The model's measured time scales.
    pub scales: TimeScales,
    /// Pilot posterior standard deviation per coordinate (RMS over time);
    /// empty when `states` was given.
    pub posterior_std: Vec<f64>,
    /// Occupied cells C (0 when `states` was given).
    pub cells: usize,
}

impl ChainFilterSpec {
    /// The defaults with the given call period and horizon.
    pub fn new(period: f64, horizon: f64) -> Self {
        Self {
            period,
            horizon,
            ..Self::default()
        }
    }

    fn validate(&self) -> Result<(), build::ConfigError> {
        build::positive("period", self.period)?;
        build::positive("horizon", self.horizon)?;
        build::positive("resolution", self.resolution)?;
        build::positive("knn_c", self.knn_c)?;
        if let Some(d) = self.delta {
            build::positive("delta", d)?;
        }
        if self.obs_every == 0 {
            return Err(build::ConfigError::new("obs_every", "must be at least 1"));
        }
        if !(0.0..1.0).contains(&self.uniform_fraction) {
            return Err(build::ConfigError::new(
                "uniform_fraction",
                "must be in [0, 1)",
            ));
        }
        if !(0.0..1.0).contains(&self.flush_mass) {
            return Err(build::ConfigError::new("flush_mass", "must be in [0, 1)"));
        }
        if self.min_states == 0 || self.min_states > self.max_states {
            return Err(build::ConfigError::new(
                "min_states",
                "must be ≥ 1 and ≤ max_states",
            ));
        }
        Ok(())
    }

    /// Resolve δ, the state budget and the integration step for `model`
    /// started from `prior` (the rules of the module doc).
    pub fn plan<M: SdeModel + Clone>(
        &self,
        model: &M,
        prior: &Gaussian,
    ) -> Result<ChainPlan, SpecError> {
        self.validate()?;
        let scales = scale::probe(
            model,
            prior,
            Some(self.horizon),
            &mut stream(self.seed, PROBE),
        )?;
        let sim_dt = self.period.min(build::em_step_bound(&scales));
        let delta = match self.delta {
            Some(d) => d,
            None => {
                let mut d = self.period;
                while d * scales.rate_median > CHAIN_RATE_STEP && d > self.period * 1e-6 {
                    d *= 0.5;
                }
                d
            }
        };
        let (states, posterior_std, cells) = match self.states {
            Some(n) => (n, vec![], 0),
            None => {
                let s = self.pilot_spread(model, prior, sim_dt)?;
                let cell: Vec<f64> = s.iter().map(|v| v / self.resolution).collect();
                let c = self.occupied_cells(model, prior, sim_dt, &cell)?;
                let n = (c as f64 / (1.0 - self.uniform_fraction)).ceil() as usize;
                (n.clamp(self.min_states, self.max_states), s, c)
            }
        };
        Ok(ChainPlan {
            delta,
            states,
            sim_dt,
            scales,
            posterior_std,
            cells,
        })
    }

    /// Build the chain filter (plan, place, construct), reset to `prior`
    /// at `t0`.
    pub fn build<M: SdeModel + Clone>(
        &self,
        model: M,
        prior: &Gaussian,
        t0: f64,
    ) -> Result<ChainFilter<M>, SpecError> {
        let plan = self.plan(&model, prior)?;
        self.build_planned(model, prior, t0, &plan)
    }

    /// Build from a plan already resolved by [`Self::plan`].
    pub fn build_planned<M: SdeModel + Clone>(
        &self,
        model: M,
        prior: &Gaussian,
        t0: f64,
        plan: &ChainPlan,
    ) -> Result<ChainFilter<M>, SpecError> {
        self.validate()?;
        let d = prior.dim;
        let pts = predictive_even(
            &model,
            prior,
            self.horizon,
            plan.states,
            self.oversample,
            self.uniform_fraction,
            plan.sim_dt,
            &mut stream(self.seed, PLACE),
        )?;
        let pts = crate::chain::order::hilbert_sorted(&pts, d);
        let cfg = ChainConfig::moment_matched(d)
            .with_step(plan.delta)
            .with_near(NearRule::Knn { c: self.knn_c });
        let chain = Chain::batch(&model, cfg, &pts)?;
        let mut f = ChainFilter::new(model, chain, self.period)?;
        f.set_flush_mass(self.flush_mass);
        f.reset(t0, prior);
        Ok(f)
    }

    /// RMS over the updates of the pilot PF's posterior standard deviation
    /// right after the update, per coordinate.
    fn pilot_spread<M: SdeModel + Clone>(
        &self,
        model: &M,
        prior: &Gaussian,
        sim_dt: f64,
    ) -> Result<Vec<f64>, SpecError> {
        let dims = model.dims();
        let (d, m) = (dims.state, dims.obs);
        let sampler = prior_sampler(prior)?;
        let u = vec![0.0; dims.control];
        let calls = ((self.horizon / self.period).round() as usize).max(1);
        let mut var = vec![0.0; d];
        let mut count = 0usize;
        let mut x = vec![0.0; d];
        let mut y = vec![0.0; m];
        for r in 0..PILOT_RECORDS {
            let mut rng = stream(self.seed, PILOT + 0x100 * r as u64);
            let cfg = PfConfig {
                particles: PILOT_PARTICLES,
                max_dt: sim_dt,
                seed: self.seed.wrapping_add(r as u64),
                ..PfConfig::default()
            }
            .with_derived_step(model, prior)
            .map_err(BuildError::from)?;
            let mut pf = cfg.build(model.clone(), prior, 0.0)?;
            draw_prior(model, &sampler, &mut rng, &mut x);
            for k in 1..=calls {
                em_integrate(model, &mut x, &u, self.period, sim_dt, &mut rng);
                model.bounds().project(&mut x);
                let _ = pf.predict(k as f64 * self.period, &u);
                if k % self.obs_every == 0 {
                    simulate_observation(model, &x, &mut rng, &mut y);
                    let _ = pf.update(&Measurement::full(&y));
                    let b = pf.belief();
                    for (i, v) in var.iter_mut().enumerate() {
                        *v += b.cov_at(i, i);
                    }
                    count += 1;
                }
            }
        }
        Ok(var.iter().map(|v| (v / count as f64).sqrt()).collect())
    }

    /// Number of cells of side `cell` (per axis) that hold [`COUNT_MASS`]
    /// of [`COUNT_POINTS`] prior-predictive points.
    fn occupied_cells<M: SdeModel>(
        &self,
        model: &M,
        prior: &Gaussian,
        sim_dt: f64,
        cell: &[f64],
    ) -> Result<usize, SpecError> {
        let d = prior.dim;
        let pts = predictive_points(
            model,
            prior,
            self.horizon,
            COUNT_POINTS,
            0.0,
            sim_dt,
            &mut stream(self.seed, COUNT),
        )?;
        let mut counts: HashMap<Vec<i64>, usize> = HashMap::new();
        for p in pts.chunks_exact(d) {
            let key: Vec<i64> = p
                .iter()
                .zip(cell)
                .map(|(x, c)| (x / c.max(1e-300)).floor() as i64)
                .collect();
            *counts.entry(key).or_insert(0) += 1;
        }
        let mut c: Vec<usize> = counts.into_values().collect();
        c.sort_unstable_by(|a, b| b.cmp(a));
        let need = (COUNT_MASS * COUNT_POINTS as f64).ceil() as usize;
        let mut acc = 0;
        for (i, v) in c.iter().enumerate() {
            acc += v;
            if acc >= need {
                return Ok(i + 1);
            }
        }
        Ok(c.len())
    }
}

#[cfg(test)]
#[path = "chain_spec_tests.rs"]
mod tests;
