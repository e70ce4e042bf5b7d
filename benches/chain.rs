//! Criterion benchmarks of the Markov-chain library: batch
//! construction (Alg. 2.1), incremental construction with reconnection
//! (Alg. 2.3) measured per added state at a given chain size, and one chain
//! filter step (predict over Δ = 0.01 s + update). k-NN Near rule,
//! k = ⌈1.5 log n⌉ (floored at 1 + d + d(d+1)/2 + 1); the mean out-degree of
//! each chain is printed to stderr. d = 2: Van der Pol; d = 4: the ship.
//!
//! `filter_step_sim` runs the filter on the observations of a simulated
//! trajectory (prior and x(0) as in the ship / Van der Pol experiments,
//! observations every 0.01 s; the filter is reset to the prior when the
//! trajectory ends), and prints per-step percentiles and the mean support.
//!
//! `cargo bench --bench chain` (BENCH_FULL=1 adds n = 10⁵ to every group;
//! BENCH_CPU=1 measures the thread's CPU time instead of wall time, the
//! one-core figure on a machine shared with other jobs).

use std::time::{Duration, Instant};

use beliefbus::belief::Gaussian;
use beliefbus::chain::{Chain, ChainConfig, KernelKind, Sampler};
use beliefbus::experiments::chain_util::{draw_from, simulate};
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

/// Whether criterion's name filter (the first free argument, a regex, or
/// an exact name with `--exact`) selects some benchmark of `group`: groups
/// it does not select skip their set-up (chains of up to 10⁵ states and
/// simulated trajectories), as criterion would skip their measurement.
fn selected(group: &str) -> bool {
    static FILTER: std::sync::OnceLock<Option<(regex::Regex, bool)>> = std::sync::OnceLock::new();
    let filter = FILTER.get_or_init(|| {
        let args: Vec<String> = std::env::args().skip(1).collect();
        let exact = args.iter().any(|a| a == "--exact");
        let free = args.iter().find(|a| !a.starts_with('-'))?;
        let re = if exact {
            format!("^{}$", regex::escape(free))
        } else {
            free.clone()
        };
        Some((regex::Regex::new(&re).ok()?, exact))
    });
    let Some((re, _)) = filter else {
        return true;
    };
    sizes().iter().any(|n| re.is_match(&format!("{group}/{n}")))
}

/// Thread CPU time (CLOCK_THREAD_CPUTIME_ID).
fn cpu_now() -> Duration {
    Duration::from_nanos(beliefbus::rt::clock::thread_cpu_ns())
}

/// A clock: wall time, or thread CPU time with BENCH_CPU=1.
#[derive(Clone, Copy)]
struct Clock(bool);

impl Clock {
    fn from_env() -> Self {
        Clock(std::env::var("BENCH_CPU").is_ok())
    }
    fn now(self) -> Duration {
        if self.0 {
            cpu_now()
        } else {
            Instant::now().duration_since(*EPOCH.get_or_init(Instant::now))
        }
    }
}

static EPOCH: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();

fn cfg(d: usize, kernel: KernelKind) -> ChainConfig {
    match kernel {
        KernelKind::Gaussian => ChainConfig::gaussian(d),
        KernelKind::MomentMatched => ChainConfig::moment_matched(d),
    }
}

