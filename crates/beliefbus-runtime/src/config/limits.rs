//! Hard upper limits on every config value that sizes memory or work, or
//! that becomes a `Duration`.
//!
//! A config is data a user (or a script, or a hostile `--set`) hands to a
//! process that may run as root with SCHED_FIFO and mlockall: a value that
//! allocates a terabyte, locks a gigabyte, or asks for 10¹² integration
//! steps per second must be refused at validation (exit 2, key named)
//! instead of aborting or wedging a stage after the pipeline started.
//!
//! Three kinds of bound (`docs/security.md` lists them):
//! - **memory**: a structure sized by the config (the particle filter's
//!   particle buffers, MPPI's rollouts, the chain snapshot channel's shared
//!   memory, which the filter maps and may lock) may take at most
//!   [`MEM_SHARE_DIVISOR`]⁻¹ of the machine's physical memory;
//! - **work**: one filter step or control computation may cost at most
//!   [`STEP_WORK_MAX`] elementary operations (one state component advanced
//!   one step for one particle or rollout) — orders of magnitude above
//!   anything that meets a sensor period, far below a stall; the plant's
//!   integration step is at least [`MIN_INTEGRATION_DT`];
//! - **time**: durations at most [`MAX_DURATION_S`], periods, timeouts and
//!   budgets at most [`MAX_PERIOD_S`], all representable as `Duration`
//!   (checked with `Duration::try_from_secs_f64`, never a panic).

use super::{ConfigError, PipelineConfig};
use crate::ipc::StageKind;
use std::time::Duration;

/// A config-sized structure may use at most 1/32 of physical memory.
pub const MEM_SHARE_DIVISOR: u64 = 32;
/// Elementary operations one filter step or one control computation may
/// cost at most.
pub const STEP_WORK_MAX: f64 = 2e9;
/// Finest plant integration step (s): 10⁶ Euler–Maruyama steps per second
/// of simulated time is already most of a core.
pub const MIN_INTEGRATION_DT: f64 = 1e-6;
/// Longest catch-up burst of the plant (periods): with the burst margin it
/// fits the sensor and observation channels' largest queue (256).
pub const MAX_CATCH_UP_PERIODS: u64 = 200;
/// Highest sensor rate (Hz).
pub const MAX_SENSOR_RATE_HZ: f64 = 1e5;
/// Longest run (s): one year.
pub const MAX_DURATION_S: f64 = 365.0 * 86_400.0;
/// Longest period, timeout, age or budget (s): one hour.
pub const MAX_PERIOD_S: f64 = 3_600.0;
/// Longest prediction substep count per sensor period of a filter backend.
pub const MAX_SUBSTEPS: f64 = 1e5;
/// Samples in one publisher's data segment of the chain channel:
/// max_subscribers × (buffer + borrowed) + history + loaned = 3 × (1 + 2) +
/// 1 + 2 (iceoryx2 0.10 `required_amount_of_samples_per_data_segment`).
pub const CHAIN_SEGMENT_SAMPLES: u64 = 12;

pub use crate::rt::sched::physical_memory;

/// The memory one config-sized structure may take (bytes).
pub fn memory_cap() -> u64 {
    physical_memory() / MEM_SHARE_DIVISOR
}

fn mib(b: f64) -> String {
    format!("{:.0} MiB", b / (1024.0 * 1024.0))
}

fn mem(key: &str, bytes: f64, what: &str) -> Result<(), ConfigError> {
    let cap = memory_cap() as f64;
    if bytes.is_finite() && bytes <= cap {
        Ok(())
    } else {
        Err(ConfigError::new(
            key,
            format!(
                "{what} would take {} (limit {}: 1/{MEM_SHARE_DIVISOR} of this machine's memory)",
                mib(bytes),
                mib(cap)
            ),
        ))
    }
}

fn work(key: &str, ops: f64, what: &str) -> Result<(), ConfigError> {
    if ops.is_finite() && ops <= STEP_WORK_MAX {
        Ok(())
    } else {
        Err(ConfigError::new(
            key,
            format!("{what} would cost {ops:.3e} operations (limit {STEP_WORK_MAX:.0e})"),
        ))
    }
}

