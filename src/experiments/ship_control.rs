//! `ship-control`: the pipeline's controller question in one process —
//! implicit-sampling path-integral control of the drifting ship against MPPI
//! with 2 048 and 512 samples: closed-loop cost and compute per control.
//!
//! Each run simulates the true ship (paper 001 eq. 10–11 with control on the
//! velocities, e = 0.3 on every state) by Euler–Maruyama at Δ = 10 ms; every
//! step the controller gets the true state (`belief=truth`, default) or a
//! noisy Gaussian belief (`belief=noisy`: mean = truth + N(0, diag(0.1², 0.1²,
//! 0.05², 0.05²)), that covariance) and returns the force held over Δ. The
//! route is `configs/default.toml`'s, tracked by [`WaypointTracker`]:
//! (5,5) → (−5,5) → (−5,−5) → (5,−5), reach radius 1, from (3, 0) at rest,
//! without cycling (the last waypoint is held). All controllers share
//! the tracking cost (q = (1,1,0.1,0.1), q_f = (10,10,1,1), barrier at
//! radius 8, weight 100), the horizon (50 × 0.04 s), the control limits ±3
//! and the control weight (MPPI's r‖u‖² with r = 0.05 is ½uᵀRu with R = 0.1
//! for the path-integral controller), and each run's plant noise.
//!
//! closed-loop cost = Σ_k [q(x_k) + 0.05 ‖u_k‖²] Δ over the run, with q
//! tracking the active waypoint. Compute = wall time of `compute` (MPPI's
//! noise for the next call is drawn by `prepare` outside the timed region,
//! as the control stage does), and its thread CPU time (`cpu_*`: the same
//! without the time descheduled — on a shared machine the wall-time p99 is
//! mostly other processes' time slices). Speedups are p50 ratios to
//! `mppi_2048` measured in the same run; cost ratios are paired by run.

use super::pi_common::{check_params, list_param, mean_std, param, percentile, thread_cpu_us};
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::belief::Gaussian;
use crate::control::cost::{DiscBarrier, PathCost, TrackingCost};
use crate::control::mppi::{Mppi, MppiConfig};
use crate::control::path_integral::{
    BeliefMode, GradientConfig, PathIntegralConfig, PathIntegralController, WarmShift,
};
use crate::control::waypoints::{RouteConfig, WaypointTracker};
use crate::control::Controller;
use crate::model::ship::{Ship, ShipParams};
use crate::model::{em_step, SdeModel};
use crate::rng;
use rand::RngExt;
use rand_distr::StandardNormal;
use std::time::Instant;

/// The shared tracking cost.
pub fn ship_cost() -> TrackingCost {
    TrackingCost::new(
        &[1.0, 1.0, 0.1, 0.1],
        &[10.0, 10.0, 1.0, 1.0],
        Some(DiscBarrier {
            axes: (0, 1),
            radius: 8.0,
            weight: 100.0,
        }),
    )
}

enum Ctl {
    Pi(Box<PathIntegralController>),
    Mppi(Box<Mppi<Ship>>),
}

impl Ctl {
    fn as_controller(&mut self) -> &mut dyn Controller {
        match self {
            Ctl::Pi(c) => c.as_mut(),
            Ctl::Mppi(c) => c.as_mut(),
        }
    }
    fn prepare(&mut self) {
        if let Ctl::Mppi(c) = self {
            c.prepare();
        }
    }
}

/// One controller's result: name, per-run costs, (wall p50, CPU p50) µs, row.
type Summary = (String, Vec<f64>, (f64, f64), Row);

struct Spec {
    name: String,
    make: Box<dyn Fn(u64) -> anyhow::Result<Ctl>>,
}

