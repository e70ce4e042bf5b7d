//! One control of the ship at horizon 50 (× 0.04 s): implicit-sampling
//! path-integral control (paper 003) at several sample counts against MPPI
//! with 2 048 and 512 samples, same cost, same horizon, same call pattern
//! (a moving state, warm-started, as in the closed loop). Only `compute` is
//! timed: MPPI's `prepare` (noise for the next call) runs outside the timed
//! region, as the control stage runs it after publishing.
//!
//! `cargo bench --bench path_integral`

use beliefbus::belief::Gaussian;
use beliefbus::control::mppi::{Mppi, MppiConfig};
use beliefbus::control::path_integral::{
    BeliefMode, GradientConfig, PathIntegralConfig, PathIntegralController,
};
use beliefbus::control::Controller;
use beliefbus::experiments::ship_control::ship_cost;
use beliefbus::model::ship::{Ship, ShipParams};
use criterion::{criterion_group, criterion_main, Criterion};
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

fn controllers(c: &mut Criterion) {
    let params = ShipParams::paper(0.01);
    for samples in [0usize, 8, 32] {
        let cfg = PathIntegralConfig {
            samples,
            budget_us: 0.0,
            ..PathIntegralConfig::default()
        };
        let mut ctrl = PathIntegralController::ship(params.clone(), ship_cost(), cfg).unwrap();
        bench_controller(c, &format!("ship_h50/implicit_M{samples}"), &mut ctrl);
    }
    let cfg = PathIntegralConfig {
        samples: 8,
        gradient: GradientConfig::FiniteDifference,
        budget_us: 0.0,
        ..PathIntegralConfig::default()
    };
    let mut ctrl = PathIntegralController::ship(params.clone(), ship_cost(), cfg).unwrap();
    bench_controller(c, "ship_h50/implicit_M8_fd", &mut ctrl);
    let cfg = PathIntegralConfig {
        samples: 8,
        belief: BeliefMode::Sampled,
        belief_samples: 4,
        budget_us: 0.0,
        ..PathIntegralConfig::default()
    };
    let mut ctrl = PathIntegralController::ship(params.clone(), ship_cost(), cfg).unwrap();
    bench_controller(c, "ship_h50/implicit_K4_M8", &mut ctrl);
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

criterion_group!(benches, controllers);
criterion_main!(benches);
