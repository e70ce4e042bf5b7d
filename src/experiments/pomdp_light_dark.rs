//! `pomdp-light-dark`: thesis 000 §4.7.2, Figs. 4-6 to 4-8 — the
//! light-dark domain as chain POMDPs solved by our point-based solver.
//!
//! ```text
//! dx = u dt + σ dw,   y = x + G(x) v,   G(x) = ε in a light region, 1/ε elsewhere,  x ∈ [−2, 2]^d
//! reward: −|u|² per second; the terminal action u_goal ends the episode with
//! +1000 if |x − g|_∞ < e_g, −1000 otherwise;   γ = exp(−ρ h)
//! ```
//!
//! * 1-D: one beacon b = 0.9 (|x − b| < 0.1), goal −0.9 (|x + 0.9| < 0.1),
//!   20 regular states (−1.9, −1.7, …, 1.9; Near radius 0.3: the grid
//!   neighbours ±0.2), U = {0, ±1} ∪ uniform draws, the observation points
//!   the states, b₀ uniform: the agent must find the light, localise, then
//!   go to the goal. One seeded belief trajectory is drawn (`plot`).
//! * 2-D: beacons (±1.4, ±1.4), start (−1.5, −0.5), goal (1.5, −1.5).
//!   The thesis's "width" is read as e in |x − b|_∞ < e, as the 1-D
//!   e₁ = 0.1 the brief calls the width: light half-widths 1.2, goal 0.2.
//!   b₀ = N(start, 0.5² I) on the chain. The chain is grown incrementally
//!   (75 → 150 → 300 → 600) from uniform samples plus the goal's centre
//!   (so that the goal holds a state at every n; `goal_states=cross`: also
//!   the four points on its border along the axes, so that the centre's
//!   cell lies in the goal at every n), Near the radius
//!   3 (ln n / n)^{1/2}; U = {0, the four corners (±1, ±1)} ∪ uniform
//!   draws on [−1, 1]², ⌊5 ln n⌋ in all; O = ⌊5 ln n⌋ uniform points in each light
//!   box plus ⌊5 ln n⌋ on the whole square (in the dark the likelihood is
//!   flat over [−2, 2]², so points there carry nothing; in the light they
//!   set how finely the agent localises). Each size is solved for
//!   `solve_s` from the previous size's plans carried over
//!   ([`warm::carry_plan`]: the policy graph evaluated exactly on the new
//!   chain, at most [`CARRY_CAP`] nodes; `carried_b0` is its certified
//!   value at b₀, a floor for `lower_b0`). The carried value is near the
//!   stay-put plan's 0: a plan exploits its own chain (moves at ~0.7 of
//!   u h, targets snapped onto the goal's one state, exact localisation in
//!   the light) and loses in the continuous dynamics and on a finer chain
//!   alike (`carry_check=1`, [`carry`]). What keeps the larger sizes from
//!   starting blind is the upper bound's MDP start. The anytime curve
//!   solves the `anytime_states` POMDP afresh per budget.
//! * Every size's policy is also run in the continuous problem on a belief
//!   the chain filter tracks from real-valued measurements, as the live
//!   controller runs it (`continuous` ± s.e., `goal_frac`; [`continuous`]):
//!   the one yardstick that does not change with the chain.
//! * Diagnostics (defaults = the thesis's construction): `match_mean`,
//!   `kappa_drift` (κ_f of the 2-D chain) and `period_s` (one decision
//!   period at every size, δ = period/2^j).
//! * `rows=moment`: one row per period with the mean exactly the clamped
//!   z + u h ([`chain_pomdp::rows_moment`]; the 2-D chain then also holds
//!   32 states every 0.5 along the box's edges); `goal_reward=cell`: the terminal reward
//!   averaged over each state's cell ([`goal_cells`]); `solves=N`: N
//!   independent 2-D solves (chains from seeds seed, …, seed + N − 1; the
//!   evaluations keep `seed`, or `seed + r` with `eval_seed=per_solve`), summarised per size ([`replicates`]: mean
//!   ± s.e. over the solves and the step from the previous size paired by
//!   solve); `budget=per_state`: solve_s · n / (first n) per size.
//! * The box's edge: a wall by default (the truth and the moment rows
//!   clamp there). `wall_frac` is the fraction of episodes whose truth
//!   reached it; `open=1` also runs each policy with no wall
//!   (`continuous_open`, paired `open_minus_walls`): a plan that localises
//!   against the wall fails there. `edge=cliff` makes reaching the edge
//!   end the episode with −1000 in the chain ([`cliff::make_cliff`]) and
//!   in the truth, so only the light can localise. Continuous returns of
//!   consecutive sizes pair episode by episode (`continuous_step`).
//!
//! The step is the thesis's Δt_n = min_{z,u} Δt(z,u) (no power-of-two
//! rounding): with σ² ≪ r|u| every control moves about r per Δt(z,u), and
//! the strongest controls then jump with probability δ/Δt = 1 each step —
//! a chain whose holding-time randomness does not blur the dead reckoning
//! between the light and the goal (with δ < Δt each step is a coin flip
//! and the chain diffuses by ≈ r|u| per second, far above σ²).
//!
//! Unstated in the thesis, chosen here: σ (its "dw" would be σ = 1, under
//! which no 20-state policy can hold a ±0.1 goal), ε, ρ, the control cost
//! weight (1), b₀. Expected reward is the discrete POMDP's discounted
//! return from b₀ over seeded runs (the evaluation SARSOP's simulator
//! makes), with its standard error.

