//! `vanderpol` — paper 001 eq. 12 / thesis §3.4.2 (Fig. 3-3): the noisy
//! Van der Pol oscillator (μ = 2) filtered by the chain filter, a bootstrap
//! PF with 100 particles, the EKF and the UKF over 100 runs; mean error and
//! run time, plus the error-versus-compute curve of chain filter and PF.
//!
//! Paper: chain 0.1816, PF-100 0.1849, EKF diverges (x₂); 0.2 s vs 0.013 s.
//! Unstated there and chosen here (all printed in params): e₁ = e₂ = 0.1,
//! a sampled x₁ measurement every Δ = 0.01 s with σ = 0.1 (continuous
//! e₃ = σ√Δ = 0.01), T = 10 s, x(0) ~ N((0.5, 0), 0.2² I) which is also
//! the filters' prior, S = [−3, 3] × [−6, 6]. The chain is a batch chain
//! built once per size with the moment-matching kernel and
//! k = ⌈1.5 log n⌉ neighbours, δ ≤ Δ, on states concentrated by the thesis's
//! heuristic (§3.3.3) — the prior propagated through the dynamics, here by
//! simulation ([`predictive_points`]), mixed with 10 % uniform states
//! (`--param sampling=uniform` for the papers' uniform chain);
//! its construction time is reported separately from the per-run filter
//! time (it does not depend on the data). The error is
//! (1/T) Σ ‖x_k − x̂_k‖ Δ over the observation times.

use anyhow::Result;

