//! `changepoint-step-cost`: the fast RBPF against the bootstrap PF on μ_t
//! at equal M on the Table 1 model (ρ = 0.001, σ = 1): wall time per step
//! and SSE, on the same sequences. Both filters preallocate and allocate
//! nothing per step (see the `no_alloc` test), so memory is flat in t; the
//! per-step time is constant in t for both. Times are wall times in worker
//! threads on a shared machine: indicative, not a benchmark.

use super::meanshift_common::{rbpf_pass, run_rng, simulate, Pass, FILTER};
use super::par::{default_threads, par_map};
use super::report::{check_runs, mean_se, Params, Report, Row};
use super::report::{N_SEQ, RHO, SIGMA, THREADS};
use crate::error::ChangepointError;
use crate::meanshift::bootstrap::MeanShiftBootstrap;
use crate::meanshift::rbpf::{RbpfConfig, RhoPrior};
use crate::meanshift::MeanShiftModel;
use crate::resample::Scheme;
use beliefbus_core::experiment_params::{keys, p, ParamDoc};
use std::time::Instant;

/// Parameters this experiment accepts.
pub const PARAMS: &[ParamDoc] = &[
    N_SEQ,
    p("particles", "50,500", "particle counts M compared"),
    SIGMA,
    RHO,
    THREADS,
];

fn bootstrap_pass(
    model: MeanShiftModel,
    m: usize,
    y: &[f64],
    mu: &[f64],
    seed: u64,
    i: usize,
) -> Result<Pass, ChangepointError> {
    let mut f = MeanShiftBootstrap::new(model, m, Scheme::Systematic, run_rng(seed, FILTER, i))?;
    let t0 = Instant::now();
    let mut sse = 0.0;
    for (&yt, &mt) in y.iter().zip(mu) {
        let e = f.step(yt)? - mt;
        sse += e * e;
    }
    Ok(Pass {
        sse,
        resamplings: y.len() as u64,
        secs: t0.elapsed().as_secs_f64(),
    })
}

/// Run: `runs` sequences (default 20).
pub fn run(
    runs: Option<usize>,
    seed: u64,
    params: &[(String, String)],
) -> Result<Report, ChangepointError> {
    let p = Params::new(params, &keys(PARAMS))?;
    let runs = check_runs(runs.unwrap_or(20))?;
    let n: usize = p.get("n", 10_000)?;
    let ms: Vec<usize> = p.list("particles", &[50, 500])?;
    let model = MeanShiftModel::new(p.get("sigma", 1.0)?, p.get("rho", 0.001)?)?;
    let threads: usize = p.get("threads", default_threads())?;
    let per_run: Vec<Result<Vec<(Pass, Pass)>, ChangepointError>> = par_map(runs, threads, |i| {
        let (mu, y) = simulate(model, n, seed, i);
        ms.iter()
            .map(|&m| {
                let cfg = RbpfConfig {
                    particles: m,
                    cv2_bound: 1.0,
                    scheme: Scheme::Systematic,
                    rho_prior: RhoPrior::Known,
                    tilt: None,
                    estimate_after_resampling: false,
                };
                Ok((
                    rbpf_pass(model, cfg, &y, &mu, run_rng(seed, FILTER, i))?,
                    bootstrap_pass(model, m, &y, &mu, seed, i)?,
                ))
            })
            .collect()
    });
    let per_run: Vec<Vec<(Pass, Pass)>> = per_run.into_iter().collect::<Result<_, _>>()?;
    let mut rep = Report::new("changepoint-step-cost");
    rep.lead_columns(&["particles", "us_per_step", "sse", "sse_se", "resamplings"]);
    rep.param("runs", runs);
    rep.param("seed", seed);
    rep.param("n", n);
    rep.param("sigma", model.sigma);
    rep.param("rho", model.rho);
    rep.param("threads", threads);
    for (k, &m) in ms.iter().enumerate() {
        for (name, pick) in [
            ("rbpf (cv2 bound 1)", 0usize),
            ("bootstrap (resample every step)", 1),
        ] {
            let get = |r: &Vec<(Pass, Pass)>| if pick == 0 { r[k].0 } else { r[k].1 };
            let sse: Vec<f64> = per_run.iter().map(|r| get(r).sse).collect();
            let secs: f64 = per_run.iter().map(|r| get(r).secs).sum();
            let res: Vec<f64> = per_run.iter().map(|r| get(r).resamplings as f64).collect();
            let (s, se) = mean_se(&sse);
            rep.results.push(
                Row::new(name)
                    .int("particles", m as u64)
                    .num("us_per_step", secs / (runs * n) as f64 * 1e6)
                    .num("sse", s)
                    .num("sse_se", se)
                    .num("resamplings", mean_se(&res).0)
                    .num("time_s", secs),
            );
        }
    }
    rep.notes.push("no paper figure: the chapter reports no timings (A.4 of the notes); memory is flat by construction and checked by the no_alloc test".into());
    Ok(rep)
}
