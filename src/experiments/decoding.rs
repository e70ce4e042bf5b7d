//! `decoding` — MAP trajectory decoding, paper 001 §VII-D (Fig. 6) and
//! thesis §3.6.2 (Fig. 3-8): the 2-D linear system dx_i = −a x_i dt + σ dw_i,
//! dy_i = x_i dt + γ dv_i, σ = γ = 0.1, T = 2 s; total squared error
//! ∫₀^T ‖x − x̂‖² dt at 1,000 and 20,000 states and its convergence over n.
//!
//! Paper 001 (a = 1): 11.34e-3 at 1,000 states, 3.3e-3 at 20,000 (single
//! trajectories, Fig. 6 shows x₁ only); thesis (a = 3): 4.9e-3 at 20,000
//! (one trajectory; the curve averages 100). Both settings run (`a=1,3`).
//!
//! Settings the papers leave open, chosen here (all printed):
//! - x(0) = (0.5, −0.5), known to every decoder (the root (0, x₀) of
//!   Alg. 3.2); the floor is also given for x(0) ~ stationary N(0, σ²/2a)
//!   unknown, and for known x(0) it does not depend on x(0)'s value;
//! - truth and y simulated by Euler–Maruyama on a 1 ms grid (the
//!   observation increment of step k uses x before the step); S = [−1, 1]².
//!   The error integral is the Riemann sum of ‖x − x̂‖² on that grid, x̂ the
//!   linear interpolation of the decoded points.
//!
//! The floor (`exact_map`): for this linear-Gaussian system the MAP
//! trajectory is the posterior mean, computed exactly by a Kalman filter +
//! RTS smoother on the simulation's own 1 ms model (per axis; the axes are
//! independent). Its expected error Σ_k tr P_s(t_k) dt is exact and needs no
//! Monte Carlo (`exact_map_expected`, for both x(0) settings, per axis and
//! total). `grid_map` is the same smoother read only at the decoder's layer
//! times and interpolated: the floor of any decoder on that time grid.
//!
//! Methods (n = number of chain states):
//! - `layered_uniform` — paper 001's form: one set of n states uniform on S,
//!   Viterbi over layers t_k = kτ (the chain M_n^τ, no self-loops) with the
//!   corrections of [`crate::filter::layered_decoder`] (Gaussian kernel with
//!   the locally linearised transition, density scores, trapezoid edge
//!   likelihood);
//! - `layered_belief` — the thesis's form on [0, T] × S with n states in
//!   total, n/K per layer, each layer sampled around the Kalman filter's
//!   (causal) belief at its time, covariance inflated by κ², mixed with a
//!   uniform fraction (thesis §3.3.3's heuristic; the EKF is the Kalman
//!   filter here);
//! - baselines (`--param baselines=1`): `alg3.2` — Alg. 3.2 on the
//!   uniformly sampled time-augmented chain (σ_t = 0.01, moment-matching
//!   kernel, k = ⌈1.5 ln n⌉, half the states on {T} × S, Girsanov edge
//!   likelihood at the left point); `viterbi` on the time-equalised M_n^δ
//!   with sampled observations every Δ = 0.02 s; `viterbi_advected` on the
//!   advected chain (Δt = δ = Δ).
//!
//! Why the baselines stay 3–7× above the floor (measured, a = 3, 5 runs):
//! their chains' transition probabilities are not transition *densities* —
//! the moment-matching kernel keeps ≤ 1 + d + d(d+1)/2 neighbours (mean
//! out-degree 3.2–3.9 in 3-D) and no Gaussian shape, the most probable chain
//! path favours large cells (−log v missing), M_n^δ's self-loops make
//! standing still most probable, and in 3-D with σ_t ≪ 1 every edge is
//! drift-dominated (Δt ≈ r, transition std σ√r below the state spacing r).
//! The previous floor (`rts_sampled_0.02`, RTS on y_k = Δy/Δ as x(t_k) +
//! noise) is slightly mis-specified; `exact_map` replaces it.

use anyhow::Result;
use nalgebra::{DMatrix, DVector};
use rand_distr::StandardNormal;

use super::chain_util::{mean_se, Params};
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::belief::Gaussian;
use crate::chain::{Chain, ChainConfig, NearRule, Sampler, TimeEqualized};
use crate::filter::decoder::{decode_time_augmented, viterbi, Decoded, ObsPath, TimeAugmented};
use crate::filter::layered_decoder::{decode_layered, Layer, LayeredChain, LayeredConfig};
pub use crate::filter::rts::{rts_1d, Rts1};
use crate::model::linear::LinearSde;
use crate::model::Bounds;
use crate::rng::stream;
use rand::RngExt;

