//! `[filter.chain.stale]`: when the chain filter's belief counts as stale
//! and the fallback filter's is published instead (the guard that applies
//! it is `stage::chain_guard`).

use serde::{Deserialize, Serialize};

/// `[filter.chain.stale]`: when the chain's belief is stale (see the module
/// docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct StaleConfig {
    /// Run the fallback filter and publish it when the chain is stale
    /// (false: the chain's belief always goes out, as before).
    pub enabled: bool,
    /// Moving frame: a version installed longer ago than this is stale
    /// (0: never by age).
    pub max_age_ms: f64,
    /// Observations the evidence average spans (its time constant).
    pub evidence_window: f64,
    /// Stale when the chain's average predictive log-likelihood falls this
    /// many nats per observation below the fallback's (0: criterion off).
    pub evidence_margin: f64,
}

impl Default for StaleConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            max_age_ms: 1000.0,
            evidence_window: 20.0,
            evidence_margin: 2.0,
        }
    }
}

impl StaleConfig {
    /// Check every field; the error names the key under `filter.chain.stale`.
    pub fn validate(&self) -> Result<(), (&'static str, &'static str)> {
        let ok = |v: f64| v.is_finite() && v >= 0.0;
        if !ok(self.max_age_ms) {
            return Err(("max_age_ms", "must be >= 0"));
        }
        if !(self.evidence_window.is_finite() && self.evidence_window >= 1.0) {
            return Err(("evidence_window", "must be >= 1"));
        }
        if !ok(self.evidence_margin) {
            return Err(("evidence_margin", "must be >= 0"));
        }
        Ok(())
    }
}
