//! Criterion benchmarks of the Markov-chain library (issue 3): batch
//! construction (Alg. 2.1), incremental construction with reconnection
//! (Alg. 2.3) measured per added state at a given chain size, and one chain
//! filter step (predict over Δ = 0.01 s + update). k-NN Near rule,
//! k = ⌈1.5 log n⌉ (floored at 1 + d + d(d+1)/2 + 1); the mean out-degree of
//! each chain is printed to stderr. d = 2: Van der Pol; d = 4: the ship.
//!
//! `cargo bench --bench chain` (BENCH_FULL=1 adds n = 10⁵ to every group).

use std::time::{Duration, Instant};

use beliefbus::chain::{Chain, ChainConfig, KernelKind, Sampler};
use beliefbus::filter::chain_filter::ChainFilter;
use beliefbus::filter::BayesFilter;
use beliefbus::model::ship::{Ship, ShipParams};
use beliefbus::model::vanderpol::{VanDerPol, VanDerPolParams};
use beliefbus::model::{Measurement, SdeModel};
use beliefbus::rng::stream;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

fn sizes() -> Vec<usize> {
    if std::env::var("BENCH_FULL").is_ok() {
        vec![1_000, 10_000, 100_000]
    } else {
        vec![1_000, 10_000]
    }
}

fn cfg(d: usize, kernel: KernelKind) -> ChainConfig {
    match kernel {
        KernelKind::Gaussian => ChainConfig::gaussian(d),
        KernelKind::MomentMatched => ChainConfig::moment_matched(d),
    }
}

fn batch_group<M: SdeModel + Clone>(c: &mut Criterion, name: &str, model: &M, kernel: KernelKind) {
    let d = model.dims().state;
    let mut g = c.benchmark_group(format!("batch/{name}/{kernel:?}"));
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    for n in sizes() {
        let pts = Sampler::Uniform.sample_many(model.bounds(), n, &mut stream(1, n as u64));
        let ch = Chain::batch(model, cfg(d, kernel), &pts).unwrap();
        eprintln!(
            "batch/{name}/{kernel:?} n={n}: mean out-degree {:.2}",
            ch.mean_out_degree()
        );
        g.throughput(Throughput::Elements(n as u64));
        g.bench_with_input(BenchmarkId::from_parameter(n), &pts, |b, pts| {
            b.iter(|| Chain::batch(model, cfg(d, kernel), pts).unwrap())
        });
    }
    g.finish();
}

fn incremental_group<M: SdeModel + Clone>(
    c: &mut Criterion,
    name: &str,
    model: &M,
    kernel: KernelKind,
) {
    let d = model.dims().state;
    let add = 1000;
    let mut g = c.benchmark_group(format!("incremental/{name}/{kernel:?}"));
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    g.throughput(Throughput::Elements(add as u64));
    for n in sizes() {
        let pts = Sampler::Uniform.sample_many(model.bounds(), n, &mut stream(2, n as u64));
        let base = Chain::batch(model, cfg(d, kernel), &pts).unwrap();
        let new = Sampler::Uniform.sample_many(model.bounds(), add, &mut stream(3, n as u64));
        g.bench_function(BenchmarkId::from_parameter(n), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                let mut rec = Vec::with_capacity(64);
                for _ in 0..iters {
                    let mut ch = base.clone();
                    ch.reserve(add);
                    let t0 = Instant::now();
                    for x in new.chunks_exact(d) {
                        ch.add_state(model, x, &mut rec).unwrap();
                    }
                    total += t0.elapsed();
                }
                total
            })
        });
    }
    g.finish();
}

fn step_group<M: SdeModel + Clone>(
    c: &mut Criterion,
    name: &str,
    model: &M,
    y: &[f64],
    kernel: KernelKind,
) {
    step_group_with(c, name, model, y, kernel, false)
}

/// `advected`: ChainConfig::step = 0.01 (one δ step per observation) and
/// flush 1e-12 (sparse support), as in the filtering experiments.
fn step_group_with<M: SdeModel + Clone>(
    c: &mut Criterion,
    name: &str,
    model: &M,
    y: &[f64],
    kernel: KernelKind,
    advected: bool,
) {
    let d = model.dims().state;
    let u = vec![0.0; model.dims().control];
    let tag = if advected {
        "filter_step_advected"
    } else {
        "filter_step"
    };
    let mut g = c.benchmark_group(format!("{tag}/{name}/{kernel:?}"));
    g.sample_size(20).measurement_time(Duration::from_secs(3));
    for n in sizes() {
        let pts = Sampler::Uniform.sample_many(model.bounds(), n, &mut stream(4, n as u64));
        let mut cf = cfg(d, kernel);
        if advected {
            cf.step = Some(0.01);
        }
        let ch = Chain::batch(model, cf, &pts).unwrap();
        let deg = ch.mean_out_degree();
        let mut f = ChainFilter::new(model.clone(), ch, 0.01).unwrap();
        if advected {
            f.set_flush(1e-12);
        }
        eprintln!(
            "{tag}/{name}/{kernel:?} n={n}: mean out-degree {deg:.2}, delta {:.2e} ({} substeps per step)",
            f.delta(),
            (0.01 / f.delta()).round()
        );
        let mut t = 0.0;
        g.bench_function(BenchmarkId::from_parameter(n), |b| {
            b.iter(|| {
                t += 0.01;
                f.predict(t, &u).unwrap();
                let _ = f.update(&Measurement::full(y));
            })
        });
    }
    g.finish();
}

fn benches(c: &mut Criterion) {
    let vdp = VanDerPol::new(VanDerPolParams::default()).unwrap();
    let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
    for kernel in [KernelKind::Gaussian, KernelKind::MomentMatched] {
        batch_group(c, "d2", &vdp, kernel);
        batch_group(c, "d4", &ship, kernel);
        incremental_group(c, "d2", &vdp, kernel);
        incremental_group(c, "d4", &ship, kernel);
        step_group(c, "d2", &vdp, &[0.5], kernel);
        step_group(c, "d4", &ship, &[5.0, 0.3], kernel);
        step_group_with(c, "d2", &vdp, &[0.5], kernel, true);
        step_group_with(c, "d4", &ship, &[5.0, 0.3], kernel, true);
    }
}

criterion_group!(chain, benches);
criterion_main!(chain);
