//! `beliefbus solve <scenario> [--config FILE] [--set K=V] [--out FILE]`:
//! a scenario's offline part ([`System::solve`], e.g. the policy table the
//! inventory scenario's `belief-mdp` controller loads), written where its
//! controller looks for it unless `--out` says otherwise.
//!
//! Only the scenario's own section (and the sample period) is read: the
//! rest of the config is not validated, because a run's validation is
//! exactly what refuses a config whose policy is not solved yet.

use crate::config::load::apply_override;
use crate::config::ConfigSource;
use crate::scenario::{BuildContext, Registry, SolveRequest, System};
use anyhow::{anyhow, bail, Result};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The arguments of `solve`.
#[derive(clap::Args)]
pub(crate) struct SolveArgs {
    /// The registered scenario (see `beliefbus scenarios`).
    scenario: String,
    /// Pipeline config whose `[<scenario>]` section to solve for (default:
    /// the scenario's built-in config).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override one config key by dotted path (repeatable), as for `run`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    sets: Vec<String>,
    /// Write the result here (default: where the scenario's controller
    /// looks, e.g. `[inventory.policy] path`).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Worker threads (0: the machine's parallelism).
    #[arg(long, default_value_t = 0)]
    threads: usize,
}

/// Build the scenario's system from its section of the config.
fn system(registry: &Registry, a: &SolveArgs) -> Result<Arc<dyn System>> {
    let entry = registry.get(&a.scenario).ok_or_else(|| {
        anyhow!(
            "unknown scenario `{}`; registered: {}",
            a.scenario,
            registry.names().join(", ")
        )
    })?;
    let source = match &a.config {
        Some(p) => ConfigSource::File(p.clone()),
        None => ConfigSource::Scenario(Some(a.scenario.clone())),
    };
    let (text, origin) = source.text(registry).map_err(|e| anyhow!("{e}"))?;
    let mut table: toml::Table =
        toml::from_str(&text).map_err(|e| anyhow!("{origin}: not valid TOML: {e}"))?;
    for kv in &a.sets {
        apply_override(&mut table, kv).map_err(|e| anyhow!("--set: {e}"))?;
    }
    let named = table
        .get("run")
        .and_then(|r| r.get("scenario"))
        .and_then(|s| s.as_str());
    if let Some(n) = named.filter(|n| *n != a.scenario) {
        bail!(
            "{origin} runs scenario `{n}`, not `{}` (run.scenario)",
            a.scenario
        );
    }
    let rate = table
        .get("plant")
        .and_then(|p| p.get("sensor_rate_hz"))
        .and_then(|r| r.as_float().or_else(|| r.as_integer().map(|i| i as f64)))
        .filter(|r| *r > 0.0 && r.is_finite())
        .unwrap_or(1000.0);
    let section = match table.get(entry.name) {
        Some(toml::Value::Table(t)) => Some(t),
        Some(_) => bail!("{origin}: `{}` must be a section", entry.name),
        None => None,
    };
    let ctx = BuildContext {
        sample_dt: 1.0 / rate,
    };
    entry.build(section, &ctx).map_err(|e| {
        let key = if e.key.is_empty() {
            entry.name.to_string()
        } else {
            format!("{}.{}", entry.name, e.key)
        };
        anyhow!("{origin}: `{key}`: {}", e.problem)
    })
}

/// Run `solve`.
pub(crate) fn run(registry: &Registry, a: &SolveArgs) -> Result<()> {
    let sys = system(registry, a)?;
    let mut progress = |m: &str| eprintln!("{m}");
    let req = SolveRequest {
        out: a.out.as_deref().map(Path::new),
        threads: a.threads,
        progress: &mut progress,
    };
    let outcome = sys
        .solve(req)
        .ok_or_else(|| anyhow!("scenario `{}` has nothing to solve offline", a.scenario))?
        .map_err(|e| anyhow!("scenario `{}`: {e}", a.scenario))?;
    println!(
        "solved {} in {:.2} s: {}",
        a.scenario,
        outcome.seconds,
        outcome.path.display()
    );
    for (k, v) in &outcome.figures {
        println!("  {k} = {v}");
    }
    Ok(())
}
