//! Scenarios: what the pipeline needs to run a system, and the registry that
//! maps `run.scenario = "<name>"` to it.
//!
//! A scenario is a plug-in with two parts:
//! - [`Scenario`], registered by name: its typed parameter section (the
//!   TOML table named after the scenario, e.g. `[ship]`, deserialized with
//!   serde into [`Scenario::Params`]), a complete pipeline config that runs
//!   it (embedded in the binary, so `beliefbus run --scenario NAME` works
//!   from any directory), and [`Scenario::build`];
//! - [`System`], what `build` returns: its [`Dynamics`] — an SDE model
//!   (the [`SdeModel`] and [`SdeJacobians`] traits), on which every
//!   built-in backend runs, or a discrete-time system whose plant steps
//!   once per sensor sample ([`Plant::step`]) — optional capabilities (the
//!   control-affine view of paper 003 eq. 7 for the implicit path-integral
//!   controller), the plant simulation, the sensor channels, the prior and
//!   the initial state, and what the accuracy report and the route measure
//!   ("position" axes);
//! - the system's **own backends**, offered by name: a filter
//!   ([`System::filter_backend`]) or controller ([`System::controller`])
//!   that `filter.backend` / `control.backend` select exactly like the
//!   built-in ones, and its own report figures ([`System::run_metrics`],
//!   the report's `scenario_metrics.<scenario>` section).
//!
//! The built-in scenarios ([`builtin`]) register through the same API a
//! user's crate uses ([`Registry::with`]); the stages, the launcher and the
//! config never match on a scenario's name. A backend that needs a
//! capability asks [`System`] for it and the config reports a missing one
//! at validation, naming the scenario and the capability.

// The core modules under the names the scenario code uses.
use beliefbus_core::{model, rng};

pub mod backends;
pub mod builtin;
pub mod handle;
pub mod metrics;
pub mod registry;

pub use backends::{ControlContext, FilterContext};
pub use handle::{DynAffine, DynModel, PipelineModel};
pub use metrics::{BeliefView, ControlView, RunMetrics, TruthView};
pub use registry::{Registry, ScenarioInfo};

use crate::model::discrete::em_integrate;
use crate::model::{simulate_observation, Dims, SdeModel};
use crate::rng::SimRng;
use beliefbus_core::control::Controller;
use beliefbus_core::filter::BayesFilter;
use beliefbus_core::{MAX_CONTROL, MAX_NOISE, MAX_STATE};
use serde::de::DeserializeOwned;
use serde::Serialize;

/// What a scenario's constructor knows about the run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildContext {
    /// The sensor's sample period (s): models whose sampled observation
    /// noise derives from a continuous one need it (σ = G/√Δ).
    pub sample_dt: f64,
}

/// A system the pipeline can run, registered by [`Scenario::NAME`].
///
/// ```ignore
/// struct Pendulum;
/// impl Scenario for Pendulum {
///     type Params = PendulumParams;          // serde, #[serde(default)]
///     const NAME: &'static str = "pendulum";
///     const SUMMARY: &'static str = "torque-controlled damped pendulum";
///     const CONFIG: &'static str = include_str!("pendulum.toml");
///     fn defaults(_: &BuildContext) -> PendulumParams { PendulumParams::default() }
///     fn build(p: PendulumParams, _: &BuildContext) -> Result<Box<dyn System>, String> {
///         Ok(Box::new(PendulumSystem::new(p)?))
///     }
/// }
/// let registry = Registry::builtin().with::<Pendulum>();
/// ```
pub trait Scenario: 'static {
    /// The parameter section `[<NAME>]`, laid over [`Scenario::defaults`]:
    /// keys the config leaves out keep their default values. Unknown keys
    /// should be refused (`#[serde(deny_unknown_fields)]`).
    type Params: DeserializeOwned + Serialize;
    /// Registry name (`run.scenario`), lower case.
    const NAME: &'static str;
    /// One line for `beliefbus scenarios`.
    const SUMMARY: &'static str;
    /// A complete pipeline config (TOML) that runs this scenario: what
    /// `beliefbus run --scenario NAME` starts.
    const CONFIG: &'static str;
    /// The parameters when the config has no `[<NAME>]` section.
    fn defaults(ctx: &BuildContext) -> Self::Params;
    /// Build the system; an invalid parameter is an `Err` naming it.
    fn build(params: Self::Params, ctx: &BuildContext) -> Result<Box<dyn System>, String>;
    /// The JSON schema of `Params` for the generated configuration
    /// reference (`schemars::schema_for!(Params)` when `Params` derives
    /// `schemars::JsonSchema`); `None`: the section is not documented there.
    fn params_schema() -> Option<schemars::Schema> {
        None
    }
}

