//! Solve a projected-belief MDP end to end: Monte Carlo build
//! ([`crate::build`]), then value iteration (discounted) or relative value
//! iteration (average cost), into a [`GridPolicy`] keyed by everything the
//! solution depends on.

use crate::build::{build_projected_mdp, BuildOptions};
use crate::family::ExpFamily;
use crate::grid::ParamGrid;
use crate::model::Pomdp;
use crate::policy::{Criterion, GridPolicy, PolicyKey, SolveStats};
use crate::ProjectionError;
use std::time::Instant;

/// Stopping rules of the iterations.
#[derive(Clone, Debug)]
pub struct SolveOptions {
    pub build: BuildOptions,
    /// Value iteration: the greedy policy is `eps`-optimal for the grid MDP
    /// (sup-norm step < eps(1−γ)/(2γ)). Relative value iteration: the
    /// span of T h − h, i.e. the width of the bracket on the gain.
    pub eps: f64,
    pub max_iter: usize,
    /// Aperiodicity weight τ of relative value iteration.
    pub tau: f64,
}

impl SolveOptions {
    /// N_s = `samples`, N_c = `cost_samples`, eps = 1e-6, τ = 0.5, up to
    /// 10⁶ sweeps.
    pub fn new(samples: usize, cost_samples: usize, seed: u64, threads: usize) -> Self {
        Self {
            build: BuildOptions {
                samples,
                cost_samples,
                threads,
                seed,
            },
            eps: 1e-6,
            max_iter: 1_000_000,
            tau: 0.5,
        }
    }

    /// The solver's part of a policy key.
    pub fn key_fields(&self, key: PolicyKey, criterion: &Criterion) -> PolicyKey {
        let key = key
            .int("mc_samples", self.build.samples as u64)
            .int("mc_cost_samples", self.build.cost_samples as u64)
            .int("mc_seed", self.build.seed)
            .num("solver_eps", self.eps);
        match criterion {
            Criterion::Discounted { gamma } => {
                key.text("criterion", "discounted").num("gamma", *gamma)
            }
            Criterion::Average => key.text("criterion", "average").num("rvi_tau", self.tau),
        }
    }
}

/// Build and solve; `model_key` names the model's parameters, to which the
/// family, grid and solver fields are added.
pub fn solve_policy<M: Pomdp, F: ExpFamily>(
    model: &M,
    family: &F,
    grid: &ParamGrid,
    criterion: Criterion,
    opts: &SolveOptions,
    model_key: PolicyKey,
) -> Result<GridPolicy, ProjectionError> {
    let (mdp, built) = build_projected_mdp(model, family, grid, &opts.build)?;
    let start = Instant::now();
    let (policy, values, iterations, gain) = match criterion {
        Criterion::Discounted { gamma } => {
            let s = mdp.value_iteration(gamma, opts.eps, opts.max_iter)?;
            (s.policy, s.values, s.iterations, None)
        }
        Criterion::Average => {
            let s = mdp.relative_value_iteration(opts.tau, opts.eps, opts.max_iter)?;
            (s.policy, s.bias, s.iterations, Some(s.gain))
        }
    };
    let stats = SolveStats {
        build_s: built.seconds,
        iterate_s: start.elapsed().as_secs_f64(),
        iterations,
        nnz: built.nnz,
        gain,
    };
    let key = opts
        .key_fields(model_key, &criterion)
        .text("family", family.name())
        .text("grid", &serde_json::to_string(grid).unwrap_or_default());
    GridPolicy::new(
        key,
        family.name(),
        criterion,
        grid.clone(),
        &policy,
        values,
        stats,
    )
}
