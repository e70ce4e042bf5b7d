//! `beliefbus pomdp solve | simulate`: the [`beliefbus_pomdp`] crate on
//! files in Cassandra's `.pomdp` format.

use anyhow::{bail, Context, Result};
use beliefbus_pomdp::{
    parse_file, simulate, simulate_plan, solve, AlphaPolicy, Pomdp, SimulateOptions, SolveOptions,
};
use clap::Subcommand;
use std::path::{Path, PathBuf};
use std::time::Duration;

#[derive(Subcommand)]
pub(crate) enum PomdpCommand {
    /// Solve a `.pomdp` file: print the lower and upper bounds at the start
    /// belief as they tighten, then write the α-vector policy.
    Solve {
        /// The problem, in Cassandra's `.pomdp` format.
        file: PathBuf,
        /// Time budget in seconds (default: until the precision is reached).
        #[arg(long)]
        time: Option<f64>,
        /// Stop when upper − lower at the start belief is at most this.
        #[arg(long, default_value_t = 1e-3)]
        precision: f64,
        /// Write the policy here (text α-vectors, see `beliefbus_pomdp::policy`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Threads for the backups (default: the machine's cores).
        #[arg(long)]
        threads: Option<usize>,
        /// After solving, run the lower bound's own controller (the plan of
        /// the vector best at b0, `beliefbus_pomdp::simulate_plan`) this
        /// many times and print its mean discounted reward beside the bound.
        #[arg(long, value_name = "RUNS")]
        simulate_plan: Option<usize>,
        /// Seed of those runs.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Run an α-vector policy on its model and print the mean discounted
    /// reward with its standard error.
    Simulate {
        /// The problem, in Cassandra's `.pomdp` format.
        file: PathBuf,
        /// The policy written by `pomdp solve --out`.
        policy: PathBuf,
        /// Number of runs.
        #[arg(long, default_value_t = 1000)]
        runs: usize,
        /// Seed of the runs' random streams.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Each run's horizon makes the discarded tail at most this.
        #[arg(long, default_value_t = 1e-3)]
        precision: f64,
        /// Threads (default: the machine's cores).
        #[arg(long)]
        threads: Option<usize>,
    },
}

fn load(file: &Path) -> Result<Pomdp> {
    let p = parse_file(file)?;
    println!(
        "{}: {} states, {} actions, {} observations, discount {}",
        file.display(),
        p.n_states(),
        p.n_actions(),
        p.n_obs(),
        p.discount
    );
    Ok(p)
}

fn threads(t: Option<usize>) -> Result<usize> {
    match t {
        Some(0) => bail!("--threads must be at least 1"),
        Some(t) => Ok(t),
        None => Ok(std::thread::available_parallelism().map_or(1, |n| n.get())),
    }
}

pub(crate) fn run(cmd: PomdpCommand) -> Result<()> {
    match cmd {
        PomdpCommand::Solve {
            file,
            time,
            precision,
            out,
            threads: t,
            simulate_plan: plan_runs,
            seed,
        } => {
            if !(precision > 0.0 && precision.is_finite()) {
                bail!("--precision must be a positive number, got {precision}");
            }
            let time_limit = match time {
                Some(s) if !(s > 0.0 && s.is_finite()) => {
                    bail!("--time must be a positive number of seconds, got {s}")
                }
                Some(s) => Some(Duration::from_secs_f64(s)),
                None => None,
            };
            // Fail on an unwritable --out before a long solve, not after.
            if let Some(o) = &out {
                std::fs::File::create(o).with_context(|| format!("--out {}", o.display()))?;
            }
            let p = load(&file)?;
            let opts = SolveOptions {
                precision,
                time_limit,
                threads: threads(t)?,
                ..Default::default()
            };
            let sol = solve(&p, &opts, |r| {
                println!(
                    "{:9.3} s  lower {:.6}  upper {:.6}  gap {:.3e}  ({} trials, {} α-vectors, {} upper points)",
                    r.time_s,
                    r.lower,
                    r.upper,
                    r.upper - r.lower,
                    r.trials,
                    r.alpha_vectors,
                    r.upper_points
                )
            })?;
            println!(
                "bounds at b0: [{:.6}, {:.6}], gap {:.3e} after {:.3} s ({})",
                sol.lower,
                sol.upper,
                sol.upper - sol.lower,
                sol.time_s,
                if sol.converged {
                    "precision reached"
                } else {
                    "time budget spent"
                }
            );
            if let Some(runs) = plan_runs {
                let opts = SimulateOptions {
                    runs,
                    seed,
                    precision: 1e-3,
                    threads: threads(t)?,
                };
                let r = simulate_plan(&p, &sol, &opts)?;
                println!(
                    "the lower bound's controller (vector {}, {:.6} at b0): discounted reward {:.6} ± {:.6} (s.e., {} runs, horizon {}, seed {seed})",
                    r.vector, r.vector_value, r.result.mean, r.result.std_err, r.result.runs, r.result.horizon
                );
            }
            if let Some(o) = out {
                sol.policy
                    .write(&o)
                    .with_context(|| format!("writing {}", o.display()))?;
                println!(
                    "policy: {} α-vectors written to {}",
                    sol.policy.vectors.len(),
                    o.display()
                );
            }
            Ok(())
        }
        PomdpCommand::Simulate {
            file,
            policy,
            runs,
            seed,
            precision,
            threads: t,
        } => {
            let p = load(&file)?;
            let pol = AlphaPolicy::read(&policy)?;
            let opts = SimulateOptions {
                runs,
                seed,
                precision,
                threads: threads(t)?,
            };
            let r = simulate(&p, &pol, &opts)?;
            println!(
                "discounted reward {:.6} ± {:.6} (s.e., {} runs, horizon {}, seed {seed})",
                r.mean, r.std_err, r.runs, r.horizon
            );
            Ok(())
        }
    }
}
