//! The live chain filter under closed-loop-like control (issue 4): the ship
//! of a pipeline config driven by strong piecewise-constant forces that a
//! PD law on the *true* state computes toward the config's waypoints
//! (u = clamp(k_p(w − p) − k_d v, ±u_max), held for `hold_s`), recorded
//! once so that every filter sees the same controls and measurements. The
//! live chain filter runs on the chain that the pipeline's refine code grows
//! around its belief (simulated time, as in [`super::anytime`]); the
//! bootstrap PF of the config and the raw range/bearing inversion run on the
//! same record. Rows: RMS position / velocity error per filter, re-spreads
//! and versions of the live chain.

use super::chain_util::Params;
use super::{ExperimentArgs, ExperimentReport, Row};
use crate::chain::snapshot::words_needed;
use crate::filter::live_chain::LiveChainFilter;
use crate::filter::pf::Pf;
use crate::filter::BayesFilter;
use crate::model::discrete::{em_integrate, simulate_observation};
use crate::model::{Measurement, SdeModel};
use crate::pipeline::{config, PipelineConfig};
use crate::stage::filter::{make_filter, prior};
use crate::stage::refine::Refiner;
use anyhow::Result;
use std::time::Duration;

/// The outcome of one closed-loop-like run.
#[derive(Clone, Debug, Default)]
pub struct ClosedLoopRun {
    pub rmse_position_chain: f64,
    pub rmse_position_pf: f64,
    pub rmse_position_raw: f64,
    pub rmse_velocity_chain: f64,
    pub rmse_velocity_pf: f64,
    /// RMS position error of the chain filter per second.
    pub per_second_chain: Vec<f64>,
    pub per_second_pf: Vec<f64>,
    pub respreads: u64,
    pub refused: u64,
    pub versions: u64,
    pub states: usize,
    pub delta: f64,
    /// Largest |u| component of the record.
    pub u_abs_max: f64,
}

