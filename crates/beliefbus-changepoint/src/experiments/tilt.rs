//! `changepoint-tilt`: Table 2 of Chen, Lai & Wu — the tilted proposal
//! ρ̃ = r·ρ with the importance correction (12), cv² bound 1, on the same
//! sequences as Table 1. Besides each SSE we give its paired difference to
//! ρ̃ = ρ on the same data and filter random numbers, whose s.e. is the one
//! that decides "lower than ρ̃ = ρ".

use super::meanshift_common::{rbpf_pass, run_rng, simulate, Pass, FILTER, TABLE2};
use super::par::{default_threads, par_map};
use super::report::{check_runs, mean_se, Params, Report, Row};
use super::report::{BOUND, N_SEQ, PARTICLES, RHO, SIGMA, THREADS};
use crate::error::ChangepointError;
use crate::meanshift::rbpf::{RbpfConfig, RhoPrior};
use crate::meanshift::MeanShiftModel;
use crate::resample::Scheme;
use beliefbus_core::experiment_params::{keys, p, ParamDoc};

/// Parameters this experiment accepts.
pub const PARAMS: &[ParamDoc] = &[
    N_SEQ,
    PARTICLES,
    SIGMA,
    RHO,
    BOUND,
    p(
        "ratios",
        "= Table 2 ratios r",
        "tilt ratios r of the proposal rho~ = r*rho (must include 1)",
    ),
    p(
        "scheme",
        "systematic",
        "resampling scheme: multinomial, residual or systematic",
    ),
    THREADS,
];

/// Run the experiment: `runs` sequences (default 100) from `seed`.
pub fn run(
    runs: Option<usize>,
    seed: u64,
    params: &[(String, String)],
) -> Result<Report, ChangepointError> {
    let p = Params::new(params, &keys(PARAMS))?;
    let runs = check_runs(runs.unwrap_or(100))?;
    let n: usize = p.get("n", 10_000)?;
    let m: usize = p.get("particles", 50)?;
    let model = MeanShiftModel::new(p.get("sigma", 1.0)?, p.get("rho", 0.001)?)?;
    let bound: f64 = p.get("bound", 1.0)?;
    let default_ratios: Vec<f64> = TABLE2.iter().map(|r| r.0).collect();
    let ratios: Vec<f64> = p.list("ratios", &default_ratios)?;
    let scheme: Scheme = p.get("scheme", Scheme::Systematic)?;
    let threads: usize = p.get("threads", default_threads())?;
    if !ratios.contains(&1.0) {
        return Err(ChangepointError::Param {
            key: "ratios".into(),
            msg: "must contain 1 (the untilted reference)".into(),
        });
    }

    let started = std::time::Instant::now();
    let per_run: Vec<Result<Vec<Pass>, ChangepointError>> = par_map(runs, threads, |i| {
        let (mu, y) = simulate(model, n, seed, i);
        ratios
            .iter()
            .map(|&r| {
                let cfg = RbpfConfig {
                    particles: m,
                    cv2_bound: bound,
                    scheme,
                    rho_prior: RhoPrior::Known,
                    tilt: if r == 1.0 { None } else { Some(r * model.rho) },
                    estimate_after_resampling: false,
                };
                rbpf_pass(model, cfg, &y, &mu, run_rng(seed, FILTER, i))
            })
            .collect()
    });
    let per_run: Vec<Vec<Pass>> = per_run.into_iter().collect::<Result<_, _>>()?;
    let base = ratios.iter().position(|&r| r == 1.0).unwrap_or(0);

    let mut rep = Report::new("changepoint-tilt");
    rep.lead_columns(&[
        "tilt_ratio",
        "sse",
        "sse_paper",
        "sse_se",
        "sse_se_paper",
        "sse_minus_untilted",
        "sse_minus_untilted_se",
        "resamplings",
    ]);
    rep.param("runs", runs);
    rep.param("seed", seed);
    rep.param("n", n);
    rep.param("particles", m);
    rep.param("sigma", model.sigma);
    rep.param("rho", model.rho);
    rep.param("cv2_bound", bound);
    rep.param("scheme", scheme.name());
    rep.param("threads", threads);
    for (k, &r) in ratios.iter().enumerate() {
        let sse: Vec<f64> = per_run.iter().map(|x| x[k].sse).collect();
        let diff: Vec<f64> = per_run.iter().map(|x| x[k].sse - x[base].sse).collect();
        let res: Vec<f64> = per_run.iter().map(|x| x[k].resamplings as f64).collect();
        let secs: f64 = per_run.iter().map(|x| x[k].secs).sum();
        let (s, se) = mean_se(&sse);
        let (d, dse) = mean_se(&diff);
        let mut row = Row::new(&format!("rbpf-{}", scheme.name()))
            .num("tilt_ratio", r)
            .num("sse", s)
            .num("sse_se", se);
        if let Some(t) = TABLE2.iter().find(|t| t.0 == r) {
            row = row.num("sse_paper", t.1).num("sse_se_paper", t.2);
        }
        rep.results.push(
            row.num("sse_minus_untilted", d)
                .num("sse_minus_untilted_se", dse)
                .num("resamplings", mean_se(&res).0)
                .num("time_s", secs)
                .num("us_per_step", secs / (runs * n) as f64 * 1e6),
        );
    }
    for t in TABLE2 {
        rep.paper.push(
            Row::new("paper-table2")
                .num("tilt_ratio", t.0)
                .num("sse", t.1)
                .num("sse_se", t.2),
        );
    }
    rep.notes.push(format!(
        "tilt_ratio = rho~/rho; all ratios see the same sequences and filter random numbers; time_s summed over runs in {threads} worker thread(s) on a shared, loaded machine; total {:.1} s",
        started.elapsed().as_secs_f64()
    ));
    Ok(rep)
}
