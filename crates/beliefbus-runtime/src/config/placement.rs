//! `refine.placement`: where the moving-frame chain versions put their
//! states (`docs/degenerate-chains.md`, "The live pipeline").

use serde::{Deserialize, Serialize};

/// How refine draws the states of a moving-frame version.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum Placement {
    /// Around the latest belief, N(x̂, (inflate·σ)²) of its own covariance;
    /// a fresh version every `publish_period_ms`.
    #[default]
    Belief,
    /// Around N(x̂, inflate² P∞), P∞ the steady-state posterior covariance
    /// of the model linearised at x̂ under the reference control and
    /// observed at the sensor rate (a discrete Riccati solve: data-free);
    /// between fresh versions (every `publish_period_ms`) the latest one
    /// is published again as a new lineage every `recenter_ms`, which the
    /// filter installs from its Gaussian belief: the frame is re-centred
    /// without building a chain. Meant for models whose noise enters
    /// through the velocities only.
    Steady,
}

/// The placement keys of `[refine]`.
pub(super) fn validate(r: &super::RefineConfig) -> Result<(), super::ConfigError> {
    use super::ConfigError;
    if !(r.recenter_ms.is_finite() && r.recenter_ms >= 0.0) {
        return Err(ConfigError::new("refine.recenter_ms", "must be >= 0"));
    }
    if r.placement == Placement::Steady && !r.moving_frame {
        return Err(ConfigError::new(
            "refine.placement",
            "\"steady\" places moving-frame versions: needs refine.moving_frame = true",
        ));
    }
    Ok(())
}
