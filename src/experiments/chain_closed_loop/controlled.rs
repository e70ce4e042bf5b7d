//! Closed loop: the configured controller acts on each filter's own
//! belief, with the diagnostics that separate the chain filter's error
//! sources.

use super::super::chain_util::live_chain_filter;
use super::super::refine_sim::SimRefine;

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
