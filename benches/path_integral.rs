//! One control of the ship at horizon 50 (× 0.04 s): implicit-sampling
//! path-integral control (paper 003) at several sample counts against MPPI
//! with 2 048 and 512 samples, same cost, same horizon, same call pattern
//! (a moving state, warm-started, as in the closed loop). Only `compute` is
//! timed: MPPI's `prepare` (noise for the next call) runs outside the timed
//! region, as the control stage runs it after publishing.
//!
//! A second pass prints p50/p99 of the per-control time over 3 000 calls,
//! wall and thread-CPU (the CPU time excludes preemption, so it stays
//! meaningful on a loaded machine), and the CPU-p50 ratio to MPPI-2048.
//!
//! `cargo bench --bench path_integral` (criterion, then the percentiles);
//! `cargo bench --bench path_integral -- percentiles` (the percentiles only).

use beliefbus::belief::Gaussian;
use beliefbus::control::mppi::{Mppi, MppiConfig};
use beliefbus::control::path_integral::{
    BeliefMode, GradientConfig, PathIntegralConfig, PathIntegralController,
};
use beliefbus::control::Controller;
use beliefbus::experiments::ship_control::ship_cost;
use beliefbus::model::ship::{Ship, ShipParams};
use beliefbus::rt::clock::thread_cpu_ns;
use criterion::Criterion;
use hdrhistogram::Histogram;
use std::hint::black_box;
use std::time::{Duration, Instant};

/// Time `compute` only, along a slowly moving state.
fn bench_controller(c: &mut Criterion, id: &str, ctrl: &mut dyn Controller) {
    let mut b = Gaussian::diagonal(&[-3.0, 2.0, 0.5, 0.0], &[0.05; 4]);
    let mut u = [0.0; 2];
    let mut t = 0.0;
    ctrl.set_goal(&[4.0, -3.0, 0.0, 0.0]);
    c.bench_function(id, |bench| {
        bench.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                t += 0.01;
                b.mean[0] += 0.005;
                if b.mean[0] > 3.0 {
                    b.mean[0] = -3.0;
                }
                let start = Instant::now();
                ctrl.compute(black_box(t), black_box(&b), &mut u).unwrap();
                total += start.elapsed();
                black_box(u);
            }
            total
        })
    });
}

/// The path-integral configurations measured: name and config.
fn pi_configs() -> Vec<(String, PathIntegralConfig)> {
    let base = PathIntegralConfig {
        budget_us: 0.0,
        ..PathIntegralConfig::default()
    };
    let mut v = vec![];
    for samples in [0usize, 8, 32] {
        v.push((
            format!("implicit_M{samples}"),
            PathIntegralConfig {
                samples,
                ..base.clone()
            },
        ));
    }
    for samples in [0usize, 8] {
        v.push((
            format!("implicit_M{samples}_rti1"),
            PathIntegralConfig {
                samples,
                newton_max_iter: 1,
                newton_accept_at_cap: true,
                ..base.clone()
            },
        ));
    }
    for (name, gradient) in [
        ("fd", GradientConfig::FiniteDifference),
        ("lr", GradientConfig::LikelihoodRatio),
    ] {
        v.push((
            format!("implicit_M8_{name}"),
            PathIntegralConfig {
                samples: 8,
                gradient,
                ..base.clone()
            },
        ));
    }
    v.push((
        "implicit_K4_M8".into(),
        PathIntegralConfig {
            samples: 8,
            belief: BeliefMode::Sampled,
            belief_samples: 4,
            ..base
        },
    ));
    v
}

fn controllers(c: &mut Criterion) {
    let params = ShipParams::paper(0.01);
    for (name, cfg) in pi_configs() {
        let mut ctrl = PathIntegralController::ship(params.clone(), ship_cost(), cfg).unwrap();
        bench_controller(c, &format!("ship_h50/{name}"), &mut ctrl);
    }
    for k in [2048usize, 512] {
        let ship = Ship::new(params.clone()).unwrap();
        let cfg = MppiConfig {
            samples: k,
            ..MppiConfig::default()
        };
        let mut m = Mppi::new(ship, ship_cost(), &cfg).unwrap();
        let mut b = Gaussian::diagonal(&[-3.0, 2.0, 0.5, 0.0], &[0.05; 4]);
        let mut u = [0.0; 2];
        let mut t = 0.0;
        m.set_goal(&[4.0, -3.0, 0.0, 0.0]);
        c.bench_function(&format!("ship_h50/mppi_{k}"), |bench| {
            bench.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    t += 0.01;
                    b.mean[0] += 0.005;
                    if b.mean[0] > 3.0 {
                        b.mean[0] = -3.0;
                    }
                    m.prepare();
                    let start = Instant::now();
                    m.compute(black_box(t), black_box(&b), &mut u).unwrap();
                    total += start.elapsed();
                    black_box(u);
                }
                total
            })
        });
    }
}