fn batch_group<M: SdeModel + Clone>(c: &mut Criterion, name: &str, model: &M, kernel: KernelKind) {
    let d = model.dims().state;
    let group = format!("batch/{name}/{kernel:?}");
    if !selected(&group) {
        return;
    }
    let mut g = c.benchmark_group(group);
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    for n in sizes() {
        let pts = Sampler::Uniform.sample_many(model.bounds(), n, &mut stream(1, n as u64));
        let ch = Chain::batch(model, cfg(d, kernel), &pts).unwrap();
        eprintln!(
            "batch/{name}/{kernel:?} n={n}: mean out-degree {:.2}",
            ch.mean_out_degree()
        );
        g.throughput(Throughput::Elements(n as u64));
        let clock = Clock::from_env();
        g.bench_with_input(BenchmarkId::from_parameter(n), &pts, |b, pts| {
            b.iter_custom(|iters| {
                let t0 = clock.now();
                for _ in 0..iters {
                    std::hint::black_box(Chain::batch(model, cfg(d, kernel), pts).unwrap());
                }
                clock.now() - t0
            })
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
    let group = format!("incremental/{name}/{kernel:?}");
    if !selected(&group) {
        return;
    }
    let mut g = c.benchmark_group(group);
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    g.throughput(Throughput::Elements(add as u64));
    for n in sizes() {
        let pts = Sampler::Uniform.sample_many(model.bounds(), n, &mut stream(2, n as u64));
        let base = Chain::batch(model, cfg(d, kernel), &pts).unwrap();
        let new = Sampler::Uniform.sample_many(model.bounds(), add, &mut stream(3, n as u64));
        let clock = Clock::from_env();
        {
            let mut ch = base.clone();
            let t0 = clock.now();
            ch.reserve(add);
            let prep = clock.now() - t0;
            let mut rec = Vec::new();
            let mut touched = 0usize;
            let before = ch.stats().rows_computed;
            for x in new.chunks_exact(d) {
                ch.add_state(model, x, &mut rec).unwrap();
                touched += rec.len();
            }
            let rows = ch.stats().rows_computed - before;
            eprintln!(
                "incremental/{name}/{kernel:?} n={n}: mean out-degree {:.2}, k = {}, per added state {:.1} rows reconnected of which {:.1} recomputed; reserve (builds the reverse-query tree; once per chain, not timed) {:.1} ms",
                ch.mean_out_degree(),
                ch.knn_k(ch.len()),
                touched as f64 / add as f64,
                rows as f64 / add as f64,
                prep.as_secs_f64() * 1e3
            );
        }
        g.bench_function(BenchmarkId::from_parameter(n), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                let mut rec = Vec::with_capacity(64);
                for _ in 0..iters {
                    let mut ch = base.clone();
                    ch.reserve(add);
                    let t0 = clock.now();
                    for x in new.chunks_exact(d) {
                        ch.add_state(model, x, &mut rec).unwrap();
                    }
                    total += clock.now() - t0;
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
/// the default flush (sparse support), as in the filtering experiments.
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
    let group = format!("{tag}/{name}/{kernel:?}");
    if !selected(&group) {
        return;
    }
    let mut g = c.benchmark_group(group);
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

/// One filter step (predict 0.01 s + update) on the observations of a
/// simulated trajectory from `prior`; thesis chain (`advected` false) or
/// advected chain, the filter's default flush (at most `FLUSH_MASS` of the
/// posterior mass discarded per update).
fn sim_group<M: SdeModel + Clone>(
    c: &mut Criterion,
    name: &str,
    model: &M,
    prior: &Gaussian,
    kernel: KernelKind,
    advected: bool,
) {
    let d = model.dims().state;
    let m = model.dims().obs;
    let u = vec![0.0; model.dims().control];
    let dt = 0.01;
    let steps = 500;
    let tag = if advected { "advected" } else { "thesis" };
    let group = format!("filter_step_sim/{tag}/{name}/{kernel:?}");
    if !selected(&group) {
        return;
    }
    let mut rng = stream(5, 0);
    let x0 = draw_from(model, prior, &mut rng);
    let rec = simulate(model, &x0, dt, steps, 1e-3, &mut rng);
    let clock = Clock::from_env();
    let mut g = c.benchmark_group(group);
    g.sample_size(20).measurement_time(Duration::from_secs(3));
    for n in sizes() {
        let pts = Sampler::Uniform.sample_many(model.bounds(), n, &mut stream(4, n as u64));
        let mut cf = cfg(d, kernel);
        if advected {
            cf.step = Some(dt);
        }
        let ch = Chain::batch(model, cf, &pts).unwrap();
        let deg = ch.mean_out_degree();
        let mut f = ChainFilter::new(model.clone(), ch, dt).unwrap();
        let mut k = 0usize;
        let mut first = true;
        g.bench_function(BenchmarkId::from_parameter(n), |b| {
            if first {
                // Per-step percentiles and support over the trajectory (at
                // most two passes or 20 s).
                first = false;
                let mut times = Vec::with_capacity(2 * steps);
                let mut support = 0usize;
                let mut max_dropped = 0.0f64;
                let dropped0 = f.discarded_total();
                let start = Instant::now();
                'pass: for _ in 0..2 {
                    f.reset(0.0, prior);
                    for (k, &t) in rec.times.iter().enumerate() {
                        let t0 = clock.now();
                        f.predict(t, &u).unwrap();
                        let _ = f.update(&Measurement::full(&rec.ys[k * m..(k + 1) * m]));
                        times.push((clock.now() - t0).as_secs_f64() * 1e6);
                        support += f.support();
                        max_dropped = max_dropped.max(f.last_discarded());
                        if start.elapsed() > Duration::from_secs(20) {
                            break 'pass;
                        }
                    }
                }
                times.sort_by(f64::total_cmp);
                let q = |p: f64| times[((times.len() - 1) as f64 * p).round() as usize];
                eprintln!(
                    "filter_step_sim/{tag}/{name}/{kernel:?} n={n}: out-degree {deg:.2}, {} substeps per step, mean support {:.0}, flush {:?}: mass dropped per update max {:.1e} mean {:.1e}, {} steps: p50 {:.1} us, p90 {:.1} us, p99 {:.1} us",
                    (dt / f.delta()).round(),
                    support as f64 / times.len() as f64,
                    f.flush(),
                    max_dropped,
                    (f.discarded_total() - dropped0) / times.len() as f64,
                    times.len(),
                    q(0.5),
                    q(0.9),
                    q(0.99)
                );
                f.reset(0.0, prior);
            }
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    if k == rec.times.len() {
                        k = 0;
                        f.reset(0.0, prior);
                    }
                    let t0 = clock.now();
                    f.predict(rec.times[k], &u).unwrap();
                    let _ = f.update(&Measurement::full(&rec.ys[k * m..(k + 1) * m]));
                    total += clock.now() - t0;
                    k += 1;
                }
                total
            })
        });
    }
    g.finish();
}

/// One filter step (predict 0.01 s + update) in the `vanderpol`
/// experiment's setting: Van der Pol (μ = 2, e₁ = e₂ = σ = 0.1), states
/// placed as there (`predictive_even`: 3n predictive candidates thinned by
/// sample elimination), advected moment-matched chain with τ = 0.01,
/// k = ⌈1.5 log n⌉, flush 10⁻⁴, on a simulated 10 s record (the filter is
/// reset to the prior when it ends). `order`: the slots as placed, or
/// along the Hilbert curve (the experiment's default).
fn vdp_group(c: &mut Criterion, order: &str) {
    use beliefbus::chain::placement::{eliminate, predictive_points};
    use beliefbus::experiments::vanderpol::VDP_FLUSH_MASS;
    let group = format!("filter_step_vdp/{order}");
    let vdp_sizes = [2_000usize, 4_000, 8_000];
    let re_ok = {
        let args: Vec<String> = std::env::args().skip(1).collect();
        match args.iter().find(|a| !a.starts_with('-')) {
            None => true,
            Some(f) => regex::Regex::new(f)
                .map(|re| {
                    vdp_sizes
                        .iter()
                        .any(|n| re.is_match(&format!("{group}/{n}")))
                })
                .unwrap_or(true),
        }
    };
    if !re_ok {
        return;
    }
    let model = VanDerPol::new(VanDerPolParams::default()).unwrap();
    let prior = Gaussian::diagonal(&[0.5, 0.0], &[0.2, 0.2]);
    let dt = 0.01;
    let mut rng = stream(6, 0);
    let x0 = draw_from(&model, &prior, &mut rng);
    let rec = simulate(&model, &x0, dt, 1000, 1e-3, &mut rng);
    let clock = Clock::from_env();
    let mut g = c.benchmark_group(group.clone());
    g.sample_size(20).measurement_time(Duration::from_secs(3));
    for n in vdp_sizes {
        let mut rng = stream(7, n as u64);
        let cand = predictive_points(&model, &prior, 10.0, 3 * n, 0.1, dt, &mut rng).unwrap();
        let pts = eliminate(&cand, 2, n);
        let pts = order_points(order, pts);
        let mut cf = ChainConfig::moment_matched(2).with_step(dt);
        cf.near = beliefbus::chain::NearRule::Knn { c: 1.5 };
        let ch = Chain::batch(&model, cf, &pts).unwrap();
        let mut f = ChainFilter::new(model.clone(), ch, dt).unwrap();
        f.set_flush_mass(VDP_FLUSH_MASS);
        f.reset(0.0, &prior);
        let mut k = 0usize;
        g.bench_function(BenchmarkId::from_parameter(n), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    if k == rec.times.len() {
                        k = 0;
                        f.reset(0.0, &prior);
                    }
                    let t0 = clock.now();
                    f.predict(rec.times[k], &[]).unwrap();
                    let _ = f.update(&Measurement::full(&rec.ys[k..k + 1]));
                    std::hint::black_box(f.belief());
                    total += clock.now() - t0;
                    k += 1;
                }
                total
            })
        });
        eprintln!(
            "{group} n={n}: out-degree {:.2}, mean support {:.0}",
            f.chain().mean_out_degree(),
            f.mean_support()
        );
    }
    g.finish();
}