/// `v` in units of `unit` seconds (1e-6 for a key in µs) at most `max_s`
/// seconds, as a valid `Duration`.
pub fn seconds_in(key: &str, v: f64, unit: f64, max_s: f64) -> Result<Duration, ConfigError> {
    let s = v * unit;
    let num = |x: f64| {
        if x.abs() < 1e9 {
            x.to_string()
        } else {
            format!("{x:e}")
        }
    };
    if !(s <= max_s) {
        return Err(ConfigError::new(
            key,
            format!("must be at most {}, got {}", num(max_s / unit), num(v)),
        ));
    }
    Duration::try_from_secs_f64(s)
        .map_err(|e| ConfigError::new(key, format!("not a duration ({e}), got {}", num(v))))
}

/// `v` seconds at most `max_s`, as a valid `Duration`.
pub fn seconds(key: &str, v: f64, max_s: f64) -> Result<Duration, ConfigError> {
    seconds_in(key, v, 1.0, max_s)
}

/// The chain snapshot channel's shared memory for `n` states of dimension
/// `dim` with the k-NN rule's constant `c` (bytes per publisher).
pub fn chain_bytes(dim: usize, n: usize, c: f64) -> f64 {
    let k = ((c * (n as f64).ln()).ceil())
        .max((crate::chain::moment_equations(dim) + 1) as f64)
        .min(n.saturating_sub(1) as f64);
    let nnz = n as f64 * k;
    // Words of a snapshot (as `chain::snapshot::words_needed`, in floating
    // point so a huge value cannot overflow before it is refused).
    let words = if nnz <= usize::MAX as f64 / 4.0 {
        crate::chain::snapshot::words_needed(dim, n, nnz as usize) as f64
    } else {
        f64::INFINITY
    };
    words * 8.0 * CHAIN_SEGMENT_SAMPLES as f64
}

