//! `[stages.<name>.restart]`: the supervisor's restart policy and
//! heartbeat deadline (the decisions that use it are in
//! `pipeline::supervisor`).

use serde::{Deserialize, Serialize};
use std::time::Duration;

/// When a dead stage is restarted.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum RestartOn {
    /// After a crash or a hang (not after a clean exit 0).
    #[default]
    Failure,
    /// After any exit.
    Always,
    /// Never: the run ends.
    Never,
}

/// `[stages.<name>.restart]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RestartPolicy {
    #[serde(default)]
    pub on: RestartOn,
    /// Delay before the first restart of a series (ms).
    #[serde(default = "default_backoff")]
    pub backoff_ms: f64,
    /// Longest delay (ms).
    #[serde(default = "default_max_backoff")]
    pub max_backoff_ms: f64,
    /// An incarnation that lived this long resets the backoff (s).
    #[serde(default = "default_reset_after")]
    pub reset_after_s: f64,
    /// Restarts allowed over the run (absent: unlimited).
    #[serde(default)]
    pub max_restarts: Option<u32>,
    /// Heartbeat deadline (ms); absent: `max(5 · run.stats_period_s, 2 s)`.
    #[serde(default)]
    pub heartbeat_timeout_ms: Option<f64>,
}

fn default_backoff() -> f64 {
    20.0
}
fn default_max_backoff() -> f64 {
    2000.0
}
fn default_reset_after() -> f64 {
    10.0
}

impl Default for RestartPolicy {
    fn default() -> Self {
        Self {
            on: RestartOn::Failure,
            backoff_ms: default_backoff(),
            max_backoff_ms: default_max_backoff(),
            reset_after_s: default_reset_after(),
            max_restarts: None,
            heartbeat_timeout_ms: None,
        }
    }
}

/// A policy problem: (key below `restart.`, problem).
pub type PolicyError = (&'static str, String);

impl RestartPolicy {
    /// Check every value.
    pub fn validate(&self) -> Result<(), PolicyError> {
        let nonneg = |k: &'static str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err((k, format!("must be finite and >= 0, got {v}")))
            }
        };
        nonneg("backoff_ms", self.backoff_ms)?;
        nonneg("max_backoff_ms", self.max_backoff_ms)?;
        nonneg("reset_after_s", self.reset_after_s)?;
        if self.max_backoff_ms < self.backoff_ms {
            return Err((
                "max_backoff_ms",
                format!(
                    "must be >= backoff_ms ({}), got {}",
                    self.backoff_ms, self.max_backoff_ms
                ),
            ));
        }
        if let Some(h) = self.heartbeat_timeout_ms {
            if !(h.is_finite() && h > 0.0) {
                return Err((
                    "heartbeat_timeout_ms",
                    format!("must be positive and finite, got {h}"),
                ));
            }
        }
        Ok(())
    }

    /// The heartbeat deadline for a stats period of `stats_period_s`.
    pub fn heartbeat_timeout(&self, stats_period_s: f64) -> Duration {
        match self.heartbeat_timeout_ms {
            Some(ms) => Duration::from_secs_f64(ms * 1e-3),
            None => Duration::from_secs_f64((5.0 * stats_period_s).max(2.0)),
        }
    }

    /// Delay before the `n`-th consecutive restart (n ≥ 1).
    pub fn backoff(&self, n: u32) -> Duration {
        let exp = n.saturating_sub(1).min(30) as i32;
        let ms = (self.backoff_ms * 2f64.powi(exp)).min(self.max_backoff_ms);
        Duration::from_secs_f64(ms * 1e-3)
    }
}