/// Per-control wall and CPU percentiles over `calls` controls along the
/// benchmark's moving state (MPPI's `prepare` outside the timed region).
fn percentiles() {
    let calls = 3000;
    let params = ShipParams::paper(0.01);
    enum Ctl {
        Pi(Box<PathIntegralController>),
        Mppi(Box<Mppi<Ship>>),
    }
    let mut ctrls: Vec<(String, Ctl)> = pi_configs()
        .into_iter()
        .map(|(name, cfg)| {
            let c = PathIntegralController::ship(params.clone(), ship_cost(), cfg).unwrap();
            (name, Ctl::Pi(Box::new(c)))
        })
        .collect();
    for k in [2048usize, 512] {
        let ship = Ship::new(params.clone()).unwrap();
        let cfg = MppiConfig {
            samples: k,
            ..MppiConfig::default()
        };
        let m = Mppi::new(ship, ship_cost(), &cfg).unwrap();
        ctrls.push((format!("mppi_{k}"), Ctl::Mppi(Box::new(m))));
    }
    println!("\nper-control time over {calls} calls (µs; cpu = this thread's CPU time)");
    println!(
        "{:>20} {:>9} {:>9} {:>9} {:>9} {:>12}",
        "controller", "wall p50", "wall p99", "cpu p50", "cpu p99", "cpu x mppi2k"
    );
    let mut rows = vec![];
    for (name, ctl) in ctrls.iter_mut() {
        let ctrl: &mut dyn Controller = match ctl {
            Ctl::Pi(c) => c.as_mut(),
            Ctl::Mppi(m) => {
                m.prepare();
                m.as_mut()
            }
        };
        let mut wall = Histogram::<u64>::new(3).expect("histogram");
        let mut cpu = Histogram::<u64>::new(3).expect("histogram");
        let mut b = Gaussian::diagonal(&[-3.0, 2.0, 0.5, 0.0], &[0.05; 4]);
        let mut u = [0.0; 2];
        ctrl.set_goal(&[4.0, -3.0, 0.0, 0.0]);
        for i in 0..calls {
            b.mean[0] += 0.005;
            if b.mean[0] > 3.0 {
                b.mean[0] = -3.0;
            }
            let (c0, t0) = (thread_cpu_ns(), Instant::now());
            ctrl.compute(black_box(i as f64 * 0.01), black_box(&b), &mut u)
                .unwrap();
            let w = t0.elapsed().as_nanos() as u64;
            cpu.record(thread_cpu_ns().saturating_sub(c0).max(1))
                .expect("record");
            wall.record(w.max(1)).expect("record");
            black_box(u);
            // MPPI draws the next call's noise after publishing (untimed).
            ctrl.prepare();
        }
        let q = |h: &Histogram<u64>, p: f64| h.value_at_quantile(p) as f64 / 1e3;
        rows.push((
            name.clone(),
            q(&wall, 0.5),
            q(&wall, 0.99),
            q(&cpu, 0.5),
            q(&cpu, 0.99),
        ));
    }
    let reference = rows
        .iter()
        .find(|r| r.0 == "mppi_2048")
        .map(|r| r.3)
        .unwrap_or(f64::NAN);
    for (name, w50, w99, c50, c99) in rows {
        println!(
            "{name:>20} {w50:>9.1} {w99:>9.1} {c50:>9.1} {c99:>9.1} {:>12.2}",
            reference / c50
        );
    }
}

fn main() {
    let only_percentiles = std::env::args().any(|a| a == "percentiles");
    if !only_percentiles {
        let mut c = Criterion::default().configure_from_args();
        controllers(&mut c);
        c.final_summary();
    }
    percentiles();
}