/// Settings shared by every `a`.
struct Setup {
    runs: usize,
    seed: u64,
    progress: bool,
    sigma: f64,
    gamma: f64,
    t_end: f64,
    dt_obs: f64,
    sizes: Vec<usize>,
    sigma_t: f64,
    boundary_fraction: f64,
    layer_step: f64,
    inflate: f64,
    uniform_fraction: f64,
    c_near: f64,
    normalise: bool,
    baselines: bool,
}

const X0: [f64; 2] = [0.5, -0.5];
const DT_SIM: f64 = 1e-3;

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("decoding");
    let mut p = Params::new(args);
    let runs = args.runs.unwrap_or(100);
    rep.param("runs", runs);
    rep.param("seed", args.seed);
    let a_list = p.list(&mut rep, "a", &[1, 3])?;
    let s = Setup {
        runs,
        seed: args.seed,
        progress: args.progress,
        sigma: p.f64(&mut rep, "sigma", 0.1)?,
        gamma: p.f64(&mut rep, "gamma", 0.1)?,
        t_end: p.f64(&mut rep, "horizon_s", 2.0)?,
        dt_obs: p.f64(&mut rep, "obs_period_s", 0.02)?,
        sizes: p.list(&mut rep, "states", &[1000, 2000, 5000, 10000, 20000])?,
        sigma_t: p.f64(&mut rep, "sigma_t", 0.01)?,
        boundary_fraction: p.f64(&mut rep, "boundary_fraction", 0.5)?,
        layer_step: p.f64(&mut rep, "layer_step_s", 0.0)?,
        inflate: p.f64(&mut rep, "inflate", 3.0)?,
        uniform_fraction: p.f64(&mut rep, "uniform_fraction", 0.1)?,
        c_near: p.f64(&mut rep, "c_near", 3.0)?,
        normalise: p.usize(&mut rep, "normalise", 0)? != 0,
        baselines: p.usize(&mut rep, "baselines", 1)? != 0,
    };
    p.finish()?;
    rep.param("x0", "(0.5, -0.5), known");
    rep.param("sim_dt_s", DT_SIM);
    rep.param("bounds", "[-1,1]^2");
    if !(s.layer_step >= 0.0 && s.dt_obs > 0.0 && s.t_end > 0.0) {
        anyhow::bail!("horizon and obs_period_s must be positive, layer_step_s ≥ 0 (0: auto)");
    }
    for &a in &a_list {
        run_setting(&mut rep, &s, a as f64)?;
    }
    for &a in &a_list {
        let a = a as f64;
        let steps = (s.t_end / DT_SIM).round() as usize;
        for (label, p0) in [
            ("known", 0.0),
            ("stationary", s.sigma * s.sigma / (2.0 * a)),
        ] {
            let axis = expected_floor(a, s.sigma, s.gamma, p0, steps);
            rep.results.push(
                Row::new("exact_map_expected")
                    .num("a", a)
                    .text("x0", label)
                    .num("sq_error", 2.0 * axis)
                    .num("x1_only", axis),
            );
        }
    }
    rep.paper.push(
        Row::new("decoder")
            .num("a", 1.0)
            .int("n_states", 1000)
            .num("sq_error", 11.34e-3)
            .text("source", "paper 001 Fig. 6a, one trajectory"),
    );
    rep.paper.push(
        Row::new("decoder")
            .num("a", 1.0)
            .int("n_states", 20000)
            .num("sq_error", 3.3e-3)
            .text("source", "paper 001 Fig. 6b, one trajectory"),
    );
    rep.paper.push(
        Row::new("decoder")
            .num("a", 3.0)
            .int("n_states", 20000)
            .num("sq_error", 4.9e-3)
            .text("source", "thesis Fig. 3-8a, one trajectory"),
    );
    rep.notes.push(
        "the papers' figures are single trajectories: compare them with one run's spread \
         (p10..p90) and with exact_map, the linear-Gaussian floor (the exact MAP = posterior \
         mean) that no decoder beats on average; frac_below_paper = share of our trajectories \
         whose exact-MAP error is already below the paper's figure"
            .into(),
    );
    rep.notes.push(
        "layered_uniform: n = states in S (paper 001's M_n); layered_belief and alg3.2: \
         n = states in [0,T]×S in total (thesis)"
            .into(),
    );
    Ok(rep)
}

