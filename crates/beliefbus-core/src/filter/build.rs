//! Errors of building a filter backend from its config and prior.

use super::FilterError;

/// A config value out of range; `key` is the field name inside the
/// backend's config section (the pipeline prefixes its section path).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {problem}")]
pub struct ConfigError {
    pub key: &'static str,
    pub problem: String,
}

impl ConfigError {
    pub(crate) fn new(key: &'static str, problem: impl Into<String>) -> Self {
        Self {
            key,
            problem: problem.into(),
        }
    }
}

/// Why a filter could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BuildError {
    /// The config is invalid.
    #[error("filter config: {0}")]
    Config(#[from] ConfigError),
    /// The model, prior or start time is unusable.
    #[error("filter start: {0}")]
    Start(#[from] FilterError),
}

/// `v` must be finite and > 0.
pub(crate) fn positive(key: &'static str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(ConfigError::new(
            key,
            format!("must be positive and finite, got {v}"),
        ))
    }
}

/// Check the model's dimensions against the crate's compile-time maxima.
pub(crate) fn check_dims(dims: crate::model::Dims) -> Result<(), FilterError> {
    use crate::{MAX_CONTROL, MAX_NOISE, MAX_OBS, MAX_STATE};
    for (what, got, max) in [
        ("model state", dims.state, MAX_STATE),
        ("model noise", dims.noise, MAX_NOISE),
        ("model observation", dims.obs, MAX_OBS),
        ("model control", dims.control, MAX_CONTROL),
    ] {
        if got > max || (what == "model state" && got == 0) {
            return Err(FilterError::Dimension {
                what,
                got,
                expected: max,
            });
        }
    }
    Ok(())
}

/// RNG stream of the time-scale probe behind the step checks (mixed with
/// the filter's seed; the filter's own stream is untouched, so a check
/// changes no filter output).
pub const PROBE_STREAM: u64 = 0x5052_4f42; // "PROB"

/// Largest ρ·h an Euler–Maruyama step h may take (ρ the 99th-percentile
/// spectral radius of the drift Jacobian over the prior predictive,
/// [`crate::model::scale::probe`]). On a mode e^{λt} one EM step
/// multiplies by 1 + λh instead of e^{λh}: the rate is biased by
/// ≈ |λ|h/2 relatively, ≤ 10 % here at the 99th-percentile rate.
pub const EM_RATE_STEP: f64 = 0.2;

/// Largest ratio R of Euler–Maruyama's drift error to the model's own
/// diffusion over one time constant (see [`em_step_bound`]).
pub const EM_BIAS: f64 = 0.3;

/// The largest Euler–Maruyama step that neither misrepresents the fastest
/// rate nor shifts a particle cloud by a sizeable part of its own spread:
///
/// ```text
/// h ≤ min( EM_RATE_STEP / ρ₉₉,  EM_BIAS · 2 √(q ρ₅₀) / ā )
/// ```
///
/// with ρ₉₉ and ρ₅₀ the 99th percentile and median of the drift
/// Jacobian's spectral radius, ā the mean of ‖(∂f/∂x) f‖ over the probe's
/// points (a time average along the trajectories) and q the median
/// ‖F Fᵀ‖. One Euler step errs by ≈ ‖(∂f/∂x) f‖ h²/2, so over one typical
/// time constant 1/ρ₅₀ (1/(ρ₅₀ h) steps; errors older than that are
/// forgotten) by ā h/(2ρ₅₀), while the diffusion spreads a state by
/// √(q/ρ₅₀) over the same time: their ratio is R = ā h / (2 √(q ρ₅₀)).
/// Between two observations a bootstrap PF's cloud spreads only by the
/// model's noise; a drift error comparable to that spread moves the whole
/// cloud off the truth.
///
/// Evidence for EM_BIAS (PF-300, `beliefbus experiment chain-defaults
/// --param models=lorenz --param pf_max_dt=…`, 30 runs, seed 1;
/// stochastic Lorenz-63 observed in x, R = 114 h): error 7.02 at
/// h = 9.5 ms (R = 1.08, ρ₉₉h = 0.20), 1.72 at 5 ms (R = 0.57), 1.44 at
/// 3.5 ms (0.40), 1.34 at 2 ms (0.23), 1.31 with PF-1000 at 1 ms. Van der
/// Pol (`beliefbus experiment vanderpol`, 100–200 runs) shows no bias at
/// 10 ms: 0.345 vs 0.353 ± 0.013 at 2 ms (e = 0.2, R ≈ 0.12) and 0.1983
/// vs 0.1978 ± 0.004 (e = 0.1 with `configs/vanderpol.toml`'s prior,
/// R ≈ 0.24). Without diffusion (q = 0) only the rate bound applies.
pub fn em_step_bound(s: &crate::model::scale::TimeScales) -> f64 {
    let rate = if s.rate_p99 > 0.0 {
        EM_RATE_STEP / s.rate_p99
    } else {
        f64::INFINITY
    };
    let bias = if s.accel_mean > 0.0 && s.diffusion_median > 0.0 && s.rate_median > 0.0 {
        EM_BIAS * 2.0 * (s.diffusion_median * s.rate_median).sqrt() / s.accel_mean
    } else {
        f64::INFINITY
    };
    rate.min(bias)
}

