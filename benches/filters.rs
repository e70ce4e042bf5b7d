//! One filter step (predict to the next sample + update on its measurement)
//! on the ship, as the filter stage runs it: bootstrap PF with 1000
//! particles, the projection PF with as many (`projection-pf`: the same
//! propagation, then a Gaussian projection and redraw every update), EKF
//! and UKF, at 1 kHz (Δ = 1 ms) and 100 Hz (Δ = 10 ms).
//!
//! Criterion measures the step on a pre-recorded ship trajectory; a second
//! pass prints percentiles of the per-step time over a long run, wall and
//! thread-CPU.
//!
//! `cargo bench --bench filters`

use beliefbus::belief::Gaussian;
use beliefbus::filter::ekf::{Ekf, EkfConfig};
use beliefbus::filter::pf::{Pf, PfConfig};
use beliefbus::filter::ukf::{Ukf, UkfConfig};
use beliefbus::filter::BayesFilter;
use beliefbus::model::ship::{Ship, ShipParams};
use beliefbus::model::Measurement;
use beliefbus::rt::clock::thread_cpu_ns;
use criterion::{BenchmarkId, Criterion};
use hdrhistogram::Histogram;
use std::hint::black_box;
use std::time::Instant;

const X0: [f64; 4] = [2.0, -1.0, 1.0, 0.5];

/// A ship trajectory sampled every `dt` with the paper's noise for that rate.
fn trajectory(dt: f64, n: usize) -> (Ship, Vec<[f64; 2]>) {
    let ship = Ship::new(ShipParams::paper(dt)).expect("ship");
    let mut rng = beliefbus::rng::stream(3, 3);
    let mut x = X0;
    let ys = (0..n)
        .map(|_| {
            beliefbus::model::discrete::em_integrate(
                &ship,
                &mut x,
                &[0.0, 0.0],
                dt,
                1e-3,
                &mut rng,
            );
            let mut y = [0.0; 2];
            beliefbus::model::simulate_observation(&ship, &x, &mut rng, &mut y);
            y
        })
        .collect();
    (ship, ys)
}

fn prior() -> Gaussian {
    Gaussian::diagonal(&X0, &[0.3; 4])
}

type Make = fn(Ship) -> Box<dyn BayesFilter>;

fn backends() -> [(&'static str, Make); 4] {
    [
        ("pf1000", |s| {
            let cfg = PfConfig {
                particles: 1000,
                ..PfConfig::default()
            };
            Box::new(Pf::new(s, &cfg, &prior(), 0.0).expect("pf"))
        }),
        ("ppf1000", |s| {
            let cfg = PfConfig {
                particles: 1000,
                ..PfConfig::default()
            };
            Box::new(
                beliefbus_projection::SdeProjectionPf::new(s, &cfg, &prior(), 0.0)
                    .expect("projection pf"),
            )
        }),
        ("ekf", |s| {
            Box::new(Ekf::new(s, &EkfConfig::default(), &prior(), 0.0).expect("ekf"))
        }),
        ("ukf", |s| {
            Box::new(Ukf::new(s, &UkfConfig::default(), &prior(), 0.0).expect("ukf"))
        }),
    ]
}

fn step(f: &mut dyn BayesFilter, t: f64, y: &[f64; 2]) {
    f.predict(t, &[0.0, 0.0]).expect("predict");
    // A Degenerate update (possible for the PF on an outlier) keeps the
    // belief; the stage counts it. It is part of the measured cost.
    let _ = black_box(f.update(&Measurement::full(y)));
}

fn criterion_benches(c: &mut Criterion) {
    let mut g = c.benchmark_group("filter_step_ship");
    for (rate, dt) in [("1khz", 0.001), ("100hz", 0.01)] {
        for (name, make) in backends() {
            let (ship, ys) = trajectory(dt, 20_000);
            let mut f = make(ship);
            let mut k = 0usize;
            g.bench_function(BenchmarkId::new(name, rate), |b| {
                b.iter(|| {
                    let i = k % ys.len();
                    if i == 0 {
                        f.reset(0.0, &prior());
                    }
                    k += 1;
                    step(f.as_mut(), (i + 1) as f64 * dt, &ys[i]);
                })
            });
        }
    }
    g.finish();
}

fn percentiles() {
    println!("\nfilter step (predict + update) on the ship, per-step time:");
    println!("(wall: elapsed time; cpu: this thread's CPU time, excluding preemption)");
    println!(
        "{:>8} {:>6} {:>5} {:>7} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "backend", "rate", "clock", "steps", "p50_us", "p90_us", "p99_us", "p999_us", "max_us"
    );
    for (rate, dt) in [("1khz", 0.001), ("100hz", 0.01)] {
        for (name, make) in backends() {
            let n = 10_000;
            let (ship, ys) = trajectory(dt, n);
            let mut f = make(ship);
            let mut wall = Histogram::<u64>::new(3).expect("histogram");
            let mut cpu = Histogram::<u64>::new(3).expect("histogram");
            for (i, y) in ys.iter().enumerate() {
                let (c0, t0) = (thread_cpu_ns(), Instant::now());
                step(f.as_mut(), (i + 1) as f64 * dt, y);
                wall.record(t0.elapsed().as_nanos() as u64).expect("record");
                cpu.record(thread_cpu_ns().saturating_sub(c0).max(1))
                    .expect("record");
            }
            for (clock, h) in [("wall", &wall), ("cpu", &cpu)] {
                let q = |p: f64| h.value_at_quantile(p) as f64 / 1e3;
                println!(
                    "{:>8} {:>6} {:>5} {:>7} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1}",
                    name,
                    rate,
                    clock,
                    h.len(),
                    q(0.5),
                    q(0.9),
                    q(0.99),
                    q(0.999),
                    h.max() as f64 / 1e3
                );
            }
        }
    }
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    criterion_benches(&mut c);
    c.final_summary();
    percentiles();
}
