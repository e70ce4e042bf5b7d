//! The offline half of `pomdp`: solving the chain POMDP with the
//! point-based solver into an α-vector policy file, and finding and
//! checking that file.
//!
//! The file is the solver's α-vector text format (`beliefbus pomdp
//! simulate` reads it) behind a comment header naming the problem's
//! fingerprint ([`super::model::model_key`]): a file solved for another
//! light, goal, noise, chain or discount is refused as stale with the
//! command that solves the right one.
//!
//! ```text
//! # beliefbus light-dark policy
//! # key <16 hex digits>
//! # lower_b0 <V̲(b₀)> upper_b0 <V̄(b₀)> solve_s <s>
//! beliefbus-alpha 1
//! …
//! ```

pub use super::flat::FlatPolicy;
use super::{LightDarkParams, LightDarkSystem};
use crate::{SolveOutcome, SolveRequest};
use beliefbus_pomdp::{solve as pbvi, AlphaPolicy, SolveOptions};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

impl LightDarkSystem {
    /// Where the policy file is: `[light-dark.policy] path`, or the cache.
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
        cache
            .join("beliefbus")
            .join("policies")
            .join("light-dark.alpha")
    }

    /// The command that writes the policy this system needs: `beliefbus
    /// solve light-dark` with a `--set` for every parameter of the key
    /// that differs from its default, and `--out` for a configured path.
    pub fn solve_command(&self) -> String {
        let (p, d) = (&self.params, LightDarkParams::default());
        let mut cmd = String::from("beliefbus solve light-dark");
        let nums = [
            ("light", p.light, d.light),
            ("light_width", p.light_width, d.light_width),
            ("goal", p.goal, d.goal),
            ("goal_width", p.goal_width, d.goal_width),
            ("noise", p.noise, d.noise),
            ("epsilon", p.epsilon, d.epsilon),
            ("rate", p.rate, d.rate),
            ("reward", p.reward, d.reward),
        ];
        for (k, v, def) in nums {
            if v != def {
                cmd.push_str(&format!(" --set light-dark.{k}={v:?}"));
            }
        }
        if p.states != d.states {
            cmd.push_str(&format!(" --set light-dark.states={}", p.states));
        }
        if p.control_seed != d.control_seed {
            cmd.push_str(&format!(
                " --set light-dark.control_seed={}",
                p.control_seed
            ));
        }
        if !p.policy.path.is_empty() {
            cmd.push_str(&format!(" --out {}", p.policy.path));
        }
        cmd
    }

    /// The file's text for `policy`.
    pub fn policy_text(&self, policy: &AlphaPolicy, lower: f64, upper: f64, secs: f64) -> String {
        format!(
            "# beliefbus light-dark policy\n# key {}\n# lower_b0 {lower} upper_b0 {upper} solve_s {secs:.3}\n{}",
            self.key,
            policy.to_text()
        )
    }

    /// Load the policy file and check it is the one this system needs.
    pub fn load_policy(&self) -> Result<(AlphaPolicy, f64), String> {
        let path = self.policy_path();
        let cmd = self.solve_command();
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(format!(
                    "no policy file at {}: solve it first with `{cmd}`",
                    path.display()
                ))
            }
            Err(e) => return Err(format!("cannot read {}: {e}", path.display())),
        };
        let header = |name: &str| {
            text.lines()
                .take_while(|l| l.starts_with('#'))
                .find_map(|l| l.strip_prefix(&format!("# {name} ")))
                .map(str::trim)
        };
        match header("key") {
            Some(k) if k == self.key => {}
            Some(k) => {
                return Err(format!(
                    "policy file {} is stale: solved for problem {k}, this config's is {}; run `{cmd}`",
                    path.display(),
                    self.key
                ))
            }
            None => {
                return Err(format!(
                    "policy file {} has no `# key` header (not written by `beliefbus solve light-dark`); run `{cmd}`",
                    path.display()
                ))
            }
        }
        let lower = header("lower_b0")
            .and_then(|l| l.split_whitespace().next())
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NEG_INFINITY);
        let p = AlphaPolicy::from_text(&path.display().to_string(), &text)
            .map_err(|e| format!("{e}; run `{cmd}` to write a new one"))?;
        let pomdp = &self.pomdp.pomdp;
        p.check_fits(pomdp.n_states(), pomdp.n_actions())
            .map_err(|e| format!("{}: {e}; run `{cmd}`", path.display()))?;
        if p.vectors.is_empty() {
            return Err(format!(
                "policy file {} has no α-vectors; run `{cmd}`",
                path.display()
            ));
        }
        Ok((p, lower))
    }

    /// Solver settings: `secs` of budget, continuing from `initial`.
    pub fn solve_options(
        &self,
        secs: f64,
        threads: usize,
        initial: Vec<(Vec<f64>, usize)>,
    ) -> SolveOptions {
        SolveOptions {
            precision: self.params.policy.precision,
            time_limit: Some(Duration::from_secs_f64(secs)),
            threads: threads.max(1),
            initial_lower: initial,
            belief_flush: 1e-7,
            // Keep every non-dominated vector: a pruned set can lose the
            // plan's continuation at unsampled beliefs (solver docs).
            prune_lower: false,
            ..Default::default()
        }
    }
}

