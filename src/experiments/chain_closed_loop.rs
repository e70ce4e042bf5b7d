//! The live chain filter under closed-loop-like control: the ship
//! of a pipeline config driven by strong piecewise-constant forces that a
//! PD law on the *true* state computes toward the config's waypoints
//! (u = clamp(k_p(w − p) − k_d v, ±u_max), held for `hold_s`), recorded
//! once so that every filter sees the same controls and measurements. The
//! live chain filter runs on the chain that the pipeline's refine code grows
//! around its belief (simulated time, as in [`super::anytime`]); the
//! bootstrap PF of the config and the raw range/bearing inversion run on the
//! same record. Rows: RMS position / velocity error per filter, re-spreads
//! and versions of the live chain.

use super::chain_util::{live_chain_filter, split_config_param, Params};
use super::refine_sim::SimRefine;
use super::{ExperimentArgs, ExperimentReport, Row};
use crate::belief::Gaussian;
use crate::control::waypoints::WaypointTracker;
use crate::control::Controller;
use crate::filter::chain_filter::ChainFilter;
use crate::filter::pf::Pf;
use crate::filter::BayesFilter;
use crate::model::discrete::{em_integrate, simulate_observation};
use crate::model::{Measurement, SdeModel};
use crate::pipeline::{config, PipelineConfig};
use crate::stage::snapshots::chain_config;
use crate::MAX_STATE;
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