/// The schema of a parameter section with every sub-schema inlined (what
/// the configuration reference renders): a [`Scenario::params_schema`]
/// body for `Params` deriving `schemars::JsonSchema`.
pub fn inline_schema<T: schemars::JsonSchema>() -> Option<schemars::Schema> {
    Some(
        schemars::generate::SchemaSettings::draft2020_12()
            .with(|s| s.inline_subschemas = true)
            .into_generator()
            .into_root_schema_for::<T>(),
    )
}

/// One sensor channel of a scenario: which components of the model's
/// observation vector its samples carry.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SensorChannel {
    /// Channel id in the sensor sample.
    pub id: u32,
    /// A short name (`range_bearing`, `encoder`, ...).
    pub name: &'static str,
    /// Observation components, in sample order.
    pub components: Vec<usize>,
}

/// How a system evolves in time.
#[derive(Clone, Debug)]
pub enum Dynamics {
    /// Continuous time: an SDE model. The plant integrates it between
    /// sensor samples, and every built-in backend (`pf`, `ekf`, `ukf`,
    /// `chain`, `mppi`, `implicit`) runs on it.
    Sde(DynModel),
    /// Discrete time: the plant steps once per sensor sample
    /// ([`Plant::step`]); the step index is the sample's sequence number.
    /// The built-in backends need an SDE model and are refused at
    /// validation: the system runs its own ([`System::filter_backend`],
    /// [`System::controller`]).
    Discrete(DiscreteSpec),
}

/// What the pipeline must know of a discrete-time system: its name, its
/// dimensions and its observation noise (the σ a measurement without its
/// own has). Its transition and likelihood live in its own backends.
#[derive(Clone, Debug, PartialEq)]
pub struct DiscreteSpec {
    pub name: &'static str,
    /// State, observation and control dimensions (`noise` unused).
    pub dims: Dims,
    /// Observation noise std per component (length `dims.obs`).
    pub obs_std: Vec<f64>,
}

impl Dynamics {
    /// The model's name.
    pub fn name(&self) -> &str {
        match self {
            Dynamics::Sde(m) => m.name(),
            Dynamics::Discrete(d) => d.name,
        }
    }
    /// Its dimensions.
    pub fn dims(&self) -> Dims {
        match self {
            Dynamics::Sde(m) => m.dims(),
            Dynamics::Discrete(d) => d.dims,
        }
    }
    /// The SDE model (`None`: discrete time).
    pub fn sde(&self) -> Option<DynModel> {
        match self {
            Dynamics::Sde(m) => Some(m.clone()),
            Dynamics::Discrete(_) => None,
        }
    }
    /// Observation noise std into `std[..dims().obs]`.
    pub fn obs_std(&self, std: &mut [f64]) {
        match self {
            Dynamics::Sde(m) => m.obs_std(std),
            Dynamics::Discrete(d) => std[..d.obs_std.len()].copy_from_slice(&d.obs_std),
        }
    }
}

/// A built scenario: the model and what the pipeline needs around it.
pub trait System: Send + Sync {
    /// How it evolves: an SDE model (every built-in backend runs on it) or
    /// a discrete-time system (only its own backends run on it).
    fn dynamics(&self) -> Dynamics;

    /// The SDE model (`None` for a discrete-time system).
    fn sde_model(&self) -> Option<DynModel> {
        self.dynamics().sde()
    }

    /// State, observation and control dimensions.
    fn dims(&self) -> Dims {
        self.dynamics().dims()
    }

    /// The control-affine view (paper 003 eq. 7) the implicit path-integral
    /// controller needs; `None`: that controller is refused at validation.
    fn control_affine(&self) -> Option<DynAffine> {
        None
    }

    /// State components the accuracy report calls "position"
    /// (`rmse_position`) and the route's waypoints set (1 or 2 of them).
    fn position_axes(&self) -> &[usize];

    /// The position obtained by inverting one raw measurement (the
    /// no-filter reference `rmse_position_raw`), written into
    /// `out[..position_axes().len()]`; `false` when the sensor cannot be
    /// inverted (the report then has no raw reference).
    fn raw_position(&self, _y: &[f64], _out: &mut [f64]) -> bool {
        false
    }