/// Mean time (ns) of one lookup over `n` beliefs (a deterministic sweep
/// of point masses and mixtures; no RNG in the timed loop).
pub fn time_lookup(policy: &FlatPolicy, n: usize) -> f64 {
    let mut b = vec![0.0; policy.n];
    let mut total = 0usize;
    let start = Instant::now();
    for i in 0..n {
        let j = i % policy.n;
        b.fill(0.0);
        b[j] = 0.5;
        b[(j * 7 + 3) % policy.n] += 0.5;
        total += policy.act(std::hint::black_box(&b));
    }
    std::hint::black_box(total);
    start.elapsed().as_secs_f64() * 1e9 / n.max(1) as f64
}

/// Solve, save, and time the on-line lookup.
pub fn solve(sys: &LightDarkSystem, req: SolveRequest) -> Result<SolveOutcome, String> {
    let started = Instant::now();
    let path = req
        .out
        .map(Path::to_path_buf)
        .unwrap_or_else(|| sys.policy_path());
    let cp = &sys.pomdp;
    let secs = sys.params.policy.solve_s;
    (req.progress)(&format!(
        "solving the light-dark chain POMDP: {} states, {} actions, {} observations, period {:.4} s, gamma {:.6}, budget {secs} s",
        cp.n_chain(),
        cp.pomdp.n_actions(),
        cp.pomdp.n_obs(),
        cp.period,
        cp.pomdp.discount
    ));
    let threads = if req.threads == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        req.threads
    };
    let opts = sys.solve_options(secs, threads, Vec::new());
    let progress = &mut *req.progress;
    let sol = pbvi(&cp.pomdp, &opts, |p| {
        progress(&format!(
            "{:7.2} s  lower {:10.3}  upper {:10.3}  vectors {}",
            p.time_s, p.lower, p.upper, p.alpha_vectors
        ))
    })
    .map_err(|e| e.to_string())?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    }
    let text = sys.policy_text(&sol.policy, sol.lower, sol.upper, sol.time_s);
    std::fs::write(&path, text).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let flat = FlatPolicy::new(&sol.policy, cp.n_chain(), sol.lower);
    let pp = &sys.params.policy;
    let (table, pruned) =
        super::prune::bounded_table(sys, &flat, pp.lookup_capacity, pp.prune_episodes, 1);
    let lookup_ns = time_lookup(&table, 200_000);
    let full_ns = time_lookup(&flat, 200_000);
    Ok(SolveOutcome {
        path,
        seconds: started.elapsed().as_secs_f64(),
        figures: vec![
            ("lower_b0".into(), format!("{:.3}", sol.lower)),
            ("upper_b0".into(), format!("{:.3}", sol.upper)),
            ("converged".into(), sol.converged.to_string()),
            ("vectors".into(), sol.policy.vectors.len().to_string()),
            ("undominated_vectors".into(), flat.len().to_string()),
            ("lookup_vectors".into(), table.len().to_string()),
            ("table_maximisers".into(), pruned.maximisers.to_string()),
            ("table_beliefs".into(), pruned.beliefs.to_string()),
            ("table_loss".into(), format!("{:.3e}", pruned.loss)),
            ("trials".into(), sol.trials.to_string()),
            ("period_s".into(), format!("{:.4}", cp.period)),
            ("lookup_ns".into(), format!("{lookup_ns:.0}")),
            ("full_lookup_ns".into(), format!("{full_ns:.0}")),
        ],
    })
}
