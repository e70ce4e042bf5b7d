//! One filter step on the change-point ARX model (k = 2, h = 1, ρ = 0.001,
//! θ ~ N(0, I) in the AR stability region after a change): the fast RBPF
//! (Kalman statistics per particle, cv² ≤ 1 rejuvenation) against the
//! bootstrap PF on θ_t (resampling every step) at equal M, on the same
//! pre-simulated sequence with i.i.d. N(0, 1) inputs.
//!
//! `cargo bench -p beliefbus-changepoint --bench arx_step`

use beliefbus_changepoint::arx::bootstrap::ArxBootstrap;
use beliefbus_changepoint::arx::linalg::Vector;
use beliefbus_changepoint::arx::plant::{ArxPlant, ThetaRegion};
use beliefbus_changepoint::arx::rbpf::{ArxRbpf, ArxRbpfConfig};
use beliefbus_changepoint::arx::ThetaPrior;
use beliefbus_changepoint::resample::Scheme;
use beliefbus_changepoint::rng::stream;
use criterion::{BenchmarkId, Criterion};
use rand_distr::{Distribution, StandardNormal};
use std::hint::black_box;

const N: usize = 20_000;
const RHO: f64 = 0.001;

fn data() -> Vec<(f64, Vector<3>)> {
    let mut rng = stream(11, 1);
    let mut plant = ArxPlant::<3>::new(
        2,
        RHO,
        ThetaPrior::standard(),
        ThetaRegion::StableAr,
        &mut rng,
    )
    .expect("plant");
    (0..N)
        .map(|_| {
            let (y, phi, _, _) = plant.observe(&mut rng);
            let u: f64 = StandardNormal.sample(&mut rng);
            plant.apply(y, u);
            (y, phi)
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let d = data();
    let mut g = c.benchmark_group("arx_step");
    for m in [50usize, 500] {
        let cfg = ArxRbpfConfig {
            particles: m,
            rho: RHO,
            ..ArxRbpfConfig::default()
        };
        let mut rbpf = ArxRbpf::new(ThetaPrior::standard(), cfg, stream(12, 1)).expect("rbpf");
        let mut i = 0;
        g.bench_with_input(BenchmarkId::new("rbpf", m), &m, |b, _| {
            b.iter(|| {
                let (y, phi) = &d[i % N];
                i += 1;
                black_box(rbpf.step(*y, phi).expect("step"))
            })
        });
        let mut boot = ArxBootstrap::new(
            ThetaPrior::standard(),
            RHO,
            m,
            Scheme::Systematic,
            stream(12, 2),
        )
        .expect("bootstrap");
        let mut i = 0;
        g.bench_with_input(BenchmarkId::new("bootstrap", m), &m, |b, _| {
            b.iter(|| {
                let (y, phi) = &d[i % N];
                i += 1;
                black_box(boot.step(*y, phi).expect("step"))
            })
        });
    }
    g.finish();
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    bench(&mut c);
    c.final_summary();
}