/// The outcome of a run in which the configured controller closes the loop
/// on each filter's own belief (as the pipeline does), with diagnostics that
/// separate the chain filter's error sources.
#[derive(Clone, Debug, Default)]
pub struct ControllerRun {
    /// The chain filter's own closed loop.
    pub rmse_position_chain: f64,
    pub rmse_velocity_chain: f64,
    /// The PF's own closed loop (same plant noise stream).
    pub rmse_position_pf: f64,
    pub rmse_velocity_pf: f64,
    /// The raw range/bearing inversion on the chain loop's record.
    pub rmse_position_raw: f64,
    /// The PF on the chain loop's record (same observations and controls):
    /// the estimation error on that trajectory without the chain.
    pub rmse_position_pf_on_chain_trace: f64,
    pub rmse_velocity_pf_on_chain_trace: f64,
    /// The library's offline chain filter on the chain loop's record, on a
    /// uniform batch chain of the live chain's final size.
    pub rmse_position_offline_chain: f64,
    /// Controller errors on chain beliefs (and on PF beliefs).
    pub control_errors_chain: u64,
    pub control_errors_pf: u64,
    /// Chain beliefs with a non-finite or non-positive-definite covariance.
    pub bad_beliefs: u64,
    /// Mean number of chain states within Mahalanobis distance 1 and 2 of
    /// the belief mean (under the belief's covariance).
    pub states_within_1sd: f64,
    pub states_within_2sd: f64,
    /// Mean squared Mahalanobis distance of the truth under the chain belief
    /// (4 for a consistent 4-d Gaussian belief), and under the PF's on the
    /// same record.
    pub nees_chain: f64,
    pub nees_pf_on_chain_trace: f64,
    /// Fraction of steps with a true speed component beyond ship.v_max, in
    /// the chain's loop and in the PF's, and the largest |speed component|.
    pub frac_speed_outside: f64,
    pub frac_speed_outside_pf: f64,
    pub speed_max_chain: f64,
    pub speed_max_pf: f64,
    /// The live chain filter (with refine) on the PF loop's record: the
    /// chain's estimation error without its own feedback.
    pub rmse_position_chain_on_pf_trace: f64,
    pub rmse_velocity_chain_on_pf_trace: f64,
    /// NEES of the live chain on the PF loop's record.
    pub nees_chain_on_pf_trace: f64,
    /// Re-anchorings of the live chain's belief (support collapsed), in
    /// its own loop and on the PF loop's record.
    pub reanchors: u64,
    pub reanchors_on_pf_trace: u64,
    /// States refine added in the chain's own loop.
    pub refine_added: u64,
    /// First time (s) the chain loop's position error exceeds 1, and then:
    /// |true velocity|, |believed velocity|, the belief's largest velocity
    /// std, the true speed's largest component.
    pub diverge_s: f64,
    pub diverge_true_v: f64,
    pub diverge_chain_v: f64,
    pub diverge_chain_vel_sd: f64,
    /// Transport rate sets missing ±e_i by > 5 %.
    pub transport_off: u64,
    /// Largest belief mass lost in a remap, swaps that restarted from the
    /// Gaussian, re-spreads after degenerate updates.
    pub mass_lost_max: f64,
    pub from_gaussian_swaps: u64,
    pub respreads: u64,
    pub versions: u64,
    pub states: usize,
    pub delta: f64,
    /// Transport rate sets solved (and not exact at the chain's border).
    pub transport_built: u64,
    pub transport_partial: u64,
    /// Wall time of predict + update per observation, p50 / p99 / max (µs).
    pub step_us: [f64; 3],
    /// Preparation time per installed version, p50 / max (µs).
    pub prepare_us: [f64; 2],
    /// Swap time, p50 / max (µs).
    pub swap_us: [f64; 2],
    pub per_second_chain: Vec<f64>,
    pub per_second_pf: Vec<f64>,
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// The configured controller (implicit or MPPI) of `cfg`, seeded as the
/// control stage seeds it.
fn controller(cfg: &PipelineConfig) -> Result<Box<dyn Controller>> {
    crate::stage::control::make_backend(cfg)?
        .map(|b| b.into_controller())
        .ok_or_else(|| anyhow::anyhow!("control.backend = none"))
}

/// One closed loop: the plant (not projected into the chain's bounds, as in
/// the pipeline) driven by the configured controller on `filter`'s belief;
/// `on_step` sees (step, belief, truth) after each update. Returns the
/// record (truth, observations, controls) and the controller's errors.
#[allow(clippy::type_complexity)]
fn drive(
    cfg: &PipelineConfig,
    steps: usize,
    seed: u64,
    filter: &mut dyn FnMut(usize, f64, &[f64], &[f64]) -> Result<Gaussian>,
    on_step: &mut dyn FnMut(usize, &Gaussian, &[f64]),
) -> Result<(Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<Vec<f64>>, u64)> {
    let model = cfg.model()?;
    let dims = model.dims();
    let dt = cfg.sample_dt();
    let mut ctl = controller(cfg)?;
    let mut route = WaypointTracker::new(
        cfg.control
            .route
            .clone()
            .ok_or_else(|| anyhow::anyhow!("control.route is required"))?,
    );
    let mut goal_set = false;
    let mut rng = crate::rng::stream(seed, 0xc10);
    let mut x = cfg.plant.initial_state.clone();
    let (mut truth, mut ys, mut us) = (vec![], vec![], vec![]);
    let mut y = vec![0.0; dims.obs];
    let mut u = vec![0.0; dims.control];
    let mut errors = 0;
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        em_integrate(&model, &mut x, &u, dt, cfg.plant.integration_dt, &mut rng);
        simulate_observation(&model, &x, &mut rng, &mut y);
        truth.push(x.clone());
        ys.push(y.clone());
        us.push(u.clone());
        let g = filter(k, t, &u, &y)?;
        on_step(k, &g, &x);
        if route.update(&g.mean[..2]) || !goal_set {
            let mut goal = [0.0; MAX_STATE];
            let wp = route.goal();
            goal[0] = wp[0];
            goal[1] = wp[1];
            ctl.set_goal(&goal[..dims.state]);
            goal_set = true;
        }
        // On an error the control stage keeps the last good control.
        let mut un = u.clone();
        match ctl.compute(t, &g, &mut un) {
            Ok(_) => u = un,
            Err(_) => errors += 1,
        }
    }
    Ok((truth, ys, us, errors))
}

/// Squared Mahalanobis distance of `x` under `g` (None if P is not PD).
fn mahalanobis2(g: &Gaussian, x: &[f64]) -> Option<f64> {
    let d = g.dim;
    let mut l = [0.0; MAX_STATE * MAX_STATE];
    l[..d * d].copy_from_slice(g.cov());
    if !crate::chain::linalg::cholesky(&mut l[..d * d], d) {
        return None;
    }
    let mut y = [0.0; MAX_STATE];
    for a in 0..d {
        y[a] = x[a] - g.mean[a];
    }
    crate::chain::linalg::forward_sub(&l[..d * d], d, &mut y[..d]);
    Some(y[..d].iter().map(|v| v * v).sum())
}

