//! `smoothing` — thesis §3.5.3 (Fig. 3-6): Van der Pol, the chain filter
//! "without heuristics" (uniform chain), the forward–backward smoother on
//! the same chain with 5,000 states, and a bootstrap PF with 1,000
//! particles; average state error over the runs.
//!
//! Thesis: filter 0.051, smoother 0.0164 (5,000 states), PF 0.04233 (1,000
//! particles). Settings otherwise as in `vanderpol` (e₁ = e₂ = 0.1, σ = 0.1
//! every Δ = 0.01 s, prior N((0.5, 0), 0.2² I)), T = 5 s, 20 runs by default
//! (`--runs 100` for the thesis's count). The error is the time average of
//! ‖x_k − x̂_k‖ over the observation times (filtered for filter/PF,
//! smoothed for the smoother).

use anyhow::Result;

use super::chain_util::{draw_from, mean_se, run_filter, simulate, Params};
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::belief::Gaussian;
use crate::chain::{Chain, ChainConfig, NearRule, Sampler};
use crate::filter::chain_filter::prior_weights;
use crate::filter::pf::{Pf, PfConfig};
use crate::filter::smoother::smooth;
use crate::model::vanderpol::{VanDerPol, VanDerPolParams};
use crate::model::SdeModel;
use crate::rng::stream;

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("smoothing");
    let mut p = Params::new(args);
    let runs = args.runs.unwrap_or(20);
    rep.param("runs", runs);
    rep.param("seed", args.seed);
    let t_end = p.f64(&mut rep, "horizon_s", 5.0)?;
    let dt = p.f64(&mut rep, "obs_period_s", 0.01)?;
    let n = p.usize(&mut rep, "states", 5000)?;
    let particles = p.usize(&mut rep, "particles", 1000)?;
    let step = p.f64(&mut rep, "step_s", dt)?;
    let sampling = p.choice(
        &mut rep,
        "sampling",
        "predictive",
        &["predictive", "uniform"],
    )?;
    p.finish()?;
    rep.param("prior", "N((0.5, 0), 0.2^2 I)");
    rep.param("kernel", "moment_matched");
    let model = VanDerPol::new(VanDerPolParams::default()).map_err(anyhow::Error::msg)?;
    let prior = Gaussian::diagonal(&[0.5, 0.0], &[0.2, 0.2]);
    let steps = (t_end / dt).round() as usize;
    let mut cfg = ChainConfig::moment_matched(2);
    cfg.near = NearRule::Knn { c: 1.5 };
    cfg.step = (step > 0.0).then_some(step);
    let mut srng = stream(args.seed, 66);
    let pts = if sampling == "uniform" {
        Sampler::Uniform.sample_many(model.bounds(), n, &mut srng)
    } else {
        crate::chain::placement::predictive_points(&model, &prior, t_end, n, 0.1, dt, &mut srng)?
    };
    let mut chain = Chain::batch(&model, cfg, &pts)?;
    let mut eq = crate::chain::TimeEqualized::new(dt)?;
    eq.fit(chain.holding());
    let mut w0 = vec![0.0; n];
    let mut scratch = vec![0.0; n];
    prior_weights(&chain, &prior, &mut w0, &mut scratch);
    let view = chain.view();
    let (mut ef, mut es, mut ep) = (vec![], vec![], vec![]);
    let (mut tf, mut tp) = (vec![], vec![]);
    let mut bar = Progress::new("smoothing", runs, args.progress);
    for r in 0..runs {
        let mut rng = stream(args.seed, r as u64);
        let x0 = draw_from(&model, &prior, &mut rng);
        let rec = simulate(&model, &x0, dt, steps, 1e-3, &mut rng);
        let t0 = std::time::Instant::now();
        let sm = smooth(
            &model,
            &view,
            eq.delta(),
            &w0,
            0.0,
            &rec.times,
            &rec.ys,
            false,
        )?;
        tf.push(t0.elapsed().as_secs_f64());
        let (mut a, mut b) = (0.0, 0.0);
        for k in 1..=steps {
            let x = &rec.truth[k * 2..k * 2 + 2];
            let (f, s) = (&sm.filtered[k], &sm.smoothed[k]);
            a += ((f.mean[0] - x[0]).powi(2) + (f.mean[1] - x[1]).powi(2)).sqrt();
            b += ((s.mean[0] - x[0]).powi(2) + (s.mean[1] - x[1]).powi(2)).sqrt();
        }
        ef.push(a / steps as f64);
        es.push(b / steps as f64);
        let cfg = PfConfig {
            particles,
            max_dt: dt,
            seed: args.seed.wrapping_mul(1000).wrapping_add(r as u64),
            ..PfConfig::default()
        };
        let mut pf = Pf::new(model.clone(), &cfg, &prior, 0.0)?;
        let res = run_filter(&mut pf, &rec, None);
        ep.push(res.mean_error);
        tp.push(res.time_s);
        bar.tick();
    }
    let row = |name: &str, v: &[f64]| {
        let (m, se) = mean_se(v);
        Row::new(name).num("mean_error", m).num("stderr", se)
    };
    rep.results.push(
        row("chain", &ef)
            .int("n_states", n as u64)
            .num("delta_s", eq.delta())
            .num("out_degree", view.nnz() as f64 / n as f64),
    );
    rep.results.push(
        row("smoother", &es)
            .int("n_states", n as u64)
            .num("time_s", mean_se(&tf).0),
    );
    rep.results.push(
        row("pf", &ep)
            .int("particles", particles as u64)
            .num("time_s", mean_se(&tp).0),
    );
    rep.paper.push(Row::new("chain").num("mean_error", 0.051));
    rep.paper.push(
        Row::new("smoother")
            .num("mean_error", 0.0164)
            .int("n_states", 5000),
    );
    rep.paper.push(
        Row::new("pf")
            .num("mean_error", 0.04233)
            .int("particles", 1000),
    );
    rep.notes
        .push("smoother time_s includes its forward (filter) pass".into());
    Ok(rep)
}