/// Run the ship of `cfg` for `seconds` under the recorded PD forces;
/// refine works `work` of wall-clock time per `refine.period_ms` of
/// simulated time (`None`: `refine.work_ms`).
pub fn closed_loop(
    cfg: &PipelineConfig,
    seconds: usize,
    seed: u64,
    hold_s: f64,
    work: Option<Duration>,
) -> Result<ClosedLoopRun> {
    let mut cfg = cfg.clone();
    cfg.filter.backend = config::FilterBackend::Chain;
    let model = cfg.model()?;
    let dims = model.dims();
    anyhow::ensure!(dims.control >= 2 && dims.state >= 4, "needs the ship");
    let dt = cfg.sample_dt();
    let steps_per_s = (1.0 / dt).round() as usize;
    let steps = seconds * steps_per_s;
    let hold = ((hold_s / dt).round() as usize).max(1);
    let prior = prior(&cfg);
    let route = cfg
        .control
        .route
        .clone()
        .ok_or_else(|| anyhow::anyhow!("control.route is required"))?;
    let (wps, reach) = (route.waypoints, route.reach_radius);
    let u_max = cfg.control.implicit.u_max;

    // The record: truth, measurements and the PD forces on the truth.
    let mut rng = crate::rng::stream(seed, 0xc10);
    let mut x = cfg.plant.initial_state.clone();
    let (mut truth, mut ys, mut us) = (vec![], vec![], vec![]);
    let mut y = vec![0.0; dims.obs];
    let mut u = vec![0.0; dims.control];
    let mut w = 0usize;
    let mut u_abs_max: f64 = 0.0;
    for k in 0..steps {
        if k % hold == 0 {
            let p = &wps[w % wps.len()];
            if ((x[0] - p[0]).powi(2) + (x[1] - p[1]).powi(2)).sqrt() < reach {
                w += 1;
            }
            let p = &wps[w % wps.len()];
            for i in 0..2 {
                u[i] = (2.0 * (p[i] - x[i]) - 2.0 * x[2 + i]).clamp(-u_max, u_max);
                u_abs_max = u_abs_max.max(u[i].abs());
            }
        }
        em_integrate(&model, &mut x, &u, dt, cfg.plant.integration_dt, &mut rng);
        model.bounds().project(&mut x);
        simulate_observation(&model, &x, &mut rng, &mut y);
        truth.push(x.clone());
        ys.push(y.clone());
        us.push(u.clone());
    }

    let mut out = ClosedLoopRun {
        u_abs_max,
        per_second_chain: vec![0.0; seconds],
        per_second_pf: vec![0.0; seconds],
        ..Default::default()
    };
    let se = |g: &crate::belief::Gaussian, x: &[f64], o: usize| {
        (g.mean[o] - x[o]).powi(2) + (g.mean[o + 1] - x[o + 1]).powi(2)
    };

    // Live chain: refine and filter interleaved in simulated time.
    let mut refiner = Refiner::new(&cfg, 1)?;
    let mut live: LiveChainFilter<_, Vec<u64>> = LiveChainFilter::new(
        model.clone(),
        make_filter(&cfg, 0.0)?,
        cfg.refine.max_states,
        &prior,
        0.0,
    );
    let period = (cfg.refine.period_ms * 1e-3 / dt).round().max(1.0) as usize;
    let publish = (cfg.refine.publish_period_ms * 1e-3 / dt).round().max(1.0) as usize;
    let work = work.unwrap_or(Duration::from_secs_f64(cfg.refine.work_ms * 1e-3));
    let prepare = Duration::from_secs_f64(cfg.filter.chain.prepare_budget_us * 1e-6);
    let (mut pos, mut vel) = (0.0, 0.0);
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        if k % period == 0 {
            refiner.set_belief_at(&live.belief(), k as f64 * dt);
            let fresh = refiner.is_empty();
            refiner.work(work)?;
            if fresh || k % publish == 0 {
                let mut buf =
                    vec![0u64; refiner.snapshot_words().max(words_needed(dims.state, 0, 0))];
                refiner.write_snapshot(&mut buf, 0)?;
                live.offer(buf)?;
            }
        }
        live.predict(t, &us[k])?;
        if live.update(&Measurement::full(&ys[k])).is_err() {
            out.refused += 1;
        }
        live.advance(prepare)?;
        let g = live.belief();
        let e = se(&g, &truth[k], 0);
        pos += e;
        vel += se(&g, &truth[k], 2);
        out.per_second_chain[k / steps_per_s] += e;
    }
    out.rmse_position_chain = (pos / steps as f64).sqrt();
    out.rmse_velocity_chain = (vel / steps as f64).sqrt();
    out.respreads = live.respreads();
    out.versions = live.versions();
    if let Some((_, n, d)) = live.active_info() {
        out.states = n;
        out.delta = d;
    }

    // PF and raw inversion on the same record.
    let mut pf_cfg = cfg.filter.pf.clone();
    pf_cfg.seed = seed;
    let mut pf = Pf::new(model.clone(), &pf_cfg, &prior, 0.0)?;
    let (mut pos, mut vel, mut raw) = (0.0, 0.0, 0.0);
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        pf.predict(t, &us[k])?;
        let _ = pf.update(&Measurement::full(&ys[k]));
        let g = pf.belief();
        let e = se(&g, &truth[k], 0);
        pos += e;
        vel += se(&g, &truth[k], 2);
        out.per_second_pf[k / steps_per_s] += e;
        let (r, b) = (ys[k][0], ys[k][1]);
        raw += (r * b.cos() - truth[k][0]).powi(2) + (r * b.sin() - truth[k][1]).powi(2);
    }
    out.rmse_position_pf = (pos / steps as f64).sqrt();
    out.rmse_velocity_pf = (vel / steps as f64).sqrt();
    out.rmse_position_raw = (raw / steps as f64).sqrt();
    for v in out
        .per_second_chain
        .iter_mut()
        .chain(out.per_second_pf.iter_mut())
    {
        *v = (*v / steps_per_s as f64).sqrt();
    }
    Ok(out)
}

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("chain-closed-loop");
    let mut p = Params::new(args);
    let seconds = p.usize(&mut rep, "seconds", 20)?;
    let hold = p.f64(&mut rep, "hold_s", 0.1)?;
    let runs = args.runs.unwrap_or(2);
    p.finish()?;
    let cfg = config::load(std::path::Path::new("configs/default.toml"), &[])?;
    rep.param("seed", args.seed);
    rep.param("runs", runs as u64);
    for r in 0..runs {
        let s = args.seed + r as u64;
        let o = closed_loop(&cfg, seconds, s, hold, None)?;
        rep.results.push(
            Row::new("run")
                .int("seed", s)
                .num("rmse_position_chain", o.rmse_position_chain)
                .num("rmse_position_pf", o.rmse_position_pf)
                .num("rmse_position_raw", o.rmse_position_raw)
                .num("rmse_velocity_chain", o.rmse_velocity_chain)
                .num("rmse_velocity_pf", o.rmse_velocity_pf)
                .int("respreads", o.respreads)
                .int("refused", o.refused)
                .int("versions", o.versions)
                .int("states", o.states as u64)
                .num("delta_s", o.delta)
                .num("u_abs_max", o.u_abs_max),
        );
        for (s2, (c, f)) in o.per_second_chain.iter().zip(&o.per_second_pf).enumerate() {
            rep.results.push(
                Row::new("per_second")
                    .int("run", r as u64)
                    .int("second", s2 as u64 + 1)
                    .num("chain", *c)
                    .num("pf", *f),
            );
        }
    }
    Ok(rep)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ship under strong recorded PD forces (|u| reaches u_max = 3):
    /// the live chain filter on the chain refine grows around it stays
    /// within a bound of the bootstrap PF on the same record and well below
    /// the raw range/bearing inversion, and keeps versions coming.
    #[test]
    fn under_strong_recorded_forces_the_live_chain_stays_near_the_pf() {
        let cfg = config::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/default.toml"),
            &[],
        )
        .unwrap();
        let o = closed_loop(&cfg, 12, 5, 0.1, None).unwrap();
        eprintln!("{o:?}");
        assert!(
            o.u_abs_max > 2.9,
            "the forces must be strong: {}",
            o.u_abs_max
        );
        assert!(o.versions > 10, "{o:?}");
        assert!(
            o.rmse_position_chain < 0.5 * o.rmse_position_raw,
            "chain {} vs raw {}",
            o.rmse_position_chain,
            o.rmse_position_raw
        );
        assert!(
            // Measured 0.49–0.60 vs the PF's 0.41 (refine's work is
            // wall-clock time, so the chain's size varies with the load).
            o.rmse_position_chain < 2.0 * o.rmse_position_pf,
            "chain {} vs PF {}",
            o.rmse_position_chain,
            o.rmse_position_pf
        );
    }
}