use super::chain_util::Params;
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::chain::{Chain, ChainConfig, NearRule, Sampler};
use crate::rng::{self, SimRng};
use anyhow::{Context, Result};
use beliefbus_pomdp::chain_pomdp::{self, cliff, warm, ChainPomdp, ChainPomdpSpec, Rows, Terminal};
use beliefbus_pomdp::{simulate, solve, AlphaPolicy, SimulateOptions, Solution};
use rand::{RngExt, SeedableRng};
use std::path::Path;
use std::time::Duration;

#[path = "pomdp_light_dark_carry.rs"]
pub mod carry;
#[path = "pomdp_light_dark_continuous.rs"]
pub mod continuous;
#[path = "pomdp_light_dark_goal.rs"]
mod goal_cells;
#[path = "pomdp_light_dark_model.rs"]
mod model;
#[path = "pomdp_light_dark_paper.rs"]
mod paper;
#[path = "pomdp_light_dark_params.rs"]
mod params;
#[path = "pomdp_light_dark_plot.rs"]
mod plot;
#[path = "pomdp_light_dark_replicates.rs"]
mod replicates;
#[path = "pomdp_light_dark_size_row.rs"]
mod size_row;
#[path = "pomdp_light_dark_trace.rs"]
mod trace;
use continuous::{value as continuous_value, Edge, Truth};
pub use model::{goal_2d, light_2d, Boxes, LightDark, LightDarkObs};
pub use params::PARAMS;
use params::{solve_opts, solve_opts_gap};
pub use plot::{trajectory, Step};

/// Thesis Fig. 4-8 (states, reward, ±) and Fig. 4-7 (solver s, reward, ±)
/// at 150 states.
pub const PAPER_STATES: [(usize, f64, f64); 2] = [(75, 377.9, 48.7), (150, 428.6, 55.2)];
pub const PAPER_ANYTIME: [(f64, f64, f64); 2] = [(100.0, 212.1, 99.7), (200.0, 428.6, 55.2)];

/// The continuous truth of the experiment's main columns: the box is a wall.
const WALLS: Truth = Truth::Sde(Edge::Wall);

/// Settings shared by both problems.
#[derive(Clone, Copy, Debug)]
pub struct Setting {
    pub sigma: f64,
    pub eps: f64,
    pub rate: f64,
    /// Rows consistent in the mean ([`ChainPomdpSpec::match_mean`]).
    pub match_mean: bool,
    /// A decision period fixed across sizes (δ = period/2^j, K = 2^j);
    /// 0: the thesis's Δt_n per size.
    pub period: f64,
    /// κ_f of the 2-D chain's holding time (the thesis: 1).
    pub kappa_drift: f64,
    /// The transition rows ([`Rows::Kernel`]: the thesis's).
    pub rows: Rows,
    /// Terminal reward averaged over each state's cell ([`goal_cells`]);
    /// false: at the state's point (the thesis's).
    pub cell_goal: bool,
    /// Besides the goal's centre, seed the 2-D chain with the four points
    /// on the goal's border along the axes (the centre's cell then lies in
    /// the goal whatever the uniform samples); false: the centre only.
    pub goal_cross: bool,
    /// The 2-D box's edge is a cliff (−1000, the episode ends;
    /// [`chain_pomdp::cliff`]) in the chain and the truth; false: a wall.
    pub cliff: bool,
    /// The 2-D solves' [`SolveOptions::trial_gap_fraction`] (0: HSVI2's
    /// fixed-precision trials).
    pub trial_gap: f64,
    /// The 2-D solves' [`SolveOptions::follow_lower_every`] (0: every
    /// trial follows the upper bound).
    pub follow_lower: u32,
    /// Regular states of the 1-D chain on [−1.9, 1.9] (the thesis: 20).
    pub states_1d: usize,
}

