//! Open-loop record: strong PD forces computed on the true state, recorded
//! once, replayed to the live chain filter, the PF and the raw inversion.

use super::super::chain_util::live_chain_filter;
use super::super::refine_sim::SimRefine;

use crate::filter::pf::Pf;
use crate::filter::BayesFilter;
use crate::model::discrete::{em_integrate, simulate_observation};
use crate::model::{Measurement, SdeModel};
use crate::pipeline::{config, PipelineConfig};
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
    let prior = cfg.prior();
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
    let mut refine = SimRefine::new(&cfg, dt, dims.state, work)?;
    let mut live = live_chain_filter(model.clone(), &cfg, &prior)?;
    live.set_reanchor(cfg.filter.chain.reanchor_ess);
    live.set_moving_frame(cfg.refine.moving_frame);
    let prepare = Duration::from_secs_f64(cfg.filter.chain.prepare_budget_us * 1e-6);
    let (mut pos, mut vel) = (0.0, 0.0);
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        refine.tick(k, &us[k], &mut live)?;
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