    /// The true initial state when `plant.initial_state` is not given.
    fn initial_state(&self) -> Vec<f64>;

    /// The filter's prior (mean, per-component std) when `filter.prior_mean`
    /// / `filter.prior_std` are not given.
    fn prior(&self) -> (Vec<f64>, Vec<f64>);

    /// The sensor channels (the ingest channel map when `ingest.channels`
    /// is not given). Default: channel 0 carries the whole observation.
    fn sensor_channels(&self) -> Vec<SensorChannel> {
        vec![SensorChannel {
            id: 0,
            name: "sensor",
            components: (0..self.dims().obs).collect(),
        }]
    }

    /// The simulated plant started at `x0` (seeded, integrating with steps
    /// of at most `max_dt`). Default: Euler–Maruyama on the model's SDE and
    /// its observation model; a discrete-time system must supply its own
    /// (the default then refuses to build).
    fn plant(&self, x0: &[f64], seed: u64, max_dt: f64) -> Result<Box<dyn Plant>, String> {
        match self.dynamics() {
            Dynamics::Sde(m) => Ok(Box::new(SdePlant::new(m, x0, seed, max_dt))),
            Dynamics::Discrete(d) => Err(format!(
                "the discrete-time system {} has no plant simulation (System::plant)",
                d.name
            )),
        }
    }

    /// Names of the filter backends this system supplies itself (config
    /// `filter.backend`), beside the built-in ones.
    fn filter_backends(&self) -> Vec<&'static str> {
        Vec::new()
    }

    /// Build its filter backend `name`: `None` when it offers no such
    /// backend, `Err` (one line) when the backend cannot be built from its
    /// settings. Called once at validation and once when the filter stage
    /// starts.
    fn filter_backend(
        &self,
        _name: &str,
        _ctx: &FilterContext,
    ) -> Option<Result<Box<dyn BayesFilter>, String>> {
        None
    }

    /// Names of the controllers this system supplies itself (config
    /// `control.backend`), beside the built-in ones.
    fn controller_backends(&self) -> Vec<&'static str> {
        Vec::new()
    }

    /// Build its controller `name` (as [`System::filter_backend`]).
    fn controller(
        &self,
        _name: &str,
        _ctx: &ControlContext,
    ) -> Option<Result<Box<dyn Controller>, String>> {
        None
    }

    /// The system's own figures for the run report (section
    /// `scenario_metrics.<scenario>`), fed with the truth, the beliefs and
    /// the controls the launcher sees; `None`: no section.
    fn run_metrics(&self) -> Option<Box<dyn RunMetrics>> {
        None
    }

    /// Solve the system's offline part (e.g. a POMDP policy its controller
    /// loads) and write it to `req.out`, or to the place its controller
    /// looks by default (`beliefbus solve <scenario>`); `None`: the system
    /// has nothing to solve.
    fn solve(&self, _req: SolveRequest) -> Option<Result<SolveOutcome, String>> {
        None
    }
}

/// What `beliefbus solve` asks of [`System::solve`].
pub struct SolveRequest<'a> {
    /// Where to write the result (`None`: the system's default place).
    pub out: Option<&'a std::path::Path>,
    /// Worker threads (0: the machine's parallelism).
    pub threads: usize,
    /// One-line progress messages.
    pub progress: &'a mut dyn FnMut(&str),
}

/// What [`System::solve`] produced.
#[derive(Clone, Debug, PartialEq)]
pub struct SolveOutcome {
    /// The file written.
    pub path: std::path::PathBuf,
    /// Wall time of the solve (s).
    pub seconds: f64,
    /// Figures worth printing (name, value), e.g. the solve's stages and
    /// the policy's lookup time.
    pub figures: Vec<(String, String)>,
}

impl std::fmt::Debug for dyn System {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "System({})", self.dynamics().name())
    }
}