impl Setting {
    /// The continuous truth of the main columns.
    pub fn truth(&self) -> Truth {
        Truth::Sde(if self.cliff { Edge::Cliff } else { Edge::Wall })
    }
}

fn quadratic_control(_z: &[f64], u: &[f64]) -> f64 {
    u.iter().map(|v| v * v).sum()
}

fn spec_for(
    chain: &Chain,
    controls: &[Vec<f64>],
    obs: &[Vec<f64>],
    start: Vec<f64>,
    goal: &Boxes,
    s: &Setting,
) -> ChainPomdpSpec {
    ChainPomdpSpec {
        controls: controls.to_vec(),
        observations: obs.to_vec(),
        delta_max: if s.period > 0.0 {
            s.period
        } else {
            f64::INFINITY
        },
        decision_min: s.period,
        discount_rate: s.rate,
        start,
        row_flush: 1e-9,
        obs_flush: 1e-6,
        match_mean: s.match_mean,
        terminal: Some(Terminal {
            reward: if s.cell_goal {
                let (d, n) = (chain.dim(), chain.len());
                let per_axis = if d == 1 { 4000 } else { 400 };
                goal_cells::cell_rewards(&chain.states()[..n * d], d, goal, -2.0, 2.0, per_axis)
            } else {
                (0..chain.len())
                    .map(|i| {
                        if goal.contains(chain.state(i)) {
                            1000.0
                        } else {
                            -1000.0
                        }
                    })
                    .collect()
            },
        }),
    }
}

/// The 1-D problem on its regular grid of `s.states_1d` states on
/// [−1.9, 1.9] (20: the thesis's −1.9, −1.7, …, 1.9).
pub fn one_d(s: &Setting) -> Result<ChainPomdp> {
    let m = LightDark::new(1, s.sigma);
    let n = s.states_1d;
    anyhow::ensure!(n >= 2, "--param states_1d: at least 2 states");
    let pts: Vec<f64> = (0..n)
        .map(|i| -1.9 + 3.8 * i as f64 / (n - 1) as f64)
        .collect();
    let cfg = ChainConfig::gaussian(1).with_near(NearRule::Radius { gamma: 2.0 });
    let chain = Chain::batch(&m, cfg, &pts)?;
    let mut rng: SimRng = SimRng::seed_from_u64(0x1d);
    let mut controls = vec![vec![0.0], vec![-1.0], vec![1.0]];
    while controls.len() < chain_pomdp::log_count(5.0, n) {
        controls.push(vec![rng.random_range(-1.0..1.0)]);
    }
    let obs_pts: Vec<Vec<f64>> = pts.iter().map(|&x| vec![x]).collect();
    let light = Boxes(vec![(vec![0.9], 0.1)]);
    let goal = Boxes(vec![(vec![-0.9], 0.1)]);
    let obs = LightDarkObs { light, eps: s.eps };
    let spec = spec_for(
        &chain,
        &controls,
        &obs_pts,
        vec![1.0 / n as f64; n],
        &goal,
        s,
    );
    Ok(chain_pomdp::build_with(
        &chain,
        &m,
        &obs,
        &quadratic_control,
        &spec,
        s.rows,
    )?)
}

fn expected_reward(
    cp: &ChainPomdp,
    policy: &AlphaPolicy,
    runs: usize,
    seed: u64,
) -> Result<(f64, f64)> {
    let r = simulate(
        &cp.pomdp,
        policy,
        &SimulateOptions {
            runs,
            seed,
            precision: 1e-2,
            threads: 1,
        },
    )?;
    Ok((r.mean, r.std_err))
}

