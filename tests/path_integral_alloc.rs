//! The path-integral controller's `compute` does not allocate: a counting
//! global allocator (this test binary only) sees zero allocations across
//! many controls after construction, for every mode.

use beliefbus::belief::Gaussian;
use beliefbus::control::cost::{DiscBarrier, TrackingCost};
use beliefbus::control::path_integral::{
    BeliefMode, GradientConfig, HorizonMode, PathIntegralConfig, PathIntegralController,
};
use beliefbus::control::Controller;
use beliefbus::model::ship::ShipParams;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;
static ALLOCS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    /// Count only this thread's allocations (the test harness allocates in
    /// its own threads meanwhile).
    static ACTIVE: Cell<bool> = const { Cell::new(false) };
}

fn count() {
    if ACTIVE.with(|a| a.get()) {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn compute_does_not_allocate() {
    let cost = TrackingCost::new(
        &[1.0, 1.0, 0.1, 0.1],
        &[10.0, 10.0, 1.0, 1.0],
        Some(DiscBarrier {
            axes: (0, 1),
            radius: 8.0,
            weight: 100.0,
        }),
    );
    let configs = [
        PathIntegralConfig::default(),
        PathIntegralConfig {
            gradient: GradientConfig::FiniteDifference,
            ..PathIntegralConfig::default()
        },
        PathIntegralConfig {
            belief: BeliefMode::Sampled,
            budget_us: 1.0, // forces the degradation ladder to move
            ..PathIntegralConfig::default()
        },
        PathIntegralConfig {
            horizon: HorizonMode::Shrinking,
            final_time: 1.5,
            ..PathIntegralConfig::default()
        },
    ];
    for cfg in configs {
        let mut c = PathIntegralController::ship(ShipParams::paper(0.01), cost, cfg).unwrap();
        c.set_goal(&[4.0, -3.0, 0.0, 0.0]);
        let mut b = Gaussian::diagonal(&[-3.0, 2.0, 0.5, 0.0], &[0.1; 4]);
        let mut u = [0.0; 2];
        c.compute(0.0, &b, &mut u).unwrap();
        let before = ALLOCS.load(Ordering::Relaxed);
        ACTIVE.with(|a| a.set(true));
        for k in 1..200 {
            b.mean[0] += 0.01;
            b.mean[1] = 8.5 * (k as f64 * 0.1).sin(); // cross the barrier at times
            c.compute(k as f64 * 0.01, &b, &mut u).unwrap();
        }
        c.set_goal(&[-4.0, 3.0, 0.0, 0.0]);
        c.compute(2.0, &b, &mut u).unwrap();
        ACTIVE.with(|a| a.set(false));
        let after = ALLOCS.load(Ordering::Relaxed);
        assert_eq!(
            after - before,
            0,
            "{} allocations in compute",
            after - before
        );
    }
}