/// The placed points in the requested slot order: `hilbert` along the
/// Hilbert curve ([`beliefbus::chain::order`], as the experiment does),
/// else as placed.
fn order_points(order: &str, pts: Vec<f64>) -> Vec<f64> {
    if order == "hilbert" {
        beliefbus::chain::order::hilbert_sorted(&pts, 2)
    } else {
        pts
    }
}

fn benches(c: &mut Criterion) {
    let vdp = VanDerPol::new(VanDerPolParams::default()).unwrap();
    let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
    let ship_prior = Gaussian::diagonal(&[3.0, 2.0, 1.0, -0.5], &[0.3, 0.3, 0.2, 0.2]);
    let vdp_prior = Gaussian::diagonal(&[0.5, 0.0], &[0.2, 0.2]);
    for kernel in [KernelKind::Gaussian, KernelKind::MomentMatched] {
        for advected in [false, true] {
            sim_group(c, "d2", &vdp, &vdp_prior, kernel, advected);
            sim_group(c, "d4", &ship, &ship_prior, kernel, advected);
        }
        batch_group(c, "d2", &vdp, kernel);
        batch_group(c, "d4", &ship, kernel);
        incremental_group(c, "d2", &vdp, kernel);
        incremental_group(c, "d4", &ship, kernel);
        step_group(c, "d2", &vdp, &[0.5], kernel);
        step_group(c, "d4", &ship, &[5.0, 0.3], kernel);
        step_group_with(c, "d2", &vdp, &[0.5], kernel, true);
        step_group_with(c, "d4", &ship, &[5.0, 0.3], kernel, true);
    }
    vdp_group(c, "placed");
    vdp_group(c, "hilbert");
}

criterion_group!(chain, benches);
criterion_main!(chain);