/// At most this many plan nodes are carried to a refined problem (the
/// solver evaluates every vector at every belief it touches).
pub const CARRY_CAP: usize = 256;

/// One size of the 2-D problem, solved.
#[derive(Clone, Copy)]
pub struct Sized<'a> {
    pub cp: &'a ChainPomdp,
    pub sol: &'a Solution,
    /// The carried plans' certified value at b₀ (warm starts only).
    pub carried_b0: Option<f64>,
    /// Seconds spent carrying and evaluating the previous plans.
    pub carry_s: f64,
    /// The previous size, solved (none at the first size).
    pub prev: Option<(&'a ChainPomdp, &'a Solution)>,
}

/// The 2-D problem grown over `sizes`, each size solved for `solve_s`
/// (the last entry repeats) from the previous size's plans unless
/// `fresh`; `each` per size.
pub fn two_d(
    sizes: &[usize],
    solve_s: &[f64],
    s: &Setting,
    seed: u64,
    fresh: bool,
    mut each: impl FnMut(&Sized<'_>) -> Result<()>,
) -> Result<()> {
    let m = LightDark::new(2, s.sigma);
    let (light, goal) = (light_2d(), goal_2d());
    let obs = LightDarkObs {
        light: light.clone(),
        eps: s.eps,
    };
    let mut rng: SimRng = SimRng::seed_from_u64(rng::splitmix64(seed ^ 0x2d));
    let cfg = ChainConfig {
        kappa_drift: s.kappa_drift,
        ..ChainConfig::gaussian(2).with_near(NearRule::Radius { gamma: 3.0 })
    };
    let corners = model::seed_states_2d(s.rows == Rows::Moment, s.goal_cross, &goal);
    let mut chain = Chain::batch(&m, cfg, &corners)?;
    let mut touched = Vec::new();
    let mut controls = vec![
        vec![0.0, 0.0],
        vec![1.0, 1.0],
        vec![1.0, -1.0],
        vec![-1.0, 1.0],
        vec![-1.0, -1.0],
    ];
    let mut obs_pts: Vec<Vec<f64>> = Vec::new();
    let mut prev: Option<(ChainPomdp, Solution)> = None;
    for (k, &n) in sizes.iter().enumerate() {
        if n > chain.len() {
            chain.grow(
                &m,
                &Sampler::Uniform,
                n - chain.len(),
                &mut rng,
                &mut touched,
            )?;
        }
        let c = chain_pomdp::log_count(5.0, n);
        while controls.len() < c {
            controls.push(vec![
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            ]);
        }
        while obs_pts.len() < 3 * c {
            let j = obs_pts.len() % 3;
            let pt = match j {
                0 => vec![rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0)],
                _ => {
                    let (ctr, e) = &light.0[j - 1];
                    (0..2)
                        .map(|i| (ctr[i] + rng.random_range(-*e..*e)).clamp(-2.0, 2.0))
                        .collect()
                }
            };
            obs_pts.push(pt);
        }
        let mut start: Vec<f64> = (0..chain.len())
            .map(|i| {
                let z = chain.state(i);
                let q = (z[0] + 1.5).powi(2) + (z[1] + 0.5).powi(2);
                (-q / (2.0 * 0.25)).exp() * chain.cell_volume(i)
            })
            .collect();
        if s.cliff {
            // The continuous start is inside the box: none on its edge
            // (a state there falls at once).
            for (i, v) in start.iter_mut().enumerate() {
                if chain.state(i).iter().any(|x| x.abs() >= 2.0) {
                    *v = 0.0;
                }
            }
        }
        let total: f64 = start.iter().sum();
        start.iter_mut().for_each(|v| *v /= total);
        let spec = spec_for(&chain, &controls, &obs_pts, start, &goal, s);
        let mut cp = chain_pomdp::build_with(&chain, &m, &obs, &quadratic_control, &spec, s.rows)?;
        if s.cliff {
            let sig = [s.sigma; 2];
            let drift = |_: &[f64], u: &[f64], f: &mut [f64]| f.copy_from_slice(u);
            cliff::make_cliff(&mut cp, &drift, &sig, &[-2.0; 2], &[2.0; 2], 1000.0)?;
        }
        let secs = solve_s[k.min(solve_s.len() - 1)];
        let t0 = std::time::Instant::now();
        let initial = match (&prev, fresh) {
            (Some((pcp, psol)), false) => Some(warm::carry_plan(
                &warm::Solved {
                    cp: pcp,
                    policy: &psol.policy,
                    plan: &psol.plan,
                    plan_nodes: &psol.plan_nodes,
                },
                &cp,
                CARRY_CAP,
                Duration::from_secs_f64(0.1 * secs),
                1e-3,
            )),
            _ => None,
        };
        let carry_s = t0.elapsed().as_secs_f64();
        let b0 = &cp.pomdp.start;
        let carried_b0 = initial.as_ref().map(|c| {
            c.values
                .iter()
                .map(|v| v.iter().zip(b0).map(|(a, b)| a * b).sum::<f64>())
                .fold(f64::NEG_INFINITY, f64::max)
        });
        let sol = solve(
            &cp.pomdp,
            &beliefbus_pomdp::SolveOptions {
                follow_lower_every: s.follow_lower,
                ..solve_opts_gap(secs, initial, s.trial_gap)
            },
            |_| {},
        )?;
        each(&Sized {
            cp: &cp,
            sol: &sol,
            carried_b0,
            carry_s,
            prev: prev.as_ref().map(|(c, s)| (c, s)),
        })?;
        prev = Some((cp, sol));
    }
    Ok(())
}

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("pomdp-light-dark");
    let mut p = Params::new(args);
    let sizes = p.list(&mut rep, "states", &[75, 150, 300, 600])?;
    let solve_s = p.f64(&mut rep, "solve_s", 60.0)?;
    let anytime = params::anytime(args, &mut rep)?;
    let anytime_states = p.usize(&mut rep, "anytime_states", 150)?;
    let solve_1d_s = p.f64(&mut rep, "solve_1d_s", 10.0)?;
    let sigma = p.f64(&mut rep, "noise", 0.1)?;
    let eps = p.f64(&mut rep, "epsilon", 0.1)?;
    let rate = p.f64(&mut rep, "rate", 0.1)?;
    let plot = params::raw(args, "plot");
    params::check_keys(args)?;
    anyhow::ensure!(
        sigma > 0.0 && eps > 0.0 && rate > 0.0 && solve_s > 0.0 && solve_1d_s > 0.0,
        "noise, epsilon, rate and solver times must be positive"
    );
    let runs = args.runs.unwrap_or(1000).max(2);
    rep.param("runs", runs);
    rep.param("seed", args.seed);
    let match_mean = p.usize(&mut rep, "match_mean", 0)? > 0;
    let period = p.f64(&mut rep, "period_s", 0.0)?;
    anyhow::ensure!(period >= 0.0, "period_s must be non-negative");
    let kappa_drift = p.f64(&mut rep, "kappa_drift", 1.0)?;
    anyhow::ensure!(kappa_drift > 0.0, "kappa_drift must be positive");
    let s = Setting {
        sigma,
        eps,
        rate,
        match_mean,
        period,
        kappa_drift,
        rows: params::rows(args, &mut rep)?,
        cell_goal: params::cell_goal(args, &mut rep)?,
        goal_cross: params::goal_cross(args, &mut rep)?,
        cliff: params::cliff(args, &mut rep)?,
        trial_gap: p.f64(&mut rep, "trial_gap", 0.5)?,
        follow_lower: u32::try_from(p.usize(&mut rep, "follow_lower", 0)?)
            .context("--param follow_lower: a trial count")?,
        states_1d: p.usize(&mut rep, "states_1d", 20)?,
    };
    anyhow::ensure!(
        (0.0..1.0).contains(&s.trial_gap),
        "--param trial_gap: a fraction in [0, 1)"
    );
    let solves = p.usize(&mut rep, "solves", 1)?.max(1);
    rep.lead_columns(&[
        "problem",
        "states",
        "solve_s",
        "reward",
        "reward_se",
        "reward_ci95",
    ]);
    let mut prog = Progress::new(
        "pomdp-light-dark",
        1 + sizes.len() * solves + anytime.len(),
        args.progress,
    );

    let cp1 = one_d(&s)?;
    let sol1 = solve(&cp1.pomdp, &solve_opts(solve_1d_s, None), |_| {})?;
    let (m1, se1) = expected_reward(&cp1, &sol1.policy, runs, args.seed)?;
    let traj = trajectory(&cp1, &sol1.policy, args.seed, 200);
    let light_first = plot::visits_light_before_goal(&cp1, &traj);
    let c1 = continuous_value(&cp1, &sol1.policy, &s, 1, runs, args.seed, WALLS);
    rep.results.push(
        c1.columns(
            Row::new("chain-pomdp")
                .text("problem", "1-D")
                .int("states", s.states_1d as u64)
                .num("solve_s", sol1.time_s)
                .num("reward", m1)
                .num("reward_se", se1)
                .num("reward_ci95", 1.96 * se1)
                .num("lower_b0", sol1.lower)
                .num("upper_b0", sol1.upper)
                .num("period_s", cp1.period)
                .text("light_before_goal", if light_first { "yes" } else { "no" }),
        ),
    );
    if let Some(path) = &plot {
        plot::write(Path::new(path), &cp1, &traj)?;
        rep.notes.push(format!("plot: {path}"));
    }
    prog.tick();

    let carry_check = p.usize(&mut rep, "carry_check", 0)? > 0;
    let open = p.usize(&mut rep, "open", 0)? > 0;
    let budgets = params::budgets(args, &mut rep, &sizes, solve_s)?;
    let eval_seed = params::eval_seeds(args, &mut rep)?;
    let (dump, load, trace) = (
        params::raw(args, "dump"),
        params::raw(args, "load"),
        params::raw(args, "trace"),
    );
    anyhow::ensure!(
        load.is_none() || !carry_check,
        "--param load: not with carry_check (no previous solve)"
    );
    // Created up front: a run of many minutes must not fail at its first
    // policy for want of a directory.
    if let Some(dir) = &dump {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--param dump: creating the directory {dir}"))?;
    }
    // Loaded policies: the chains rebuilt from the same seeds, no solving.
    let (budgets, fresh) = match load {
        Some(_) => (vec![1e-3], true),
        None => (budgets, false),
    };
    // Independent solves: the chain's samples (and controls, observation
    // points) from seed + r; the evaluation's random numbers from
    // `eval_seed` (by default `seed` for every solve).
    for r in 0..solves as u64 {
        // The previous size's continuous outcomes (walls, open) in this
        // solve: same seed and period, so the returns pair episode by episode.
        let mut before: size_row::Before = None;
        two_d(&sizes, &budgets, &s, args.seed + r, fresh, |z| {
            let loaded = load
                .as_ref()
                .map(|d| trace::load(d, r, z.cp, z.sol))
                .transpose()?;
            let z = &Sized {
                sol: loaded.as_ref().unwrap_or(z.sol),
                ..*z
            };
            let cp = z.cp;
            if let (true, Some(prev)) = (carry_check, z.prev) {
                let rows = carry::diagnose(prev, (cp, z.sol), z.carried_b0, &s, runs, args.seed);
                for r in rows {
                    eprintln!("{r:?}");
                    rep.results.push(r);
                }
            }
            if let Some(dir) = &dump {
                let path = trace::policy_path(dir, r, cp.n_chain());
                let w = z.sol.policy.write(&path);
                w.with_context(|| format!("--param dump: writing {}", path.display()))?;
            }
            let e = size_row::Eval {
                runs,
                seed: eval_seed(args.seed, r),
                open,
                solve: r,
                trace: trace.clone(),
            };
            let row = size_row::size_row(z, &s, &e, &mut before)?;
            rep.results.push(row);
            prog.tick();
            Ok(())
        })?;
    }
    replicates::summarise(&mut rep);
    for &budget in &anytime {
        two_d(&[anytime_states], &[budget], &s, args.seed, true, |z| {
            let (m, se) = expected_reward(z.cp, &z.sol.policy, runs, args.seed)?;
            rep.results.push(
                Row::new("anytime")
                    .text("problem", "2-D")
                    .int("states", z.cp.n_chain() as u64)
                    .num("solve_s", z.sol.time_s)
                    .num("reward", m)
                    .num("reward_se", se)
                    .num("reward_ci95", 1.96 * se)
                    .num("lower_b0", z.sol.lower)
                    .num("upper_b0", z.sol.upper),
            );
            Ok(())
        })?;
        prog.tick();
    }
    paper::append(&mut rep);
    Ok(rep)
}

#[cfg(test)]
#[path = "pomdp_light_dark_tests.rs"]
mod tests;