/// Simulated truth and continuous observation path on the 1 ms grid.
struct Sim {
    times: Vec<f64>,
    truth: Vec<f64>,
    ypath: Vec<f64>,
}

fn simulate(a: f64, s: &Setup, seed: u64, run: usize) -> Sim {
    let steps = (s.t_end / DT_SIM).round() as usize;
    let mut rng = stream(seed, run as u64);
    let mut x = X0;
    let mut y = [0.0, 0.0];
    let mut sim = Sim {
        times: vec![0.0],
        truth: X0.to_vec(),
        ypath: vec![0.0, 0.0],
    };
    for k in 1..=steps {
        for i in 0..2 {
            let xi = x[i];
            x[i] +=
                -a * xi * DT_SIM + s.sigma * DT_SIM.sqrt() * rng.sample::<f64, _>(StandardNormal);
            y[i] += xi * DT_SIM + s.gamma * DT_SIM.sqrt() * rng.sample::<f64, _>(StandardNormal);
        }
        sim.truth.extend_from_slice(&x);
        sim.times.push(k as f64 * DT_SIM);
        sim.ypath.extend_from_slice(&y);
    }
    sim
}

/// Expected ∫‖x − x̂‖² of the exact smoother on one axis (Riemann sum
/// Σ_k P_s(t_k) h over k = 0..N, like the measured error).
pub fn expected_floor(a: f64, sigma: f64, gamma: f64, p0: f64, steps: usize) -> f64 {
    let r = rts_1d(a, sigma, gamma, 0.0, p0, DT_SIM, &vec![0.0; steps]);
    r.smooth_p.iter().sum::<f64>() * DT_SIM
}

fn sq_err(sim: &Sim, dec: &Decoded) -> f64 {
    let mut xh = [0.0; 2];
    let mut s = 0.0;
    for (k, &t) in sim.times.iter().enumerate() {
        dec.at(t, &mut xh);
        s += ((sim.truth[2 * k] - xh[0]).powi(2) + (sim.truth[2 * k + 1] - xh[1]).powi(2)) * DT_SIM;
    }
    s
}

fn quantile(v: &[f64], p: f64) -> f64 {
    let mut w = v.to_vec();
    w.sort_by(f64::total_cmp);
    w[((w.len() - 1) as f64 * p).round() as usize]
}

fn stat_row(name: &str, a: f64, n: Option<usize>, errs: &[f64]) -> Row {
    let (m, se) = mean_se(errs);
    let mut r = Row::new(name).num("a", a);
    if let Some(n) = n {
        r = r.int("n_states", n as u64);
    }
    r.num("sq_error", m)
        .num("stderr", se)
        .num("p10", quantile(errs, 0.1))
        .num("p90", quantile(errs, 0.9))
}