use super::chain_util::{
    draw_from, mean_se, predictive_points, run_filter, simulate, Params, RunResult,
};
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::belief::Gaussian;
use crate::chain::{Chain, ChainConfig, Sampler};
use crate::filter::chain_filter::ChainFilter;
use crate::filter::ekf::{Ekf, EkfConfig};
use crate::filter::pf::{Pf, PfConfig};
use crate::filter::ukf::{Ukf, UkfConfig};
use crate::filter::BayesFilter;
use crate::model::vanderpol::{VanDerPol, VanDerPolParams};
use crate::model::SdeModel;
use crate::rng::stream;

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("vanderpol");
    let mut p = Params::new(args);
    let runs = args.runs.unwrap_or(100);
    rep.param("runs", runs);
    rep.param("seed", args.seed);
    let t_end = p.f64(&mut rep, "horizon_s", 10.0)?;
    let dt = p.f64(&mut rep, "obs_period_s", 0.01)?;
    let obs_std = p.f64(&mut rep, "obs_std", 0.1)?;
    let e = p.f64(&mut rep, "process_noise", 0.1)?;
    let n_chain = p.usize(&mut rep, "states", 1000)?;
    let particles = p.usize(&mut rep, "particles", 100)?;
    let chain_sizes = p.list(
        &mut rep,
        "curve_states",
        &[500, 1000, 2000, 3000, 4000, 8000],
    )?;
    let pf_sizes = p.list(&mut rep, "curve_particles", &[25, 50, 100, 200, 400, 1000])?;
    let c_knn = p.f64(&mut rep, "knn_c", 1.5)?;
    let kernel = p.choice(
        &mut rep,
        "kernel",
        "moment_matched",
        &["moment_matched", "gaussian"],
    )?;
    let sampling = p.choice(
        &mut rep,
        "sampling",
        "predictive",
        &["predictive", "uniform"],
    )?;
    let uniform_fraction = p.f64(&mut rep, "uniform_fraction", 0.1)?;
    let kappa_drift = p.f64(&mut rep, "kappa_drift", 2.0)?;
    let step = p.f64(&mut rep, "step_s", dt)?;
    let flush_mass = p.f64(
        &mut rep,
        "flush_mass",
        crate::filter::chain_filter::FLUSH_MASS,
    )?;
    // an absolute flush threshold instead of the mass bound, if > 0
    let flush = p.f64(&mut rep, "flush", 0.0)?;
    p.finish()?;
    rep.param("mu", 2.0);
    rep.param("prior", "N((0.5, 0), 0.2^2 I)");
    let model = VanDerPol::new(VanDerPolParams {
        e1: e,
        e2: e,
        obs_std,
        ..VanDerPolParams::default()
    })
    .map_err(anyhow::Error::msg)?;
    let prior = Gaussian::diagonal(&[0.5, 0.0], &[0.2, 0.2]);
    let steps = (t_end / dt).round() as usize;
    let mut sizes: Vec<usize> = chain_sizes.clone();
    if !sizes.contains(&n_chain) {
        sizes.push(n_chain);
    }
    let mut psizes: Vec<usize> = pf_sizes.clone();
    if !psizes.contains(&particles) {
        psizes.push(particles);
    }
    // chains, built once per size
    let mut filters = vec![];
    let mut build_s = vec![];
    for &n in &sizes {
        let mut cfg = if kernel == "gaussian" {
            ChainConfig::gaussian(2)
        } else {
            ChainConfig::moment_matched(2)
        };
        cfg.near = crate::chain::NearRule::Knn { c: c_knn };
        if kernel != "gaussian" {
            cfg.kappa_drift = kappa_drift;
        }
        cfg.step = (step > 0.0).then_some(step);
        let t0 = std::time::Instant::now();
        let mut rng = stream(args.seed, 9_000 + n as u64);
        let pts = if sampling == "uniform" {
            Sampler::Uniform.sample_many(model.bounds(), n, &mut rng)
        } else {
            predictive_points(&model, &prior, t_end, n, uniform_fraction, dt, &mut rng)
        };
        let chain = Chain::batch(&model, cfg, &pts)?;
        let mut f = ChainFilter::new(model.clone(), chain, dt)?;
        f.set_flush_mass(flush_mass);
        if flush > 0.0 {
            f.set_flush_mass(flush_mass);
            if flush > 0.0 {
                f.set_flush(flush);
            }
        }
        build_s.push(t0.elapsed().as_secs_f64());
        filters.push(f);
    }
    let mut chain_res: Vec<Vec<RunResult>> = vec![vec![]; sizes.len()];
    let mut pf_res: Vec<Vec<RunResult>> = vec![vec![]; psizes.len()];
    let mut ekf_res = vec![];
    let mut ukf_res = vec![];
    let mut bar = Progress::new("vanderpol", runs, args.progress);
    for r in 0..runs {
        let mut rng = stream(args.seed, r as u64);
        let x0 = draw_from(&model, &prior, &mut rng);
        let rec = simulate(&model, &x0, dt, steps, 1e-3, &mut rng);
        for (i, f) in filters.iter_mut().enumerate() {
            f.reset(0.0, &prior);
            chain_res[i].push(run_filter(f, &rec, None));
        }
        for (i, &np) in psizes.iter().enumerate() {
            let cfg = PfConfig {
                particles: np,
                seed: args.seed.wrapping_mul(1000).wrapping_add(r as u64),
                max_dt: dt,
                ..PfConfig::default()
            };
            let mut pf = Pf::new(model.clone(), &cfg, &prior, 0.0)?;
            pf_res[i].push(run_filter(&mut pf, &rec, None));
        }
        let mut ekf = Ekf::new(model.clone(), &EkfConfig { max_dt: dt }, &prior, 0.0)?;
        ekf_res.push(run_filter(&mut ekf, &rec, None));
        let mut ukf = Ukf::new(model.clone(), &UkfConfig::default(), &prior, 0.0)?;
        ukf_res.push(run_filter(&mut ukf, &rec, None));
        bar.tick();
    }
    let summarize = |v: &[RunResult]| {
        let ok: Vec<f64> = v
            .iter()
            .filter(|r| !r.diverged)
            .map(|r| r.mean_error)
            .collect();
        let (m, se) = mean_se(&ok);
        let (t, _) = mean_se(&v.iter().map(|r| r.time_s).collect::<Vec<_>>());
        let (c, _) = mean_se(&v.iter().map(|r| r.cpu_s).collect::<Vec<_>>());
        (m, se, t, c, v.len() - ok.len())
    };
    let ci = sizes.iter().position(|&n| n == n_chain).unwrap_or(0);
    let (m, se, t, c, div) = summarize(&chain_res[ci]);
    rep.results.push(
        Row::new("chain")
            .int("n_states", n_chain as u64)
            .num("mean_error", m)
            .num("stderr", se)
            .num("time_s", t)
            .num("cpu_s", c)
            .num("build_s", build_s[ci])
            .num("delta_s", filters[ci].delta())
            .num("out_degree", filters[ci].chain().mean_out_degree())
            .int("diverged", div as u64),
    );
    let pi = psizes.iter().position(|&n| n == particles).unwrap_or(0);
    let (m, se, t, c, div) = summarize(&pf_res[pi]);
    rep.results.push(
        Row::new("pf")
            .int("particles", particles as u64)
            .num("mean_error", m)
            .num("stderr", se)
            .num("time_s", t)
            .num("cpu_s", c)
            .int("diverged", div as u64),
    );
    let pf_ref_err = m;
    let pf_ref_time = c;
    for (name, v) in [("ekf", &ekf_res), ("ukf", &ukf_res)] {
        let (m, se, t, c, div) = summarize(v);
        rep.results.push(
            Row::new(name)
                .num("mean_error", m)
                .num("stderr", se)
                .num("time_s", t)
                .num("cpu_s", c)
                .int("diverged", div as u64),
        );
    }
    let mut reached = None;
    for (i, &n) in sizes.iter().enumerate() {
        let (m, se, t, c, _) = summarize(&chain_res[i]);
        rep.results.push(
            Row::new("chain_curve")
                .int("n_states", n as u64)
                .num("mean_error", m)
                .num("stderr", se)
                .num("time_s", t)
                .num("cpu_s", c)
                .num("out_degree", filters[i].chain().mean_out_degree()),
        );
        if m <= pf_ref_err && reached.is_none_or(|(_, cc)| c < cc) {
            reached = Some((n, c));
        }
    }
    for (i, &n) in psizes.iter().enumerate() {
        let (m, se, t, c, _) = summarize(&pf_res[i]);
        rep.results.push(
            Row::new("pf_curve")
                .int("particles", n as u64)
                .num("mean_error", m)
                .num("stderr", se)
                .num("time_s", t)
                .num("cpu_s", c),
        );
    }
    rep.paper.push(
        Row::new("chain")
            .int("n_states", 100)
            .num("mean_error", 0.1816)
            .num("time_s", 0.2),
    );
    rep.paper.push(
        Row::new("pf")
            .int("particles", 100)
            .num("mean_error", 0.1849)
            .num("time_s", 0.013),
    );
    rep.paper
        .push(Row::new("ekf").text("mean_error", "diverges (x2)"));
    match reached {
        Some((n, t)) => rep.notes.push(format!(
            "cheapest chain reaching PF-{particles}'s error {pf_ref_err:.4}: {n} states at {t:.4} CPU s/run = {:.2}x PF-{particles}'s {pf_ref_time:.4} CPU s/run",
            t / pf_ref_time
        )),
        None => rep
            .notes
            .push(format!("no chain size in the curve reached PF-{particles}'s error {pf_ref_err:.4}")),
    }
    rep.notes.push(
        "time_s / cpu_s: wall-clock / thread-CPU filter time per run (predict+update+belief over all steps; the compute comparison uses cpu_s); build_s: one-off chain construction".into(),
    );
    Ok(rep)
}