/// The experiment entry point.
pub fn run(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    check_params(
        args,
        &[
            "duration",
            "belief",
            "controllers",
            "pi_samples",
            "pi_belief",
            "budget_us",
            "mppi_samples",
            "pi_limit_weight",
            "pi_limit_blend",
            "pi_newton_tol",
            "pi_gradient",
            "pi_warm",
            "pi_newton_max_iter",
        ],
    )?;
    let runs = args.runs.unwrap_or(5);
    let duration: f64 = param(args, "duration", 20.0)?;
    let belief_mode: String = param(args, "belief", "truth".to_string())?;
    anyhow::ensure!(
        belief_mode == "truth" || belief_mode == "noisy",
        "belief must be truth or noisy"
    );
    let pi_samples: Vec<usize> = list_param(args, "pi_samples", &[8, 0])?;
    let pi_belief: String = param(args, "pi_belief", "mean".to_string())?;
    let budget_us: f64 = param(args, "budget_us", 0.0)?;
    let limit_weight: f64 = param(
        args,
        "pi_limit_weight",
        PathIntegralConfig::default().control_limit_weight,
    )?;
    let defaults = PathIntegralConfig::default();
    let limit_blend: f64 = param(args, "pi_limit_blend", defaults.control_limit_blend)?;
    let newton_tol: f64 = param(args, "pi_newton_tol", defaults.newton_tol)?;
    let gradient_name: String = param(args, "pi_gradient", "analytic".to_string())?;
    let gradient = match gradient_name.as_str() {
        "analytic" => GradientConfig::Analytic,
        "finite_difference" | "fd" => GradientConfig::FiniteDifference,
        "likelihood_ratio" | "lr" => GradientConfig::LikelihoodRatio,
        other => anyhow::bail!("pi_gradient={other}: analytic | fd | lr"),
    };
    // 0: the default cap, failing at it; k > 0: at most k iterations, the
    // iterate reached is used (real-time iteration).
    let rti: usize = param(args, "pi_newton_max_iter", 0)?;
    let warm_name: String = param(args, "pi_warm", "interpolate".to_string())?;
    let warm_shift = match warm_name.as_str() {
        "interpolate" => WarmShift::Interpolate,
        "whole_steps" => WarmShift::WholeSteps,
        other => anyhow::bail!("pi_warm={other}: interpolate | whole_steps"),
    };
    let mppi_samples: Vec<usize> = list_param(args, "mppi_samples", &[2048, 512])?;
    let dt = 0.01;
    let steps = (duration / dt).round() as usize;
    let params = ShipParams::paper(dt);
    let ship = Ship::new(params.clone()).map_err(anyhow::Error::msg)?;
    let route = RouteConfig {
        waypoints: vec![
            vec![5.0, 5.0],
            vec![-5.0, 5.0],
            vec![-5.0, -5.0],
            vec![5.0, -5.0],
        ],
        reach_radius: 1.0,
        cycle: false,
    };
    let mppi_cfg = MppiConfig::default();
    let w_u = mppi_cfg.control_weight;

    let mut specs: Vec<Spec> = vec![];
    for &m in &pi_samples {
        let params = params.clone();
        let belief = if pi_belief == "sampled" {
            BeliefMode::Sampled
        } else {
            BeliefMode::Mean
        };
        let cfg = PathIntegralConfig {
            samples: m,
            horizon_steps: mppi_cfg.horizon_steps,
            dt: mppi_cfg.dt,
            control_cost: 2.0 * w_u,
            u_max: mppi_cfg.u_max[0],
            budget_us,
            belief,
            control_limit_weight: limit_weight,
            control_limit_blend: limit_blend,
            newton_tol,
            gradient,
            warm_shift,
            newton_max_iter: if rti > 0 {
                rti
            } else {
                defaults.newton_max_iter
            },
            newton_accept_at_cap: rti > 0,
            ..PathIntegralConfig::default()
        };
        specs.push(Spec {
            name: format!("implicit_M{m}"),
            make: Box::new(move |seed| {
                let cfg = PathIntegralConfig {
                    seed,
                    ..cfg.clone()
                };
                Ok(Ctl::Pi(Box::new(PathIntegralController::ship(
                    params.clone(),
                    ship_cost(),
                    cfg,
                )?)))
            }),
        });
    }
    for &k in &mppi_samples {
        let ship = ship.clone();
        let cfg = MppiConfig {
            samples: k,
            ..mppi_cfg.clone()
        };
        specs.push(Spec {
            name: format!("mppi_{k}"),
            make: Box::new(move |seed| {
                let cfg = MppiConfig {
                    seed,
                    ..cfg.clone()
                };
                Ok(Ctl::Mppi(Box::new(Mppi::new(
                    ship.clone(),
                    ship_cost(),
                    &cfg,
                )?)))
            }),
        });
    }
    if let Some((_, v)) = args.params.iter().rev().find(|(k, _)| k == "controllers") {
        let want: Vec<&str> = v.split(',').map(str::trim).collect();
        specs.retain(|s| want.contains(&s.name.as_str()));
        anyhow::ensure!(!specs.is_empty(), "controllers={v} selects nothing");
    }

    let mut rep = ExperimentReport::new("ship-control");
    rep.param("runs", runs);
    rep.param("duration_s", duration);
    rep.param("control_period_s", dt);
    rep.param("belief", belief_mode.as_str());
    rep.param(
        "horizon",
        format!("{} x {} s", mppi_cfg.horizon_steps, mppi_cfg.dt),
    );
    rep.param("u_max", mppi_cfg.u_max[0]);
    rep.param("control_weight", w_u);
    rep.param("pi_belief", pi_belief.as_str());
    rep.param("pi_budget_us", budget_us);
    rep.param("pi_limit_weight", limit_weight);
    rep.param("pi_limit_blend", limit_blend);
    rep.param("pi_newton_tol", newton_tol);
    rep.param("pi_gradient", gradient_name.as_str());
    rep.param("pi_warm", warm_name.as_str());
    rep.param("pi_newton_max_iter", rti);
    rep.param(
        "waypoints",
        "(5,5) (-5,5) (-5,-5) (5,-5), reach 1.0, no cycle; start (3,0,0,0)",
    );
    rep.param("seed", args.seed);

    let mut bar = Progress::new("ship-control", runs * specs.len(), args.progress);
    let mut rows: Vec<Summary> = vec![];
    for spec in &specs {
        let (mut costs, mut reached, mut times, mut fails) = (vec![], vec![], vec![], 0usize);
        let mut cpu = vec![];
        let mut iters = vec![];
        let mut final_dist = vec![];
        for run in 0..runs {
            let mut ctl = (spec.make)(args.seed.wrapping_add(run as u64))?;
            let mut plant = rng::stream(args.seed, 0x5348_0000 + run as u64);
            let mut sense = rng::stream(args.seed, 0x4245_0000 + run as u64);
            let mut tracker = WaypointTracker::new(route.clone());
            let mut cost = ship_cost();
            let mut x = [3.0, 0.0, 0.0, 0.0];
            let goal = |g: [f64; 2]| [g[0], g[1], 0.0, 0.0];
            cost.set_goal(&goal(tracker.goal2()));
            ctl.as_controller().set_goal(&goal(tracker.goal2()));
            ctl.prepare();
            let mut u = [0.0; 2];
            let mut j = 0.0;
            let std = [0.1, 0.1, 0.05, 0.05];
            for k in 0..steps {
                let mut b = Gaussian::diagonal(&x, &std);
                if belief_mode == "noisy" {
                    for i in 0..4 {
                        b.mean[i] += std[i] * sense.sample::<f64, _>(StandardNormal);
                    }
                }
                let (start, c0) = (Instant::now(), thread_cpu_us());
                let r = ctl.as_controller().compute(k as f64 * dt, &b, &mut u);
                times.push(start.elapsed().as_secs_f64() * 1e6);
                cpu.push(thread_cpu_us() - c0);
                if let Ctl::Pi(c) = &ctl {
                    iters.push(c.stats().newton_iterations as f64);
                }
                if r.is_err() {
                    fails += 1;
                    u = [0.0, 0.0];
                }
                ctl.prepare();
                j += (cost.running(&x) + w_u * (u[0] * u[0] + u[1] * u[1])) * dt;
                let mut next = [0.0; 4];
                em_step(&ship, &x, &u, dt, &mut plant, &mut next);
                x = next;
                if tracker.update(&x[..2]) {
                    cost.set_goal(&goal(tracker.goal2()));
                    ctl.as_controller().set_goal(&goal(tracker.goal2()));
                }
            }
            costs.push(j);
            reached.push(tracker.reached() as f64);
            final_dist.push(tracker.distance(&x[..2]));
            bar.tick();
        }
        let (mc, sc) = mean_std(&costs);
        let p50 = percentile(&times, 0.5);
        let cpu50 = percentile(&cpu, 0.5);
        let row = Row::new(&spec.name)
            .num("cost", mc)
            .num("cost_std", sc)
            .num("waypoints_reached", mean_std(&reached).0)
            .num("final_distance", mean_std(&final_dist).0)
            .num("compute_p50_us", p50)
            .num("compute_p90_us", percentile(&times, 0.9))
            .num("compute_p99_us", percentile(&times, 0.99))
            .num("cpu_p50_us", cpu50)
            .num("cpu_p99_us", percentile(&cpu, 0.99))
            .int("failed_controls", fails as u64);
        let row = if iters.is_empty() {
            row
        } else {
            row.num("newton_iter_mean", mean_std(&iters).0)
                .num("newton_iter_p99", percentile(&iters, 0.99))
        };
        rows.push((spec.name.clone(), costs, (p50, cpu50), row));
    }
    let reference = rows
        .iter()
        .find(|r| r.0 == "mppi_2048")
        .map(|r| (r.1.clone(), r.2));
    for (_, c, (p50, cpu50), row) in rows {
        let row = match &reference {
            Some((c_ref, (t_ref, cpu_ref))) => {
                // Paired by run (same plant noise): mean and range of the ratio.
                let ratios: Vec<f64> = c.iter().zip(c_ref).map(|(a, b)| a / b).collect();
                let lo = ratios.iter().copied().fold(f64::INFINITY, f64::min);
                let hi = ratios.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                row.num("cost_vs_mppi_2048", mean_std(&ratios).0)
                    .num("cost_ratio_min", lo)
                    .num("cost_ratio_max", hi)
                    .num("compute_speedup_vs_mppi_2048", t_ref / p50)
                    .num("cpu_speedup_vs_mppi_2048", cpu_ref / cpu50)
            }
            None => row,
        };
        rep.results.push(row);
    }
    rep.notes.push(format!(
        "the ship state dimension is {}; every controller gets the same plant noise per run; compute percentiles over all {} controls of all runs",
        ship.dims().state,
        steps * runs
    ));
    Ok(rep)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn implicit_matches_mppi_cost_over_the_route() {
        // The full route (20 s): the cost compares only once every controller
        // has reached the last waypoint (reaching one early adds the next leg).
        let args = ExperimentArgs {
            runs: Some(1),
            params: vec![
                ("pi_samples".into(), "8".into()),
                ("mppi_samples".into(), "512".into()),
            ],
            doc: crate::experiments::find("ship-control").unwrap().params,
            ..ExperimentArgs::default()
        };
        let rep = run(&args).unwrap();
        let pi = &rep.results[0].metrics;
        let mppi = &rep.results[1].metrics;
        assert_eq!(pi["waypoints_reached"].as_f64().unwrap(), 4.0);
        assert_eq!(mppi["waypoints_reached"].as_f64().unwrap(), 4.0);
        assert!(pi["cost"].as_f64().unwrap() < 1.1 * mppi["cost"].as_f64().unwrap());
    }
}