/// Largest ρ·h of an RK4 substep (EKF moment equations, UKF sigma-point
/// flow): the covariance equation runs at rate 2ρ, and RK4's relative
/// error on e^{2λh} is ≈ (2|λ|h)⁵/120 < 1 % at ρh = 0.5 (stability would
/// allow ρh < 1.39).
pub const RK4_RATE_STEP: f64 = 0.5;

/// Which rule bounds an integration step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepRule {
    /// Euler–Maruyama ([`em_step_bound`]).
    EulerMaruyama,
    /// RK4 on moments or sigma points: ρ·h ≤ [`RK4_RATE_STEP`].
    Rk4,
}

/// The largest integration step `rule` accepts for `model` started from
/// `prior` (∞ for a drift-free model), and the measured time scales.
pub fn derived_step<M: crate::model::SdeModel + ?Sized>(
    model: &M,
    prior: &crate::belief::Gaussian,
    rule: StepRule,
    seed: u64,
) -> Result<(f64, crate::model::scale::TimeScales), FilterError> {
    let mut rng = crate::rng::stream(seed, PROBE_STREAM);
    let s = crate::model::scale::probe(model, prior, None, &mut rng)
        .map_err(|_| FilterError::Numerical("time-scale probe failed (prior or drift)"))?;
    let max = match rule {
        StepRule::EulerMaruyama => em_step_bound(&s),
        StepRule::Rk4 if s.rate_p99 > 0.0 => RK4_RATE_STEP / s.rate_p99,
        StepRule::Rk4 => f64::INFINITY,
    };
    Ok((max, s))
}

/// `step` (the config field `key`) must be within what `rule` accepts,
/// else a [`ConfigError`] that names the largest acceptable step. A step
/// that silently biases the dynamics is refused rather than used.
pub fn check_step<M: crate::model::SdeModel + ?Sized>(
    model: &M,
    prior: &crate::belief::Gaussian,
    key: &'static str,
    step: f64,
    rule: StepRule,
    seed: u64,
) -> Result<(), BuildError> {
    let (max, s) = derived_step(model, prior, rule, seed)?;
    if step <= max {
        return Ok(());
    }
    let why = match rule {
        StepRule::EulerMaruyama => format!(
            "Euler–Maruyama needs {key}·ρ ≤ {EM_RATE_STEP} and a drift error per time constant \
             below {EM_BIAS} of the model's own diffusion (mean |Jf| = {:.3e}, q = {:.3e})",
            s.accel_mean, s.diffusion_median
        ),
        StepRule::Rk4 => format!("RK4 needs {key}·ρ ≤ {RK4_RATE_STEP}"),
    };
    Err(ConfigError::new(
        key,
        format!(
            "{step} s is too coarse for model '{}': its drift Jacobian reaches spectral radius \
             ρ = {:.3} /s (99th percentile over trajectories from the prior) and {why}; use \
             {key} ≤ {max:.3e} s",
            model.name(),
            s.rate_p99
        ),
    )
    .into())
}
