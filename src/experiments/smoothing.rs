//! `smoothing` — thesis §3.5.3 (Fig. 3-6): Van der Pol, the chain filter
//! and the forward–backward smoother on the same 5,000-state chain, against
//! a bootstrap PF with 1,000 particles; average state error over the runs.
//!
//! Thesis: filter 0.051, smoother 0.0164 (5,000 states), PF 0.04233 (1,000
//! particles), 100 runs, a chain "without heuristics". Settings otherwise as
//! in `vanderpol`'s dense setting (e₁ = e₂ = 0.1, σ = 0.1 every Δ = 0.01 s,
//! prior N((0.5, 0), 0.2² I)), T = 5 s, 100 runs by default. Two chains are
//! run on the same records: one on states placed where the prior
//! predictive puts mass (`chain::placement`-style predictive points; rows
//! `chain`, `smoother`) and one uniform on S, the thesis's "without
//! heuristics" (rows `chain_uniform`, `smoother_uniform`); the notes give
//! each smoother's paired difference to the PF with its 95 % interval. The
//! error is the time average of ‖x_k − x̂_k‖ over the observation times
//! (filtered for filter/PF, smoothed for the smoother).

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
    let runs = args.runs.unwrap_or(100);
    rep.param("runs", runs);
    rep.param("seed", args.seed);
    let t_end = p.f64(&mut rep, "horizon_s", 5.0)?;
    let dt = p.f64(&mut rep, "obs_period_s", 0.01)?;
    let n = p.usize(&mut rep, "states", 5000)?;
    let particles = p.usize(&mut rep, "particles", 1000)?;
    let step = p.f64(&mut rep, "step_s", dt)?;
    p.finish()?;
    rep.param("prior", "N((0.5, 0), 0.2^2 I)");
    rep.param("kernel", "moment_matched");
    let model = VanDerPol::new(VanDerPolParams::default()).map_err(anyhow::Error::msg)?;
    let prior = Gaussian::diagonal(&[0.5, 0.0], &[0.2, 0.2]);
    let steps = (t_end / dt).round() as usize;
    let mut cfg = ChainConfig::moment_matched(2);
    cfg.near = NearRule::Knn { c: 1.5 };
    cfg.step = (step > 0.0).then_some(step);
    // The two chains: predictive placement, and uniform on S.
    let mut built = Vec::new();
    for uniform in [false, true] {
        let mut srng = stream(args.seed, 66);
        let pts = if uniform {
            Sampler::Uniform.sample_many(model.bounds(), n, &mut srng)
        } else {
            crate::chain::placement::predictive_points(
                &model, &prior, t_end, n, 0.1, dt, &mut srng,
            )?
        };
        let chain = Chain::batch(&model, cfg.clone(), &pts)?;
        let mut eq = crate::chain::TimeEqualized::new(dt)?;
        eq.fit(chain.holding());
        let mut w0 = vec![0.0; n];
        let mut scratch = vec![0.0; n];
        prior_weights(&chain, &prior, &mut w0, &mut scratch);
        built.push((chain, eq, w0));
    }
    let chains: Vec<_> = built
        .iter_mut()
        .map(|(c, eq, w0)| (c.view(), &*eq, &*w0))
        .collect();
    // Per chain: filter errors, smoother errors, smoother times.
    let mut on: Vec<[Vec<f64>; 3]> = vec![Default::default(), Default::default()];
    let (mut ep, mut tp) = (vec![], vec![]);
    let mut bar = Progress::new("smoothing", runs, args.progress);
    for r in 0..runs {
        let mut rng = stream(args.seed, r as u64);
        let x0 = draw_from(&model, &prior, &mut rng);
        let rec = simulate(&model, &x0, dt, steps, 1e-3, &mut rng);
        for ((view, eq, w0), out) in chains.iter().zip(on.iter_mut()) {
            let t0 = std::time::Instant::now();
            let sm = smooth(
                &model,
                view,
                eq.delta(),
                w0,
                0.0,
                &rec.times,
                &rec.ys,
                false,
            )?;
            out[2].push(t0.elapsed().as_secs_f64());
            let (mut a, mut b) = (0.0, 0.0);
            for k in 1..=steps {
                let x = &rec.truth[k * 2..k * 2 + 2];
                let (f, s) = (&sm.filtered[k], &sm.smoothed[k]);
                a += ((f.mean[0] - x[0]).powi(2) + (f.mean[1] - x[1]).powi(2)).sqrt();
                b += ((s.mean[0] - x[0]).powi(2) + (s.mean[1] - x[1]).powi(2)).sqrt();
            }
            out[0].push(a / steps as f64);
            out[1].push(b / steps as f64);
        }
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
    for ((view, eq, _), (out, suffix)) in chains.iter().zip(on.iter().zip(["", "_uniform"])) {
        rep.results.push(
            row(&format!("chain{suffix}"), &out[0])
                .int("n_states", n as u64)
                .num("delta_s", eq.delta())
                .num("out_degree", view.nnz() as f64 / n as f64),
        );
        rep.results.push(
            row(&format!("smoother{suffix}"), &out[1])
                .int("n_states", n as u64)
                .num("time_s", mean_se(&out[2]).0),
        );
    }
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
    for (out, name) in on.iter().zip(["predictive", "uniform"]) {
        let d: Vec<f64> = out[1].iter().zip(&ep).map(|(s, p)| s - p).collect();
        let (m, se) = mean_se(&d);
        rep.notes.push(format!(
            "smoother on the {name} chain − PF-{particles}: {m:+.4} ± {:.4} (95 %, paired over {} runs){}",
            1.96 * se,
            d.len(),
            if m + 1.96 * se < 0.0 {
                ": the smoother is better"
            } else if m - 1.96 * se > 0.0 {
                ": the PF is better"
            } else {
                ": no significant difference"
            }
        ));
    }
    rep.notes.push(
        "The thesis's order smoother < PF < filter holds only with states placed where the prior predictive puts mass; with the thesis's uniform chain of 5,000 states the smoother loses to the PF here. Our absolute errors are about 3× the thesis's for every method, PF included: the thesis leaves the Van der Pol noise levels and the error's norm unstated, so compare the order and the ratios, not the values."
            .into(),
    );
    Ok(rep)
}
