//! MPPI on the ship (4 states, 2 controls, wall force, disc barrier) at the
//! pipeline's sizes: K = 512 and 2048 samples × T = 50 steps.
//!
//! - Criterion measures `compute` alone (the next call's noise drawn
//!   beforehand by `prepare`, untimed, as the control stage does after
//!   publishing) and `prepare` alone.
//! - `ship_sqrt` is the same ship with its wall force computed from ρ²
//!   (one `sqrt` only beyond the wall) and an inlinable drift, instead of
//!   `hypot` on every call: the one-line change proposed for
//!   `model/ship.rs`; it is checked against `Ship::drift` before timing.
//! - A 1 kHz closed loop (the ship advanced 1 ms under each control) prints
//!   percentiles of the per-call `compute` time, wall and thread-CPU.
//!
//! `cargo bench --bench mppi`

use beliefbus::belief::Gaussian;
use beliefbus::control::cost::{DiscBarrier, TrackingCost};
use beliefbus::control::mppi::{Mppi, MppiConfig};
use beliefbus::control::Controller;
use beliefbus::model::ship::{Ship, ShipParams};
use beliefbus::model::{Bounds, Dims, SdeModel};
use beliefbus::rt::clock::thread_cpu_ns;
use criterion::{BenchmarkId, Criterion};
use hdrhistogram::Histogram;
use rand::RngExt;
use std::hint::black_box;
use std::time::{Duration, Instant};

const HORIZON: usize = 50;

/// The ship with `hypot` replaced by a squared-radius test (see module doc).
struct ShipSqrt(Ship);

impl SdeModel for ShipSqrt {
    fn name(&self) -> &str {
        "ship_sqrt"
    }
    fn dims(&self) -> Dims {
        self.0.dims()
    }
    #[inline]
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
        let p = &self.0.params;
        let rho2 = x[0] * x[0] + x[1] * x[1];
        let (f1, f2) = if rho2 >= p.radius * p.radius && x[0] * x[2] + x[1] * x[3] >= 0.0 {
            let k = -p.wall_gain / rho2.sqrt();
            (k * x[0], k * x[1])
        } else {
            (0.0, 0.0)
        };
        f[0] = x[2];
        f[1] = x[3];
        f[2] = f1 + u[0];
        f[3] = f2 + u[1];
    }
    fn diffusion(&self, x: &[f64], big_f: &mut [f64]) {
        self.0.diffusion(x, big_f)
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        self.0.obs_mean(x, g)
    }
    fn obs_std(&self, std: &mut [f64]) {
        self.0.obs_std(std)
    }
    fn bounds(&self) -> &Bounds {
        self.0.bounds()
    }
}

fn ship() -> Ship {
    Ship::new(ShipParams::paper(0.001)).expect("ship")
}

fn check_ship_sqrt() {
    let (a, b) = (ship(), ShipSqrt(ship()));
    let mut rng = beliefbus::rng::stream(1, 2);
    for _ in 0..10_000 {
        let x: [f64; 4] = std::array::from_fn(|_| rng.random_range(-11.0..11.0));
        let u = [rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0)];
        let (mut fa, mut fb) = ([0.0; 4], [0.0; 4]);
        a.drift(&x, &u, &mut fa);
        b.drift(&x, &u, &mut fb);
        for i in 0..4 {
            assert!((fa[i] - fb[i]).abs() <= 1e-12 * fa[i].abs().max(1.0));
        }
    }
}

fn ship_cost() -> TrackingCost {
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

fn mppi<M: SdeModel>(model: M, samples: usize) -> Mppi<M> {
    let cfg = MppiConfig {
        samples,
        horizon_steps: HORIZON,
        ..MppiConfig::default()
    };
    let mut m = Mppi::new(model, ship_cost(), &cfg).expect("mppi");
    m.set_goal(&[5.0, 3.0, 0.0, 0.0]);
    m
}

fn bench_compute<M: SdeModel>(
    g: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    name: &str,
    m: &mut Mppi<M>,
    id: &str,
) {
    let belief = Gaussian::diagonal(&[1.0, -2.0, 0.5, 0.3], &[0.1; 4]);
    let mut u = [0.0; 2];
    let mut t = 0.0;
    g.bench_function(BenchmarkId::new(name, id), |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                m.prepare();
                t += 0.001;
                let t0 = Instant::now();
                black_box(m.compute(t, black_box(&belief), &mut u).expect("compute"));
                total += t0.elapsed();
            }
            total
        })
    });
}

fn criterion_benches(c: &mut Criterion) {
    let mut g = c.benchmark_group("mppi_ship");
    for k in [512usize, 2048] {
        let id = format!("{k}x{HORIZON}");
        let mut m = mppi(ship(), k);
        bench_compute(&mut g, "compute", &mut m, &id);
        g.bench_function(BenchmarkId::new("prepare", &id), |b| b.iter(|| m.prepare()));
        let mut m = mppi(ShipSqrt(ship()), k);
        bench_compute(&mut g, "compute_ship_sqrt", &mut m, &id);
    }
    g.finish();
}

/// A 1 kHz closed loop: percentiles of `compute` (µs).
fn closed_loop<M: SdeModel>(label: &str, model: M, k: usize) {
    let mut m = mppi(model, k);
    let plant = ship();
    let mut rng = beliefbus::rng::stream(1, 1);
    let mut x = [0.0, 0.0, 0.0, 0.0];
    let mut u = [0.0; 2];
    let mut wall = Histogram::<u64>::new(3).expect("histogram");
    let mut cpu = Histogram::<u64>::new(3).expect("histogram");
    let calls = if k > 1000 { 1500 } else { 4000 };
    for i in 0..calls {
        let t = i as f64 * 0.001;
        let b = Gaussian::diagonal(&x, &[0.05; 4]);
        let (c0, t0) = (thread_cpu_ns(), Instant::now());
        m.compute(t, &b, &mut u).expect("compute");
        let ns = t0.elapsed().as_nanos() as u64;
        let cpu_ns = thread_cpu_ns().saturating_sub(c0);
        m.prepare();
        if i >= 100 {
            wall.record(ns).expect("record");
            cpu.record(cpu_ns.max(1)).expect("record");
        }
        beliefbus::model::discrete::em_integrate(&plant, &mut x, &u, 0.001, 0.001, &mut rng);
    }
    for (clock, h) in [("wall", &wall), ("cpu", &cpu)] {
        let q = |p: f64| h.value_at_quantile(p) as f64 / 1e3;
        println!(
            "{:>10} {:>10} {:>5} {:>6} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1}",
            label,
            format!("{k}x{HORIZON}"),
            clock,
            h.len(),
            q(0.5),
            q(0.9),
            q(0.99),
            q(0.999),
            h.max() as f64 / 1e3,
        );
    }
}

fn main() {
    check_ship_sqrt();
    let mut c = Criterion::default().configure_from_args();
    criterion_benches(&mut c);
    c.final_summary();
    println!("\nclosed loop at 1 kHz, compute() only (prepare() after each call, untimed):");
    println!("(wall: elapsed time; cpu: this thread's CPU time, excluding preemption)");
    println!(
        "{:>10} {:>10} {:>5} {:>6} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "model", "K x T", "clock", "calls", "p50_us", "p90_us", "p99_us", "p999_us", "max_us"
    );
    for k in [512usize, 2048] {
        closed_loop("ship", ship(), k);
        closed_loop("ship_sqrt", ShipSqrt(ship()), k);
    }
}
