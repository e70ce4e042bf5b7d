//! Anytime evidence: the ship scenario of a pipeline config
//! (`configs/default.toml` unless `config=FILE`), uncontrolled (the paper's
//! drifting ship), filtered by the pipeline's chain backend on a chain that
//! the pipeline's refine code grows while the filter runs — and, on the same
//! record, the library's offline chain filter on a batch chain of the live
//! chain's final size (predictive points from the prior, as in the `ship`
//! experiment) and the bootstrap PF of the config. Rows: estimation error
//! (RMS position error) per second of run time, with the live chain's size
//! and version at the end of that second.
//!
//! The stages are driven in one thread, in simulated time: every
//! `refine.period_ms` of simulated time, refine works `refine.work_ms` of
//! wall-clock time ([`Refiner::work`]); every `refine.publish_period_ms` it
//! writes a snapshot, which the filter prepares after its updates within
//! `filter.chain.prepare_budget_us` ([`crate::filter::live_chain::LiveChainFilter::advance`]) and swaps
//! in — the same code as the `refine` and `filter` stage loops, without
//! shared memory, so that the error per second does not depend on how the
//! machine schedules the processes. (Deviation from the issue's "through the
//! stage loops": the multi-process run is `beliefbus run`; this experiment
//! isolates the anytime behaviour.)

use super::chain_util::{live_chain_filter, split_config_param, Params};
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::belief::Gaussian;
use crate::chain::placement::predictive_points;
use crate::chain::snapshot::words_needed;
use crate::chain::Chain;
use crate::filter::chain_filter::ChainFilter;
use crate::filter::pf::Pf;
use crate::filter::BayesFilter;
use crate::model::discrete::{em_integrate, simulate_observation};
use crate::model::{Measurement, SdeModel};
use crate::pipeline::config;
use crate::stage::refine::Refiner;
use crate::stage::snapshots::chain_config;
use anyhow::Result;
use std::time::Duration;

