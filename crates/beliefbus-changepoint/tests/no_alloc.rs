//! Constant memory per step: after construction, 10⁶ steps of the
//! mean-shift RBPF (with rejuvenation, each scheme, Beta prior) and 10⁵
//! steps of the ARX filter through the per-step interface perform no heap
//! allocation at all, so memory cannot grow with t. Counted by a global
//! allocator wrapper, per thread (the test harness's own threads do not
//! disturb the count).

use beliefbus_changepoint::arx::online::ArxOnline;
use beliefbus_changepoint::arx::rbpf::ArxRbpfConfig;
use beliefbus_changepoint::arx::ThetaPrior;
use beliefbus_changepoint::meanshift::rbpf::{MeanShiftRbpf, RbpfConfig, RhoPrior};
use beliefbus_changepoint::meanshift::MeanShiftModel;
use beliefbus_changepoint::resample::Scheme;
use beliefbus_changepoint::rng;
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocs() -> u64 {
    ALLOCS.with(|c| c.get())
}

#[test]
fn filters_do_not_allocate_per_step() {
    // The counter sees allocations (else the zeros below would prove nothing).
    let b = allocs();
    let v = std::hint::black_box(vec![1u8; 10]);
    assert!(allocs() > b);
    drop(v);
    let model = MeanShiftModel::new(1.0, 0.001).unwrap();
    let mut data = rng::stream(1, 0);
    let configs = [
        RbpfConfig::default(),
        RbpfConfig {
            scheme: Scheme::Multinomial,
            tilt: Some(0.005),
            ..RbpfConfig::default()
        },
        RbpfConfig {
            scheme: Scheme::Residual,
            cv2_bound: 0.0,
            ..RbpfConfig::default()
        },
        RbpfConfig {
            rho_prior: RhoPrior::Beta {
                alpha: 1.0,
                beta: 999.0,
            },
            ..RbpfConfig::default()
        },
    ];
    for (c, cfg) in configs.iter().enumerate() {
        let steps = if c == 0 { 1_000_000 } else { 100_000 };
        let mut f = MeanShiftRbpf::new(model, *cfg, rng::stream(2, c as u64)).unwrap();
        let mut level = 0.0;
        let before = allocs();
        for _ in 0..steps {
            if data.random::<f64>() < 0.001 {
                level = StandardNormal.sample(&mut data);
            }
            let z: f64 = StandardNormal.sample(&mut data);
            f.step(level + z).unwrap();
        }
        assert_eq!(
            allocs() - before,
            0,
            "config {c}: allocations during {steps} steps"
        );
        assert!(f.resamplings() > 0);
    }

    let mut arx = ArxOnline::<3>::new(
        2,
        ThetaPrior::standard(),
        ArxRbpfConfig::default(),
        rng::stream(3, 0),
    )
    .unwrap();
    let (mut y1, mut y2, mut u1) = (0.0, 0.0, 0.0);
    let before = allocs();
    for _ in 0..100_000 {
        let e: f64 = StandardNormal.sample(&mut data);
        let y = -0.5 * y1 + 0.2 * y2 + 0.8 * u1 + e;
        arx.observe(y).unwrap();
        let _ = arx.predictive();
        let _ = arx.prob_change_since(10);
        let u: f64 = StandardNormal.sample(&mut data);
        arx.apply(u).unwrap();
        (y2, y1, u1) = (y1, y, u);
    }
    assert_eq!(allocs() - before, 0, "ARX: allocations during 1e5 steps");
}
