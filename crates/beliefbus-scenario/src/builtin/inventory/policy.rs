//! The offline half of `belief-mdp`: solving the projected-belief MDP of
//! the scenario's model (paper §III, Algorithms 1–2; average cost, relative
//! value iteration) into a policy file, and finding and checking that file.
//!
//! The file's key holds every parameter the policy depends on — the model
//! (h, s, Q, β, σ), the grid, the family, the Monte Carlo sizes and seed,
//! the criterion — so a file solved for another σ, grid or cost is refused
//! with the command that solves the right one. The Monte Carlo seed is
//! derived from `[inventory.policy] seed` exactly as the
//! `inventory-average` experiment derives it from `--seed`: the same seed
//! and sizes solve the same table.

use super::{InventoryParams, InventorySystem};
use crate::{SolveOutcome, SolveRequest};
use beliefbus_projection::grid::{Axis, ParamGrid};
use beliefbus_projection::policy::{Criterion, GridPolicy, PolicyError, PolicyKey};
use beliefbus_projection::solve::{solve_policy, SolveOptions};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The seed role the `inventory-average` experiment mixes into its seed.
const SOLVE_ROLE: u64 = 0x4D44;

impl InventorySystem {
    /// The belief grid: mean 0:0.5:mean_max × std 0:0.2:5.
    pub fn grid(&self) -> Result<ParamGrid, String> {
        let axes = vec![
            Axis::range(0.0, 0.5, self.params.policy.mean_max).map_err(|e| e.to_string())?,
            Axis::range(0.0, 0.2, 5.0).map_err(|e| e.to_string())?,
        ];
        ParamGrid::new(axes).map_err(|e| e.to_string())
    }

    /// The solver's settings.
    pub fn solve_options(&self, threads: usize) -> SolveOptions {
        let p = &self.params.policy;
        SolveOptions::new(
            p.mc_samples,
            p.cost_samples,
            beliefbus_projection::rng::mix(&[p.seed, SOLVE_ROLE]),
            threads,
        )
    }

    /// The key a current policy file carries.
    pub fn policy_key(&self) -> Result<PolicyKey, String> {
        let grid = self.grid()?;
        Ok(self
            .solve_options(1)
            .key_fields(self.model.key(), &Criterion::Average)
            .text("family", "gaussian")
            .text(
                "grid",
                &serde_json::to_string(&grid).map_err(|e| e.to_string())?,
            ))
    }

    /// Where the policy file is: `[inventory.policy] path`, or the default
    /// in the cache directory.
    pub fn policy_path(&self) -> PathBuf {
        let p = &self.params.policy.path;
        if !p.is_empty() {
            return PathBuf::from(p);
        }
        let cache = std::env::var_os("XDG_CACHE_HOME")
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
            .or_else(|| {
                std::env::var_os("HOME")
                    .filter(|v| !v.is_empty())
                    .map(|h| PathBuf::from(h).join(".cache"))
            })
            .unwrap_or_else(std::env::temp_dir);
        cache.join("beliefbus").join("policies").join(format!(
            "inventory-average-sigma{:.3}.json",
            self.params.sigma
        ))
    }

    /// The command that writes the policy this system needs: `beliefbus
    /// solve inventory` (the built-in config, whose section holds the
    /// defaults) with a `--set` for every parameter of the key that differs
    /// from its default, and `--out` for a configured path. The policy
    /// depends on `[inventory]` only, so the command is exact whatever the
    /// rest of the run's config says.
    pub fn solve_command(&self) -> String {
        let (p, d) = (&self.params, InventoryParams::default());
        let mut cmd = String::from("beliefbus solve inventory");
        let nums = [
            ("h", p.h, d.h),
            ("s", p.s, d.s),
            ("q", p.q, d.q),
            ("demand_mean", p.demand_mean, d.demand_mean),
            ("sigma", p.sigma, d.sigma),
            ("policy.mean_max", p.policy.mean_max, d.policy.mean_max),
        ];
        for (k, v, def) in nums {
            if v != def {
                cmd.push_str(&format!(" --set inventory.{k}={v:?}"));
            }
        }
        let ints = [
            (
                "policy.mc_samples",
                p.policy.mc_samples as u64,
                d.policy.mc_samples as u64,
            ),
            (
                "policy.cost_samples",
                p.policy.cost_samples as u64,
                d.policy.cost_samples as u64,
            ),
            ("policy.seed", p.policy.seed, d.policy.seed),
        ];
        for (k, v, def) in ints {
            if v != def {
                cmd.push_str(&format!(" --set inventory.{k}={v}"));
            }
        }
        if !p.policy.path.is_empty() {
            cmd.push_str(&format!(" --out {}", p.policy.path));
        }
        cmd
    }

    /// Load the policy file and check it is the one this system needs.
    pub fn load_policy(&self) -> Result<GridPolicy, String> {
        let path = self.policy_path();
        let key = self.policy_key()?;
        let cmd = self.solve_command();
        match GridPolicy::load_checked(&path, &key) {
            Ok(p) if p.family == "gaussian" && p.grid.dim() == 2 => Ok(p),
            Ok(p) => Err(format!(
                "policy file {} is for family {} on a {}-d grid, not the Gaussian (mean, std) grid; run `{cmd}`",
                path.display(),
                p.family,
                p.grid.dim()
            )),
            Err(PolicyError::Missing { .. }) => Err(format!(
                "no policy file at {}: solve it first with `{cmd}`",
                path.display()
            )),
            Err(e @ PolicyError::Stale { .. }) => Err(format!("{e}: run `{cmd}`")),
            Err(e) => Err(format!("{e}; run `{cmd}` to write a new one")),
        }
    }
}

/// Solve, save, and time the on-line lookup.
pub fn solve(sys: &InventorySystem, req: SolveRequest) -> Result<SolveOutcome, String> {
    let started = Instant::now();
    let path = req
        .out
        .map(Path::to_path_buf)
        .unwrap_or_else(|| sys.policy_path());
    let p = &sys.params.policy;
    let grid = sys.grid()?;
    (req.progress)(&format!(
        "solving the projected-belief MDP: sigma {}, grid {} points, N_s = {}, N_c = {}, average cost (relative value iteration)",
        sys.params.sigma,
        grid.len(),
        p.mc_samples,
        p.cost_samples
    ));
    let family = beliefbus_projection::Gaussian::new(1).map_err(|e| e.to_string())?;
    let opts = sys.solve_options(req.threads);
    let policy = solve_policy(
        &sys.model,
        &family,
        &grid,
        Criterion::Average,
        &opts,
        sys.model.key(),
    )
    .map_err(|e| e.to_string())?;
    if policy.key != sys.policy_key()? {
        return Err("internal: the solved policy's key differs from the expected one".into());
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    }
    policy.save(&path).map_err(|e| e.to_string())?;
    let lookup_ns = super::control::time_lookup(&policy, 200_000);
    let s = &policy.stats;
    Ok(SolveOutcome {
        path,
        seconds: started.elapsed().as_secs_f64(),
        figures: vec![
            ("build_s".into(), format!("{:.2}", s.build_s)),
            ("iterate_s".into(), format!("{:.3}", s.iterate_s)),
            ("iterations".into(), s.iterations.to_string()),
            ("transitions".into(), s.nnz.to_string()),
            (
                "gain".into(),
                s.gain.map_or("-".into(), |g| format!("{g:.4}")),
            ),
            ("lookup_ns".into(), format!("{lookup_ns:.0}")),
        ],
    })
}
