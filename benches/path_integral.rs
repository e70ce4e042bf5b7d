//! One control of the ship at horizon 50: implicit-sampling path-integral
//! control (paper 003) at several sample counts, against MPPI baselines.
//!
//! `cargo bench --bench path_integral`

use beliefbus::belief::Gaussian;
use beliefbus::control::cost::{DiscBarrier, TrackingCost};
use beliefbus::control::path_integral::{
    BeliefMode, GradientConfig, PathIntegralConfig, PathIntegralController,
};
use beliefbus::control::Controller;
use beliefbus::model::ship::ShipParams;
use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;

fn ship_cost() -> TrackingCost {
    let mut c = TrackingCost::new(
        &[1.0, 1.0, 0.1, 0.1],
        &[5.0, 5.0, 1.0, 1.0],
        Some(DiscBarrier {
            axes: (0, 1),
            radius: 8.0,
            weight: 50.0,
        }),
    );
    c.set_goal(&[4.0, -3.0, 0.0, 0.0]);
    c
}

/// Run `c` along a short trajectory so every measured call is warm-started
/// at a new time and state, as in the pipeline.
fn bench_controller(c: &mut Criterion, id: &str, ctrl: &mut dyn Controller) {
    let mut b = Gaussian::diagonal(&[-3.0, 2.0, 0.5, 0.0], &[0.05; 4]);
    let mut u = [0.0; 2];
    let mut t = 0.0;
    c.bench_function(id, |bench| {
        bench.iter(|| {
            t += 0.01;
            b.mean[0] += 0.005;
            if b.mean[0] > 3.0 {
                b.mean[0] = -3.0;
            }
            ctrl.compute(black_box(t), black_box(&b), &mut u).unwrap();
            black_box(u)
        })
    });
}

fn implicit(c: &mut Criterion) {
    let params = ShipParams::paper(0.01);
    for samples in [0usize, 8, 32] {
        let cfg = PathIntegralConfig {
            samples,
            budget_us: 0.0,
            ..PathIntegralConfig::default()
        };
        let mut ctrl = PathIntegralController::ship(params.clone(), ship_cost(), cfg).unwrap();
        bench_controller(c, &format!("implicit_h50/M{samples}"), &mut ctrl);
    }
    let cfg = PathIntegralConfig {
        samples: 8,
        gradient: GradientConfig::FiniteDifference,
        budget_us: 0.0,
        ..PathIntegralConfig::default()
    };
    let mut ctrl = PathIntegralController::ship(params.clone(), ship_cost(), cfg).unwrap();
    bench_controller(c, "implicit_h50_fd/M8", &mut ctrl);
    let cfg = PathIntegralConfig {
        samples: 8,
        belief: BeliefMode::Sampled,
        belief_samples: 4,
        budget_us: 0.0,
        ..PathIntegralConfig::default()
    };
    let mut ctrl = PathIntegralController::ship(params, ship_cost(), cfg).unwrap();
    bench_controller(c, "implicit_h50_belief/K4_M8", &mut ctrl);
}

criterion_group!(benches, implicit);
criterion_main!(benches);