fn run_setting(rep: &mut ExperimentReport, s: &Setup, a: f64) -> Result<()> {
    let steps_sim = (s.t_end / DT_SIM).round() as usize;
    let k_obs = (s.t_end / s.dt_obs).round() as usize;
    let stride = (s.dt_obs / DT_SIM).round() as usize;
    let bounds = Bounds::new_box(&[-1.0, -1.0], &[1.0, 1.0])?;
    let model = LinearSde::new(
        "decode2",
        DMatrix::from_diagonal_element(2, 2, -a),
        DMatrix::zeros(2, 0),
        DMatrix::from_diagonal_element(2, 2, s.sigma),
        DMatrix::identity(2, 2),
        vec![s.gamma / s.dt_obs.sqrt(); 2],
        bounds,
    );
    let g_coeff = [s.gamma, s.gamma];
    // layer times per size: τ = layer_step_s, or (auto, 0) the largest
    // τ ≤ 0.2 s whose transition std σ√τ is ρ* = 3 state spacings
    // r = (μ(S)/n)^{1/2}, on T/K
    let layer_times_of = |n: usize| -> Vec<f64> {
        let tau = if s.layer_step > 0.0 {
            s.layer_step
        } else {
            let r = (bounds.volume() / n as f64).sqrt();
            (3.0 * r / s.sigma).powi(2).min(0.2)
        };
        let k = (s.t_end / tau).ceil().max(1.0) as usize;
        (0..=k).map(|j| j as f64 * s.t_end / k as f64).collect()
    };
    let lcfg = LayeredConfig {
        c_near: s.c_near,
        normalise: s.normalise,
        ..LayeredConfig::default()
    };
    // chains that do not depend on the data, once per size
    let mut uni_chains = vec![];
    let mut aug_chains = vec![];
    let mut mn_chains = vec![];
    let mut adv_chains = vec![];
    for &n in &s.sizes {
        let mut rng = stream(s.seed, 500 + n as u64);
        let set = Layer::uniform(&bounds, n, &mut rng);
        let layer_times = layer_times_of(n);
        let mut layer_of = vec![1; layer_times.len()];
        layer_of[0] = 0;
        uni_chains.push(LayeredChain::build(
            &model,
            layer_times,
            vec![Layer::point(&X0), set],
            layer_of,
            lcfg,
        )?);
        if !s.baselines {
            continue;
        }
        let aug = TimeAugmented::new(&model, s.sigma_t, s.t_end).map_err(anyhow::Error::msg)?;
        let mut pts = vec![0.0, X0[0], X0[1]];
        let mut z = [0.0; 3];
        for _ in 0..n {
            Sampler::Uniform.sample(crate::model::SdeModel::bounds(&aug), &mut rng, &mut z);
            if rng.random::<f64>() < s.boundary_fraction {
                // on {T} × S, jittered by < 1e-9 T (see decode_time_augmented)
                z[0] = s.t_end * (1.0 - 1e-9 * rng.random::<f64>());
            }
            pts.extend_from_slice(&z);
        }
        let mut cfg = ChainConfig::moment_matched(3);
        cfg.near = NearRule::Knn { c: 1.5 };
        let mut c = Chain::batch(&aug, cfg, &pts)?;
        c.compact();
        aug_chains.push(c);
        let mut cfg2 = ChainConfig::moment_matched(2);
        cfg2.near = NearRule::Knn { c: 1.5 };
        let mut c2 = Chain::sample_batch(&model, cfg2, &Sampler::Uniform, n, &mut rng)?;
        let mut eq = TimeEqualized::new(s.dt_obs)?;
        eq.fit(c2.holding());
        c2.compact();
        mn_chains.push((c2, eq.delta()));
        let mut cfg3 = ChainConfig::moment_matched(2);
        cfg3.near = NearRule::Knn { c: 1.5 };
        cfg3.step = Some(s.dt_obs);
        let mut c3 = Chain::sample_batch(&model, cfg3, &Sampler::Uniform, n, &mut rng)?;
        let mut eq3 = TimeEqualized::new(s.dt_obs)?;
        eq3.fit(c3.holding());
        c3.compact();
        adv_chains.push((c3, eq3.delta()));
    }
    let disc = model.discretize(s.dt_obs);
    let ns = s.sizes.len();
    let mut err_uni = vec![vec![]; ns];
    let mut err_bel = vec![vec![]; ns];
    let mut deg_bel = vec![0.0; ns];
    let mut err_aug = vec![vec![]; ns];
    let mut err_mn = vec![vec![]; ns];
    let mut err_adv = vec![vec![]; ns];
    let mut err_exact = vec![];
    let mut err_exact_x1 = vec![];
    let mut err_grid = vec![vec![]; ns];
    let mut err_sampled_rts = vec![];
    let mut bar = Progress::new(&format!("decoding a={a}"), s.runs, s.progress);
    for r in 0..s.runs {
        let sim = simulate(a, s, s.seed, r);
        let path = ObsPath {
            times: sim.times.clone(),
            y: sim.ypath.clone(),
            m: 2,
        };
        // exact floor: Kalman + RTS on the simulation's own 1 ms model
        let mut rts = vec![];
        for i in 0..2 {
            let obs: Vec<f64> = (0..steps_sim)
                .map(|k| (sim.ypath[2 * (k + 1) + i] - sim.ypath[2 * k + i]) / DT_SIM)
                .collect();
            rts.push(rts_1d(a, s.sigma, s.gamma, X0[i], 0.0, DT_SIM, &obs));
        }
        let mut e = [0.0; 2];
        for k in 0..=steps_sim {
            for i in 0..2 {
                e[i] += (sim.truth[2 * k + i] - rts[i].smooth_m[k]).powi(2) * DT_SIM;
            }
        }
        err_exact.push(e[0] + e[1]);
        err_exact_x1.push(e[0]);
        let at = |t: f64| ((t / DT_SIM).round() as usize).min(steps_sim);
        for i in 0..ns {
            let layer_times = &uni_chains[i].times;
            let n_layers = layer_times.len() - 1;
            let grid = Decoded {
                slots: vec![],
                times: layer_times.clone(),
                states: layer_times
                    .iter()
                    .flat_map(|&t| [rts[0].smooth_m[at(t)], rts[1].smooth_m[at(t)]])
                    .collect(),
                log_score: 0.0,
            };
            err_grid[i].push(sq_err(&sim, &grid));
            let dec = decode_layered(&model, &uni_chains[i], &g_coeff, &path, None)?;
            err_uni[i].push(sq_err(&sim, &dec));
            // layers around the causal Kalman belief at each layer time
            let n = s.sizes[i];
            let per = (n / n_layers).max(1);
            let mut rng = stream(s.seed, 1_000_000 + (r * ns + i) as u64);
            let mut layers = vec![Layer::point(&X0)];
            for &t in &layer_times[1..] {
                let k = at(t);
                let b = Gaussian::diagonal(
                    &[rts[0].pred_m[k], rts[1].pred_m[k]],
                    &[rts[0].pred_p[k].sqrt(), rts[1].pred_p[k].sqrt()],
                );
                layers.push(Layer::around(
                    &b,
                    s.inflate,
                    s.uniform_fraction,
                    &bounds,
                    per,
                    &mut rng,
                )?);
            }
            let layer_of: Vec<usize> = (0..=n_layers).collect();
            let ch = LayeredChain::build(&model, layer_times.clone(), layers, layer_of, lcfg)?;
            deg_bel[i] += ch.mean_out_degree() / s.runs as f64;
            let dec = decode_layered(&model, &ch, &g_coeff, &path, None)?;
            err_bel[i].push(sq_err(&sim, &dec));
        }
        if s.baselines {
            let mut obs_t = vec![];
            let mut ys = vec![];
            for k in 1..=k_obs {
                let (i1, i0) = (k * stride, (k - 1) * stride);
                obs_t.push(k as f64 * s.dt_obs);
                for c in 0..2 {
                    ys.push((sim.ypath[i1 * 2 + c] - sim.ypath[i0 * 2 + c]) / s.dt_obs);
                }
            }
            for i in 0..ns {
                let v = aug_chains[i].compact_view().expect("compact");
                let dec = decode_time_augmented(&model, &v, 0, s.t_end, &g_coeff, &path)?;
                err_aug[i].push(sq_err(&sim, &dec));
                for (chains, errs) in [(&mn_chains, &mut err_mn), (&adv_chains, &mut err_adv)] {
                    let (c2, delta) = &chains[i];
                    let v2 = c2.compact_view().expect("compact");
                    let mut near = vec![];
                    c2.nearest(&X0, 1, &mut near);
                    let mut prior = vec![0.0; c2.len()];
                    prior[near[0].0 as usize] = 1.0;
                    let dec2 = viterbi(&model, &v2, *delta, &prior, 0.0, &obs_t, &ys)?;
                    errs[i].push(sq_err(&sim, &dec2));
                }
            }
            // the previous floor: RTS on the 0.02 s sampled observations
            let rts = rts_sampled(&disc, &X0, &ys, s.gamma / s.dt_obs.sqrt());
            let dec = Decoded {
                slots: vec![],
                times: (0..=k_obs).map(|k| k as f64 * s.dt_obs).collect(),
                states: rts,
                log_score: 0.0,
            };
            err_sampled_rts.push(sq_err(&sim, &dec));
        }
        bar.tick();
    }
    let paper: &[(usize, f64)] = if a == 1.0 {
        &[(1000, 11.34e-3), (20000, 3.3e-3)]
    } else if a == 3.0 {
        &[(20000, 4.9e-3)]
    } else {
        &[]
    };
    let mut row = stat_row("exact_map", a, None, &err_exact);
    for &(n, v) in paper {
        let f = err_exact.iter().filter(|&&e| e <= v).count() as f64 / err_exact.len() as f64;
        row = row.num(&format!("frac_below_paper_{n}"), f);
    }
    rep.results.push(row);
    let mut row = stat_row("exact_map_x1", a, None, &err_exact_x1);
    for &(n, v) in paper {
        let f = err_exact_x1.iter().filter(|&&e| e <= v).count() as f64 / err_exact_x1.len() as f64;
        row = row.num(&format!("frac_below_paper_{n}"), f);
    }
    rep.results.push(row);
    for (i, &n) in s.sizes.iter().enumerate() {
        let tau = uni_chains[i].times[1];
        rep.results
            .push(stat_row("grid_map", a, Some(n), &err_grid[i]).num("layer_step_s", tau));
    }
    if s.baselines {
        rep.results
            .push(stat_row("rts_sampled_0.02", a, None, &err_sampled_rts));
    }
    let floor = mean_se(&err_exact).0;
    let mut curves: Vec<(&str, &Vec<Vec<f64>>)> =
        vec![("layered_uniform", &err_uni), ("layered_belief", &err_bel)];
    if s.baselines {
        curves.extend([
            ("alg3.2", &err_aug),
            ("viterbi", &err_mn),
            ("viterbi_advected", &err_adv),
        ]);
    }
    for (name, errs) in &curves {
        for (i, &n) in s.sizes.iter().enumerate() {
            let mut row = stat_row(name, a, Some(n), &errs[i]);
            let m = mean_se(&errs[i]).0;
            row = row.num("ratio_to_floor", m / floor);
            row = match *name {
                "layered_uniform" => row.num("out_degree", uni_chains[i].mean_out_degree()),
                "layered_belief" => row.num("out_degree", deg_bel[i]),
                "alg3.2" => row.num("out_degree", aug_chains[i].mean_out_degree()),
                "viterbi" => row.num("delta_s", mn_chains[i].1),
                _ => row.num("delta_s", adv_chains[i].1),
            };
            rep.results.push(row);
        }
    }
    if s.sizes.len() > 1 {
        let xs: Vec<f64> = s.sizes.iter().map(|&n| (n as f64).ln()).collect();
        let fit = |errs: &[Vec<f64>]| {
            let ys: Vec<f64> = errs
                .iter()
                .map(|e| (mean_se(e).0 - floor).max(1e-12).ln())
                .collect();
            slope(&xs, &ys)
        };
        let txt: Vec<String> = curves
            .iter()
            .map(|(n, e)| format!("{n} {:.3}", fit(e)))
            .collect();
        rep.notes.push(format!(
            "a={a}: log-log slope of (sq_error − exact_map) vs n: {}",
            txt.join(", ")
        ));
    }
    Ok(())
}