/// Squared position error of `g` against `x` (first two components).
fn se_pos(g: &Gaussian, x: &[f64]) -> f64 {
    (g.mean[0] - x[0]).powi(2) + (g.mean[1] - x[1]).powi(2)
}

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("anytime");
    let (cfg, path, rest) = split_config_param(args)?;
    let mut p = Params::new(&rest);
    let seconds = p.usize(&mut rep, "seconds", 20)?;
    // Known control force (all filters are given it): amplitude a of
    // u(t) = a (cos 0.7t, sin 0.5t); 0 = the drifting ship.
    let amp = p.f64(&mut rep, "control_amplitude", 0.0)?;
    p.finish()?;
    let mut cfg = cfg;
    cfg.filter.backend = config::FilterBackend::Chain;
    rep.param("config", path.as_str());
    rep.param("seed", args.seed);
    rep.param("max_states", cfg.refine.max_states as u64);
    rep.param(
        "work_ms_per_period_ms",
        format!("{}/{}", cfg.refine.work_ms, cfg.refine.period_ms),
    );
    rep.param(
        "control",
        "u(t) = a (cos 0.7t, sin 0.5t), known to every filter",
    );
    let model = cfg.model()?;
    let dims = model.dims();
    let dt = cfg.sample_dt();
    let steps_per_s = (1.0 / dt).round() as usize;
    let steps = seconds * steps_per_s;
    let prior = cfg.prior();
    let ctl = |t: f64| -> Vec<f64> {
        let mut u = vec![0.0; dims.control];
        if dims.control >= 2 {
            u[0] = amp * (0.7 * t).cos();
            u[1] = amp * (0.5 * t).sin();
        }
        u
    };

    // The record: truth and measurements.
    let mut rng = crate::rng::stream(args.seed, 0xa11);
    let mut x = cfg.plant.initial_state.clone();
    let mut truth = Vec::with_capacity(steps);
    let mut ys = Vec::with_capacity(steps);
    let mut y = vec![0.0; dims.obs];
    for k in 0..steps {
        let u = ctl(k as f64 * dt);
        em_integrate(&model, &mut x, &u, dt, cfg.plant.integration_dt, &mut rng);
        model.bounds().project(&mut x);
        simulate_observation(&model, &x, &mut rng, &mut y);
        truth.push(x.clone());
        ys.push(y.clone());
    }

    // Live: refine and filter interleaved in simulated time.
    let mut refiner = Refiner::new(&cfg, 1)?;
    let mut live = live_chain_filter(model.clone(), &cfg, &prior)?;
    let period = (cfg.refine.period_ms * 1e-3 / dt).round().max(1.0) as usize;
    let publish = (cfg.refine.publish_period_ms * 1e-3 / dt).round().max(1.0) as usize;
    let work = Duration::from_secs_f64(cfg.refine.work_ms * 1e-3);
    let prepare = Duration::from_secs_f64(cfg.filter.chain.prepare_budget_us * 1e-6);
    let mut live_se = vec![0.0; seconds];
    let mut live_n = vec![(0usize, 0u64); seconds];
    let mut swaps = Vec::new();
    let mut refused = 0u64;
    // One unit per simulated second, live and offline.
    let mut bar = Progress::new("anytime", 2 * seconds, args.progress);
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        if k % period == 0 {
            refiner.set_belief(&live.belief());
            let fresh = refiner.is_empty();
            refiner.work(work)?;
            // As the filter stage: a version being prepared is finished first.
            if (fresh || k % publish == 0) && !live.has_pending() {
                let mut buf =
                    vec![0u64; refiner.snapshot_words().max(words_needed(dims.state, 0, 0))];
                refiner.write_snapshot(&mut buf, 0)?;
                live.offer(buf)?;
            }
        }
        live.predict(t, &ctl(k as f64 * dt))?;
        if live.update(&Measurement::full(&ys[k])).is_err() {
            refused += 1;
        }
        if let Some(s) = live.advance(prepare)? {
            swaps.push(s);
        }
        live_se[k / steps_per_s] += se_pos(&live.belief(), &truth[k]);
        if let Some((v, n, _)) = live.active_info() {
            live_n[k / steps_per_s] = (n, v);
        }
        if (k + 1) % steps_per_s == 0 {
            bar.tick();
        }
    }
    let final_n = refiner.len().max(100);

    // Offline chain filter of the same size, and the PF.
    let pts = predictive_points(
        &model,
        &prior,
        seconds as f64,
        final_n,
        cfg.refine.uniform_fraction,
        dt,
        &mut crate::rng::stream(args.seed, 0xc4a1),
    )?;
    let chain = Chain::batch(&model, chain_config(&cfg, dims.state), &pts)?;
    let mut off = ChainFilter::new(model.clone(), chain, dt)?;
    off.reset(0.0, &prior);
    let mut pf_cfg = cfg.filter.pf.clone();
    pf_cfg.seed = args.seed;
    let mut pf = Pf::new(model.clone(), &pf_cfg, &prior, 0.0)?;
    let mut se = [vec![0.0; seconds], vec![0.0; seconds]];
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        for (i, f) in [&mut off as &mut dyn BayesFilter, &mut pf]
            .into_iter()
            .enumerate()
        {
            f.predict(t, &ctl(k as f64 * dt))?;
            let _ = f.update(&Measurement::full(&ys[k]));
            se[i][k / steps_per_s] += se_pos(&f.belief(), &truth[k]);
        }
        if (k + 1) % steps_per_s == 0 {
            bar.tick();
        }
    }
    let rms = |v: f64| (v / steps_per_s as f64).sqrt();
    for s in 0..seconds {
        rep.results.push(
            Row::new("chain")
                .int("second", s as u64 + 1)
                .num("rmse_position", rms(live_se[s]))
                .int("n_states", live_n[s].0 as u64)
                .int("version", live_n[s].1),
        );
    }
    for s in 0..seconds {
        rep.results.push(
            Row::new("chain_offline")
                .int("second", s as u64 + 1)
                .num("rmse_position", rms(se[0][s]))
                .int("n_states", final_n as u64),
        );
    }
    for s in 0..seconds {
        rep.results.push(
            Row::new("pf")
                .int("second", s as u64 + 1)
                .num("rmse_position", rms(se[1][s]))
                .int("particles", cfg.filter.pf.particles as u64),
        );
    }
    let mut sw: Vec<u64> = swaps.iter().map(|s| s.swap_ns).collect();
    sw.sort_unstable();
    let q = |v: &[u64], f: f64| {
        v.get(((v.len() as f64 - 1.0) * f).round() as usize)
            .map_or(0.0, |x| *x as f64 / 1e3)
    };
    rep.notes.push(format!(
        "live chain: {} versions installed, δ {:.2e} s, swap p50 {:.1} µs p99 {:.1} µs, mass lost in a remap ≤ {:.3}, {} updates refused (belief re-spread), {} states retired",
        swaps.len(),
        refiner.delta(),
        q(&sw, 0.5),
        q(&sw, 0.99),
        swaps.iter().map(|s| s.mass_lost).fold(0.0, f64::max),
        refused,
        refiner.retired,
    ));
    Ok(rep)
}