impl PipelineConfig {
    /// Check every hard limit (called by `validate` after the plain range
    /// checks, so every value here is finite and positive where it must be).
    pub(super) fn validate_limits(&self) -> Result<(), ConfigError> {
        // Long on purpose: one flat check per hard limit, each with its key
        // and the reason for the limit in its message.
        let dims = self.dims()?;
        let (d, c) = (dims.state as f64, dims.control as f64);
        let sample_dt = self.sample_dt();
        let r = &self.run;
        seconds("run.duration_s", r.duration_s, MAX_DURATION_S)?;
        seconds("run.warmup_s", r.warmup_s, MAX_DURATION_S)?;
        seconds("run.stats_period_s", r.stats_period_s, MAX_PERIOD_S)?;

        if self.plant.integration_dt < MIN_INTEGRATION_DT {
            return Err(ConfigError::new(
                "plant.integration_dt",
                format!(
                    "must be at least {MIN_INTEGRATION_DT} s (a finer step is a runaway \
                     real-time loop), got {}",
                    self.plant.integration_dt
                ),
            ));
        }
        seconds("ingest.max_age_s", self.ingest.max_age_s, MAX_PERIOD_S)?;

        let f = &self.filter;
        seconds_in(
            "filter.max_obs_age_us",
            f.max_obs_age_us,
            1e-6,
            MAX_PERIOD_S,
        )?;
        seconds_in(
            "filter.chain.prepare_budget_us",
            f.chain.prepare_budget_us,
            1e-6,
            MAX_PERIOD_S,
        )?;
        // Every backend's section is held to the limits, selected or not:
        // a value that could never run is refused wherever it is written.
        let n = f.pf.particles as f64;
        // x and its alternate (2d), log weights, weights, new log weights,
        // ancestors: (2d + 4) words per particle.
        mem(
            "filter.pf.particles",
            n * (2.0 * d + 4.0) * 8.0,
            "the particle buffers",
        )?;
        for (key, max_dt) in [
            ("filter.pf.max_dt", f.pf.max_dt),
            ("filter.ekf.max_dt", f.ekf.max_dt),
            ("filter.ukf.max_dt", f.ukf.max_dt),
        ] {
            let substeps = (sample_dt / max_dt).ceil().max(1.0);
            if substeps > MAX_SUBSTEPS {
                return Err(ConfigError::new(
                    key,
                    format!(
                        "gives {substeps:.3e} prediction substeps per sensor period \
                         (limit {MAX_SUBSTEPS:.0e})"
                    ),
                ));
            }
        }
        let substeps = (sample_dt / f.pf.max_dt).ceil().max(1.0);
        work(
            "filter.pf.particles",
            n * substeps * d,
            "one prediction step",
        )?;

        let ctl = &self.control;
        seconds_in(
            "control.max_belief_age_us",
            ctl.max_belief_age_us,
            1e-6,
            MAX_PERIOD_S,
        )?;
        {
            let m = &ctl.mppi;
            let (k, t) = (m.samples as f64, m.horizon_steps as f64);
            if t * m.dt > MAX_PERIOD_S {
                return Err(ConfigError::new(
                    "control.mppi.horizon_steps",
                    format!("the horizon must be at most {MAX_PERIOD_S} s"),
                ));
            }
            // Rollout states and controls, noise, costs and weights.
            mem(
                "control.mppi.samples",
                k * (t * (d + 2.0 * c) + 2.0) * 8.0,
                "the rollouts",
            )?;
            work(
                "control.mppi.samples",
                k * t * (d + c),
                "one control computation",
            )?;
        }
        {
            let p = &ctl.implicit;
            seconds_in(
                "control.implicit.budget_us",
                p.budget_us,
                1e-6,
                MAX_PERIOD_S,
            )?;
            if p.horizon_steps as f64 * p.dt > MAX_PERIOD_S {
                return Err(ConfigError::new(
                    "control.implicit.horizon_steps",
                    format!("the horizon must be at most {MAX_PERIOD_S} s"),
                ));
            }
            let t = p.horizon_steps as f64;
            let samples = (p.samples as f64).max(1.0);
            let beliefs = (p.belief_samples as f64).max(1.0);
            // Paths of n steps (state and control per step), the
            // Newton system of one path (n·c)².
            let path = t * (d + c);
            for (key, v) in [
                ("control.implicit.samples", samples),
                ("control.implicit.belief_samples", beliefs),
            ] {
                mem(key, v * path * 8.0, "the sampled paths")?;
            }
            mem(
                "control.implicit.horizon_steps",
                (t * c).powi(2) * 8.0,
                "the Newton system",
            )?;
            work(
                "control.implicit.samples",
                samples * beliefs * path * (p.newton_max_iter.max(1) as f64),
                "one control computation",
            )?;
            work(
                "control.implicit.newton_max_iter",
                p.newton_max_iter as f64 * (t * c).powi(3),
                "one minimisation",
            )?;
        }

        let rf = &self.refine;
        for (key, v) in [
            ("refine.period_ms", rf.period_ms),
            ("refine.publish_period_ms", rf.publish_period_ms),
        ] {
            seconds_in(key, v, 1e-3, MAX_PERIOD_S)?;
        }
        seconds("refine.horizon_s", rf.horizon_s, MAX_PERIOD_S)?;
        // The snapshot channel is created whatever the filter backend (refine
        // always runs), so it is always held to the limit.
        let dim = dims.state;
        let with_default_c = chain_bytes(
            dim,
            rf.max_states,
            super::refine::default_knn_c().min(rf.knn_c),
        );
        let chain_key = if with_default_c <= memory_cap() as f64 {
            "refine.knn_c"
        } else {
            "refine.max_states"
        };
        mem(
            chain_key,
            chain_bytes(dim, rf.max_states, rf.knn_c),
            "the chain snapshot channel",
        )?;

        for kind in StageKind::ALL {
            let s = self.stages.get(kind);
            let key = format!("stages.{}", kind.name());
            seconds_in(&format!("{key}.budget_us"), s.budget_us, 1e-6, MAX_PERIOD_S)?;
            seconds_in(&format!("{key}.spin_us"), s.spin_us as f64, 1e-6, 1.0)?;
            let p = &s.restart;
            for (k, v) in [
                ("backoff_ms", p.backoff_ms),
                ("max_backoff_ms", p.max_backoff_ms),
                (
                    "heartbeat_timeout_ms",
                    p.heartbeat_timeout_ms.unwrap_or(0.0),
                ),
            ] {
                seconds_in(&format!("{key}.restart.{k}"), v, 1e-3, MAX_PERIOD_S)?;
            }
            seconds(
                &format!("{key}.restart.reset_after_s"),
                p.reset_after_s,
                MAX_DURATION_S,
            )?;
        }
        Ok(())
    }
}