/// The ship of `cfg` for `seconds`, the loop closed by the configured
/// controller on each filter's own belief (see [`ControllerRun`]).
pub fn closed_loop_controller(
    cfg: &PipelineConfig,
    seconds: usize,
    seed: u64,
    work: Option<Duration>,
    tuning: (f64, bool),
) -> Result<ControllerRun> {
    let mut cfg = cfg.clone();
    cfg.filter.backend = config::FilterBackend::Chain;
    let model = cfg.model()?;
    let dims = model.dims();
    anyhow::ensure!(dims.control >= 2 && dims.state >= 4, "needs the ship");
    let dt = cfg.sample_dt();
    let steps_per_s = (1.0 / dt).round() as usize;
    let steps = seconds * steps_per_s;
    let prior = cfg.prior();
    let mut out = ControllerRun {
        per_second_chain: vec![0.0; seconds],
        per_second_pf: vec![0.0; seconds],
        ..Default::default()
    };
    let se = |g: &Gaussian, x: &[f64], o: usize| {
        (g.mean[o] - x[o]).powi(2) + (g.mean[o + 1] - x[o + 1]).powi(2)
    };
    let v_max = cfg
        .scenario_params::<crate::model::ship::ShipParams>()?
        .unwrap_or_else(|| crate::model::ship::ShipParams::paper(dt))
        .v_max;

    // The chain filter's loop: refine and filter interleaved in simulated
    // time, as in `closed_loop`.
    let mut refine = SimRefine::new(&cfg, dt, dims.state, work)?;
    let mut live = live_chain_filter(model.clone(), &cfg, &prior)?;
    let prepare = Duration::from_secs_f64(cfg.filter.chain.prepare_budget_us * 1e-6);
    live.set_tuning(tuning.0, tuning.1);
    live.set_reanchor(cfg.filter.chain.reanchor_ess);
    live.set_moving_frame(cfg.refine.moving_frame);
    let mut step_us = Vec::with_capacity(steps);
    let (mut in1, mut in2, mut n_in) = (0.0, 0.0, 0usize);
    let (mut mass_lost_max, mut from_gaussian_swaps) = (0.0f64, 0u64);
    let (mut prep_us, mut swap_us) = (vec![], vec![]);
    let mut filter_chain = |k: usize, t: f64, u: &[f64], y: &[f64]| -> Result<Gaussian> {
        refine.tick(k, u, &mut live)?;
        let t0 = crate::rt::clock::thread_cpu_ns();
        live.predict(t, u)?;
        let _ = live.update(&Measurement::full(y));
        let g = live.belief();
        step_us.push((crate::rt::clock::thread_cpu_ns() - t0) as f64 * 1e-3);
        if k.is_multiple_of(10) {
            if let Some(view) = live.active_view() {
                let (mut a, mut b) = (0usize, 0usize);
                for i in 0..view.len() {
                    if let Some(m) = mahalanobis2(&g, view.state(i)) {
                        a += usize::from(m <= 1.0);
                        b += usize::from(m <= 4.0);
                    }
                }
                in1 += a as f64;
                in2 += b as f64;
                n_in += 1;
            }
        }
        if let Some(s) = live.advance(prepare)? {
            prep_us.push(s.prepare_ns as f64 * 1e-3);
            swap_us.push(s.swap_ns as f64 * 1e-3);
            mass_lost_max = mass_lost_max.max(s.mass_lost);
            from_gaussian_swaps += u64::from(s.from_gaussian);
        }
        Ok(g)
    };
    let (mut pos, mut vel, mut nees, mut n_nees) = (0.0, 0.0, 0.0, 0usize);
    let mut outside = 0usize;
    let mut bad = 0u64;
    let mut speed_max: f64 = 0.0;
    let mut diverge: Option<(f64, f64, f64, f64)> = None;
    let mut per_second_chain = vec![0.0; seconds];
    let (truth, ys, us, errs) = {
        let mut on_step = |k: usize, g: &Gaussian, x: &[f64]| {
            let e = se(g, x, 0);
            pos += e;
            vel += se(g, x, 2);
            per_second_chain[k / steps_per_s] += e;
            if x[2].abs() > v_max || x[3].abs() > v_max {
                outside += 1;
            }
            speed_max = speed_max.max(x[2].abs()).max(x[3].abs());
            if diverge.is_none() && e > 1.0 {
                diverge = Some((
                    (k + 1) as f64 * dt,
                    x[2].hypot(x[3]),
                    g.mean[2].hypot(g.mean[3]),
                    g.cov_at(2, 2).max(g.cov_at(3, 3)).sqrt(),
                ));
            }
            match mahalanobis2(g, x) {
                Some(m) if g.is_finite() => {
                    nees += m;
                    n_nees += 1;
                }
                _ => bad += 1,
            }
        };
        drive(&cfg, steps, seed, &mut filter_chain, &mut on_step)?
    };
    out.mass_lost_max = mass_lost_max;
    out.from_gaussian_swaps = from_gaussian_swaps;
    out.states_within_1sd = in1 / n_in.max(1) as f64;
    out.states_within_2sd = in2 / n_in.max(1) as f64;
    out.rmse_position_chain = (pos / steps as f64).sqrt();
    out.rmse_velocity_chain = (vel / steps as f64).sqrt();
    out.control_errors_chain = errs;
    out.bad_beliefs = bad;
    out.nees_chain = nees / n_nees.max(1) as f64;
    out.frac_speed_outside = outside as f64 / steps as f64;
    out.speed_max_chain = speed_max;
    let dv = diverge.unwrap_or((f64::NAN, f64::NAN, f64::NAN, f64::NAN));
    (
        out.diverge_s,
        out.diverge_true_v,
        out.diverge_chain_v,
        out.diverge_chain_vel_sd,
    ) = dv;
    out.transport_off = live.transport_off();
    out.per_second_chain = per_second_chain;
    out.respreads = live.respreads();
    out.reanchors = live.reanchors();
    out.refine_added = refine.added;
    out.versions = live.versions();
    (out.transport_built, out.transport_partial) = live.transport_stats();
    if let Some((_, n, d)) = live.active_info() {
        out.states = n;
        out.delta = d;
    }
    out.step_us = [
        percentile(&mut step_us, 0.5),
        percentile(&mut step_us, 0.99),
        percentile(&mut step_us, 1.0),
    ];
    out.prepare_us = [percentile(&mut prep_us, 0.5), percentile(&mut prep_us, 1.0)];
    out.swap_us = [percentile(&mut swap_us, 0.5), percentile(&mut swap_us, 1.0)];

    // The PF's own loop.
    let mut pf_cfg = cfg.filter.pf.clone();
    pf_cfg.seed = seed;
    let mut pf = Pf::new(model.clone(), &pf_cfg, &prior, 0.0)?;
    let (mut pos, mut vel) = (0.0, 0.0);
    let mut per_second_pf = vec![0.0; seconds];
    {
        let mut filter = |_k: usize, t: f64, u: &[f64], y: &[f64]| -> Result<Gaussian> {
            pf.predict(t, u)?;
            let _ = pf.update(&Measurement::full(y));
            Ok(pf.belief())
        };
        let (mut outside, mut smax) = (0usize, 0.0f64);
        let mut on_step = |k: usize, g: &Gaussian, x: &[f64]| {
            let e = se(g, x, 0);
            pos += e;
            vel += se(g, x, 2);
            per_second_pf[k / steps_per_s] += e;
            if x[2].abs() > v_max || x[3].abs() > v_max {
                outside += 1;
            }
            smax = smax.max(x[2].abs()).max(x[3].abs());
        };
        let (pt, py, pu, errs) = drive(&cfg, steps, seed, &mut filter, &mut on_step)?;
        out.control_errors_pf = errs;
        out.frac_speed_outside_pf = outside as f64 / steps as f64;
        out.speed_max_pf = smax;
        // The live chain (with refine) on the PF loop's record.
        let mut refine = SimRefine::new(&cfg, dt, dims.state, work)?;
        let mut live = live_chain_filter(model.clone(), &cfg, &prior)?;
        live.set_tuning(tuning.0, tuning.1);
        live.set_reanchor(cfg.filter.chain.reanchor_ess);
        live.set_moving_frame(cfg.refine.moving_frame);
        let (mut p2, mut v2, mut n2) = (0.0, 0.0, 0.0);
        for k in 0..steps {
            let t = (k + 1) as f64 * dt;
            refine.tick(k, &pu[k], &mut live)?;
            live.predict(t, &pu[k])?;
            let _ = live.update(&Measurement::full(&py[k]));
            live.advance(prepare)?;
            let g = live.belief();
            p2 += se(&g, &pt[k], 0);
            v2 += se(&g, &pt[k], 2);
            n2 += mahalanobis2(&g, &pt[k]).unwrap_or(f64::NAN);
        }
        out.nees_chain_on_pf_trace = n2 / steps as f64;
        out.reanchors_on_pf_trace = live.reanchors();
        out.rmse_position_chain_on_pf_trace = (p2 / steps as f64).sqrt();
        out.rmse_velocity_chain_on_pf_trace = (v2 / steps as f64).sqrt();
    }
    out.rmse_position_pf = (pos / steps as f64).sqrt();
    out.rmse_velocity_pf = (vel / steps as f64).sqrt();
    out.per_second_pf = per_second_pf;

    // The PF and the offline chain filter on the chain loop's record.
    let mut pf = Pf::new(model.clone(), &pf_cfg, &prior, 0.0)?;
    let n_off = out.states.max(100);
    let mut pts = vec![0.0; n_off * dims.state];
    let mut r2 = crate::rng::stream(seed, 0x0ff);
    for p in pts.chunks_exact_mut(dims.state) {
        crate::chain::Sampler::Uniform.sample(model.bounds(), &mut r2, p);
    }
    let chain = crate::chain::Chain::batch(&model, chain_config(&cfg, dims.state), &pts)?;
    let mut off = ChainFilter::new(model.clone(), chain, dt)?;
    off.reset(0.0, &prior);
    let (mut pos, mut vel, mut raw, mut pos_off, mut nees_pf) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        pf.predict(t, &us[k])?;
        let _ = pf.update(&Measurement::full(&ys[k]));
        let g = pf.belief();
        pos += se(&g, &truth[k], 0);
        vel += se(&g, &truth[k], 2);
        nees_pf += mahalanobis2(&g, &truth[k]).unwrap_or(f64::NAN);
        off.predict(t, &us[k])?;
        let _ = off.update(&Measurement::full(&ys[k]));
        pos_off += se(&off.belief(), &truth[k], 0);
        let (r, b) = (ys[k][0], ys[k][1]);
        raw += (r * b.cos() - truth[k][0]).powi(2) + (r * b.sin() - truth[k][1]).powi(2);
    }
    out.rmse_position_pf_on_chain_trace = (pos / steps as f64).sqrt();
    out.rmse_velocity_pf_on_chain_trace = (vel / steps as f64).sqrt();
    out.rmse_position_offline_chain = (pos_off / steps as f64).sqrt();
    out.rmse_position_raw = (raw / steps as f64).sqrt();
    out.nees_pf_on_chain_trace = nees_pf / steps as f64;
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
    // config = FILE: the pipeline config (default configs/default.toml).
    let (path, rest) = split_config_param(args);
    let mut p = Params::new(&rest);
    let seconds = p.usize(&mut rep, "seconds", 20)?;
    let hold = p.f64(&mut rep, "hold_s", 0.1)?;
    // drive = 1: the configured controller closes the loop on each filter's
    // own belief (as in the pipeline), with the error-source diagnostics.
    let closed = p.usize(&mut rep, "drive", 0)? == 1;
    // Live chain tuning (drive = 1): relative posterior flush, two-hop
    // transport candidates.
    let flush_rel = p.f64(&mut rep, "flush_rel", 1e-12)?;
    let two_hop = p.usize(&mut rep, "two_hop", 0)? == 1;
    let runs = args.runs.unwrap_or(2);
    p.finish()?;
    let cfg = config::load(std::path::Path::new(&path), &[])?;
    rep.param("config", path.as_str());
    rep.param("seed", args.seed);
    rep.param("runs", runs as u64);
    if closed {
        for r in 0..runs {
            let s = args.seed + r as u64;
            let o = closed_loop_controller(&cfg, seconds, s, None, (flush_rel, two_hop))?;
            rep.results.push(
                Row::new("loop")
                    .int("seed", s)
                    .num("rmse_position_chain", o.rmse_position_chain)
                    .num("rmse_position_pf", o.rmse_position_pf)
                    .num(
                        "rmse_position_pf_on_chain_trace",
                        o.rmse_position_pf_on_chain_trace,
                    )
                    .num("rmse_position_offline_chain", o.rmse_position_offline_chain)
                    .num("rmse_position_raw", o.rmse_position_raw)
                    .num("rmse_velocity_chain", o.rmse_velocity_chain)
                    .num("rmse_velocity_pf", o.rmse_velocity_pf)
                    .num(
                        "rmse_velocity_pf_on_chain_trace",
                        o.rmse_velocity_pf_on_chain_trace,
                    )
                    .num("nees_chain", o.nees_chain)
                    .num("nees_pf_on_chain_trace", o.nees_pf_on_chain_trace)
                    .num("states_within_1sd", o.states_within_1sd)
                    .num("states_within_2sd", o.states_within_2sd)
                    .num("frac_speed_outside", o.frac_speed_outside)
                    .num("frac_speed_outside_pf", o.frac_speed_outside_pf)
                    .num("speed_max_chain", o.speed_max_chain)
                    .num("speed_max_pf", o.speed_max_pf)
                    .num(
                        "rmse_position_chain_on_pf_trace",
                        o.rmse_position_chain_on_pf_trace,
                    )
                    .num(
                        "rmse_velocity_chain_on_pf_trace",
                        o.rmse_velocity_chain_on_pf_trace,
                    )
                    .num("nees_chain_on_pf_trace", o.nees_chain_on_pf_trace)
                    .num("diverge_s", o.diverge_s)
                    .num("diverge_true_v", o.diverge_true_v)
                    .num("diverge_chain_v", o.diverge_chain_v)
                    .num("diverge_chain_vel_sd", o.diverge_chain_vel_sd)
                    .int("transport_off", o.transport_off)
                    .int("control_errors_chain", o.control_errors_chain)
                    .int("control_errors_pf", o.control_errors_pf)
                    .int("bad_beliefs", o.bad_beliefs)
                    .num("mass_lost_max", o.mass_lost_max)
                    .int("from_gaussian_swaps", o.from_gaussian_swaps)
                    .int("respreads", o.respreads)
                    .int("reanchors", o.reanchors)
                    .int("reanchors_on_pf_trace", o.reanchors_on_pf_trace)
                    .int("refine_added", o.refine_added)
                    .int("versions", o.versions)
                    .int("states", o.states as u64)
                    .num("delta_s", o.delta)
                    .int("transport_built", o.transport_built)
                    .int("transport_partial", o.transport_partial)
                    .num("step_p50_us", o.step_us[0])
                    .num("step_p99_us", o.step_us[1])
                    .num("step_max_us", o.step_us[2])
                    .num("prepare_p50_us", o.prepare_us[0])
                    .num("prepare_max_us", o.prepare_us[1])
                    .num("swap_p50_us", o.swap_us[0])
                    .num("swap_max_us", o.swap_us[1]),
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
        return Ok(rep);
    }
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
        // The record's truth is projected into the chain's compact set; this
        // test keeps the set of its measurements (v_max = 4; default.toml
        // now has 8, where the PF's error on the projected record drops to
        // 0.25 and the chain's stays 0.59).
        let cfg = config::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/default.toml"),
            // The incremental chain: the moving frame loses track on this
            // projected record (1.996 vs raw 1.774 at 12 s, open).
            &[
                "ship.v_max=4.0".to_string(),
                "refine.moving_frame=false".to_string(),
            ],
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
