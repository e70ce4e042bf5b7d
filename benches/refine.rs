//! Criterion benchmarks of the refine stage's work on the default scenario
//! (the ship, `configs/default.toml`, moving frame): one chain version of
//! n states — the points drawn around the belief, the batch chain (Alg. 2.1)
//! built for the framed drift, δ fitted, P^δ built and the snapshot written
//! — reported per state (criterion's throughput: multiply the time per
//! element by 1000 for the figure per 1000 states).
//!
//! Two forms per size, in the same run: `refine/version` builds the
//! version in one go (the baseline: what refine did before its rounds were
//! bounded), `refine/version_sliced` in slices of 5 ms (the stage's
//! `work_ms`), a deadline read between units of work — the cost of
//! slicing is the difference.
//!
//! `cargo bench --bench refine` (BENCH_CPU=1 measures the thread's CPU
//! time instead of wall time, the one-core figure on a shared machine).

use std::path::Path;
use std::time::{Duration, Instant};

use beliefbus::config::{load, PipelineConfig};
use beliefbus::stage::refine::Refiner;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

/// The default scenario with `n` states per version.
fn config(n: usize) -> PipelineConfig {
    load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/default.toml"),
        &[
            format!("refine.max_states={n}"),
            format!("refine.initial_states={}", n.min(500)),
        ],
    )
    .expect("default config")
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
            Duration::from_nanos(beliefbus::rt::clock::thread_cpu_ns())
        } else {
            Instant::now().duration_since(*EPOCH.get_or_init(Instant::now))
        }
    }
}

static EPOCH: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();

/// One version built and written (the refine stage's work per version).
fn version(r: &mut Refiner, out: &mut Vec<u64>) {
    r.work(Duration::from_secs(1)).expect("build");
    let len = r.snapshot_words();
    out.resize(len, 0);
    std::hint::black_box(r.write_snapshot(out, 1).expect("write"));
}

/// The same version in slices of `slice` each (the stage's rounds).
fn version_sliced(r: &mut Refiner, out: &mut Vec<u64>, slice: Duration) {
    loop {
        let end = Instant::now() + slice;
        if r.work_until(|| Instant::now() < end).expect("build") {
            break;
        }
    }
    let len = r.snapshot_words();
    out.resize(len, 0);
    std::hint::black_box(r.write_snapshot(out, 1).expect("write"));
}

fn refine_version(c: &mut Criterion) {
    for sliced in [false, true] {
        refine_group(c, sliced);
    }
}

fn refine_group(c: &mut Criterion, sliced: bool) {
    let name = if sliced {
        "refine/version_sliced"
    } else {
        "refine/version"
    };
    let mut g = c.benchmark_group(name);
    g.sample_size(10).measurement_time(Duration::from_secs(5));
    let clock = Clock::from_env();
    for n in [1000usize, 2000, 4000] {
        let cfg = config(n);
        let mut r = Refiner::new(&cfg, 1).expect("refiner");
        let mut out = Vec::new();
        // The first version is the crude one of initial_states.
        version(&mut r, &mut out);
        g.throughput(Throughput::Elements(n as u64));
        g.bench_function(BenchmarkId::from_parameter(n), |b| {
            b.iter_custom(|iters| {
                let t0 = clock.now();
                for _ in 0..iters {
                    if sliced {
                        version_sliced(&mut r, &mut out, Duration::from_millis(5));
                    } else {
                        version(&mut r, &mut out);
                    }
                }
                clock.now() - t0
            })
        });
    }
    g.finish();
}

criterion_group!(refine, refine_version);
criterion_main!(refine);
