//! Offline looks at solved 2-D light-dark policies: `dump=DIR` writes each
//! solve's policy, `load=DIR` reads them back instead of solving (the
//! chains are rebuilt from the same seeds, so the policies fit them), and
//! `trace=FILE` appends one CSV line per declared continuous episode: where
//! the truth was, where the belief put it, its most probable state and its
//! mass on the chain states inside the goal.

use super::continuous::Outcome;
use anyhow::{Context, Result};
use beliefbus_pomdp::chain_pomdp::ChainPomdp;
use beliefbus_pomdp::{AlphaPolicy, Solution};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The file of solve `r`'s policy at `n` chain states under `dir`.
pub fn policy_path(dir: &str, r: u64, n: usize) -> PathBuf {
    Path::new(dir).join(format!("solve{r}-n{n}.policy"))
}

/// `sol` with its policy read from `dir` (solve `r`); the bounds, which
/// the file does not hold, become NaN.
pub fn load(dir: &str, r: u64, cp: &ChainPomdp, sol: &Solution) -> Result<Solution> {
    let path = policy_path(dir, r, cp.n_chain());
    let policy = AlphaPolicy::read(&path).context("--param load")?;
    anyhow::ensure!(
        policy.n_states == cp.pomdp.n_states() && policy.n_actions == cp.pomdp.n_actions(),
        "--param load: {} has {} states and {} actions, the rebuilt problem {} and {}",
        path.display(),
        policy.n_states,
        policy.n_actions,
        cp.pomdp.n_states(),
        cp.pomdp.n_actions()
    );
    Ok(Solution {
        lower: f64::NAN,
        upper: f64::NAN,
        policy,
        ..sol.clone()
    })
}

/// The header of the trace file.
pub const HEADER: &str = "solve,states,run,step,x0,x1,mean0,mean1,map0,map1,goal_mass,hit,return";

/// Appends `c`'s declared episodes (solve `r`, chain `cp`) to `path`,
/// writing the header first if the file is new.
pub fn append(
    path: &str,
    r: u64,
    cp: &ChainPomdp,
    c: &Outcome,
    hit: impl Fn(&[f64]) -> bool,
) -> Result<()> {
    let new = !Path::new(path).exists();
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .with_context(|| format!("--param trace: opening {path}"))?;
    let mut s = String::new();
    if new {
        s.push_str(HEADER);
        s.push('\n');
    }
    for e in &c.ends {
        let z = cp.state(e.map_state);
        s.push_str(&format!(
            "{r},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            cp.n_chain(),
            e.run,
            e.step,
            e.x[0],
            e.x[1],
            e.belief_mean[0],
            e.belief_mean[1],
            z[0],
            z[1],
            e.goal_mass,
            u8::from(hit(&e.x)),
            c.returns[e.run]
        ));
    }
    f.write_all(s.as_bytes())
        .with_context(|| format!("--param trace: writing {path}"))
}