/// The simulated true system behind the plant stage.
pub trait Plant: Send {
    /// The true state.
    fn state(&self) -> &[f64];
    /// The control in force.
    fn control(&self) -> &[f64];
    /// Apply `u` from now on (extra entries are ignored).
    fn set_control(&mut self, u: &[f64]);
    /// Integrate over `dt` seconds with the control in force.
    fn advance(&mut self, dt: f64);
    /// Draw a measurement of the current state into `y` (the model's
    /// observation dimension).
    fn measure(&mut self, y: &mut [f64]);
    /// A discrete-time plant's transition, once per sensor sample, after
    /// the control in force was set and before [`Plant::measure`]:
    /// x_k = F(x_{k−1}, u_{k−1}, w_k). Default: nothing (an SDE plant moves
    /// in [`Plant::advance`], which a discrete-time plant leaves empty).
    /// A multi-rate plant moves to the sample [`Plant::next_sample`]
    /// announced.
    fn step(&mut self) {}
    /// When the next sample is taken and on which channel. Default:
    /// [`NextSample::Periodic`], one channel every sensor period. A plant
    /// with several sensors at their own rates (odometry at 40 Hz and a
    /// laser at 5 Hz, an IMU and a GPS) announces each sample; the plant
    /// stage sleeps until its time, moves the plant there
    /// ([`Plant::advance`] with the controls in force, then
    /// [`Plant::step`]), and publishes [`Plant::measure`]'s components of
    /// that channel. The answer must not change until [`Plant::step`] is
    /// called.
    fn next_sample(&mut self) -> NextSample {
        NextSample::Periodic
    }
}

/// A plant's next sample ([`Plant::next_sample`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NextSample {
    /// One sample every `plant.sensor_rate_hz` on `plant.channel`, carrying
    /// the whole observation vector (or the scenario's single channel).
    Periodic,
    /// A sample of channel `channel` (an index into
    /// [`System::sensor_channels`]) measured `t` seconds after the plant
    /// started; times never decrease. [`Plant::measure`] then needs to
    /// fill only that channel's components.
    At { channel: usize, t: f64 },
    /// No more samples (a recorded drive that has ended): the plant idles
    /// until the run stops.
    Done,
}

/// RNG stream id of the plant (mixed with `run.seed`).
pub const PLANT_STREAM: u64 = 0x0050_4C41_4E54; // "PLANT"

/// The default plant: x ← x + f(x, u) h + F(x) √h ξ with h ≤ `max_dt`, and
/// y = g(x) + v.
#[derive(Debug)]
pub struct SdePlant<M: SdeModel> {
    model: M,
    x: [f64; MAX_STATE],
    u: [f64; MAX_CONTROL],
    rng: SimRng,
    max_dt: f64,
}

impl<M: SdeModel> SdePlant<M> {
    /// Start at `x0` with zero control.
    pub fn new(model: M, x0: &[f64], seed: u64, max_dt: f64) -> Self {
        let mut x = [0.0; MAX_STATE];
        x[..x0.len()].copy_from_slice(x0);
        Self {
            model,
            x,
            u: [0.0; MAX_CONTROL],
            rng: crate::rng::stream(seed, PLANT_STREAM),
            max_dt,
        }
    }

    /// The model.
    pub fn model(&self) -> &M {
        &self.model
    }
}

impl<M: SdeModel> Plant for SdePlant<M> {
    fn state(&self) -> &[f64] {
        &self.x[..self.model.dims().state]
    }
    fn control(&self) -> &[f64] {
        &self.u[..self.model.dims().control]
    }
    fn set_control(&mut self, u: &[f64]) {
        let n = self.model.dims().control.min(u.len());
        self.u[..n].copy_from_slice(&u[..n]);
    }
    fn advance(&mut self, dt: f64) {
        let d = self.model.dims();
        em_integrate(
            &self.model,
            &mut self.x[..d.state],
            &self.u[..d.control],
            dt,
            self.max_dt,
            &mut self.rng,
        );
    }
    fn measure(&mut self, y: &mut [f64]) {
        let d = self.model.dims();
        simulate_observation(&self.model, &self.x[..d.state], &mut self.rng, y);
    }
}

/// Whether F(x)F(x)ᵀ has full rank at `x` (the chain filter's Gaussian and
/// moment-matched kernels need noise on every coordinate).
pub fn full_rank_diffusion(model: &impl SdeModel, x: &[f64]) -> bool {
    let dims = model.dims();
    let (d, k) = (dims.state, dims.noise);
    let mut f = [0.0; MAX_STATE * crate::MAX_NOISE];
    model.diffusion(x, &mut f[..d * k]);
    let fm = nalgebra::DMatrix::from_column_slice(d, k, &f[..d * k]);
    let a = &fm * fm.transpose();
    let scale = a.diagonal().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    scale > 0.0
        && a.cholesky()
            .is_some_and(|c| c.l().diagonal().iter().all(|l| *l * *l > 1e-12 * scale))
}