/// Least-squares slope of y on x.
pub fn slope(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    sxy / sxx
}

/// Kalman filter + RTS smoother (C = I, R = r² I, known x₀) on the sampled
/// observations y_k = Δy/Δ treated as x(t_k) + noise (the previous floor:
/// slightly mis-specified, y_k averages x over the period); returns the
/// smoothed means at t₀..t_K, flat.
fn rts_sampled(
    disc: &crate::model::linear::Discretized,
    x0: &[f64],
    ys: &[f64],
    r: f64,
) -> Vec<f64> {
    let k = ys.len() / 2;
    let (ad, qd) = (&disc.ad, &disc.qd);
    let rr = DMatrix::from_diagonal_element(2, 2, r * r);
    let mut mf = vec![DVector::from_column_slice(x0)];
    let mut pf = vec![DMatrix::zeros(2, 2)];
    let mut mp = vec![DVector::zeros(2)];
    let mut pp = vec![DMatrix::zeros(2, 2)];
    for j in 0..k {
        let m = ad * &mf[j];
        let p = ad * &pf[j] * ad.transpose() + qd;
        let s = &p + &rr;
        let kg = &p * s.try_inverse().expect("S positive definite");
        let y = DVector::from_column_slice(&ys[2 * j..2 * j + 2]);
        let m2 = &m + &kg * (y - &m);
        let p2 = (DMatrix::identity(2, 2) - &kg) * &p;
        mp.push(m);
        pp.push(p);
        mf.push(m2);
        pf.push(p2);
    }
    let mut ms = mf.clone();
    for j in (0..k).rev() {
        let pinv = pp[j + 1]
            .clone()
            .try_inverse()
            .unwrap_or_else(|| DMatrix::zeros(2, 2));
        let g = &pf[j] * ad.transpose() * pinv;
        ms[j] = &mf[j] + &g * (&ms[j + 1] - &mp[j + 1]);
    }
    ms.iter()
        .flat_map(|m| m.iter().copied().collect::<Vec<_>>())
        .collect()
}
