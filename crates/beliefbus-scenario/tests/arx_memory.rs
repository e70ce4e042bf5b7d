//! Memory of the live `rbpf-changepoint` backend over 10⁶ steps, driven
//! through the pipeline's `BayesFilter` interface by the scenario's plant
//! and controller: heap allocations after construction (counted per
//! thread by a global allocator wrapper) and the process's resident set at
//! 0, 10⁴, 10⁵ and 10⁶ steps, printed. Constant cost and memory per step
//! is the paper's argument for the filter (§2): the particles carry only
//! (C, μ_C, V_C).
//!
//! A measurement, not a timing: `cargo test -p beliefbus-scenario --release
//! --test arx_memory -- --ignored --nocapture`.

use beliefbus_core::belief::Gaussian;
use beliefbus_core::model::{Measurement, ObsMask};
use beliefbus_scenario::builtin::arx::{ADAPTIVE, RBPF, STATE};
use beliefbus_scenario::{BuildContext, ControlContext, FilterContext, Registry};
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

/// VmRSS in kB (Linux).
fn rss_kb() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

#[test]
#[ignore = "a measurement over 10^6 steps; run with --release --ignored --nocapture"]
fn the_live_filter_runs_a_million_steps_in_constant_memory() {
    let dt = 1e-3;
    let sys = Registry::builtin()
        .get("arx")
        .unwrap()
        .build(None, &BuildContext { sample_dt: dt })
        .unwrap();
    let mut plant = sys.plant(&sys.initial_state(), 1, dt).unwrap();
    let fctx = FilterContext {
        seed: 2,
        sample_dt: dt,
        start: Gaussian::zeros(STATE),
        resumed: false,
        t0: 0.0,
    };
    let mut f = sys.filter_backend(RBPF, &fctx).unwrap().unwrap();
    let cctx = ControlContext {
        seed: 3,
        sample_dt: dt,
    };
    let mut c = sys.controller(ADAPTIVE, &cctx).unwrap().unwrap();
    let (mut y, mut u) = ([0.0; 2], [0.0]);
    let mut marks = Vec::with_capacity(4);
    marks.push((0u64, rss_kb()));
    // Allocations of the measurement itself (reading /proc), left out.
    let mut measuring = 0;
    let before = allocs();
    let t0 = std::time::Instant::now();
    for k in 0..1_000_000u64 {
        plant.set_control(&u);
        plant.step();
        plant.measure(&mut y);
        f.predict((k + 1) as f64 * dt, &u).unwrap();
        f.update(&Measurement {
            y: &y,
            mask: ObsMask(0b11),
            std: None,
        })
        .unwrap();
        c.set_step(k);
        c.compute(0.0, &f.belief(), &mut u).unwrap();
        if matches!(k + 1, 10_000 | 100_000 | 1_000_000) {
            let a = allocs();
            let r = rss_kb();
            measuring += allocs() - a;
            marks.push((k + 1, r));
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    let n = allocs() - before - measuring;
    for (k, r) in &marks {
        println!("steps {k:>8}: VmRSS {r:?} kB");
    }
    println!(
        "heap allocations during 10^6 steps (plant + filter + controller): {n}; \
         {:.2} µs per step (wall, shared machine)",
        secs * 1e6 / 1_000_000.0
    );
    assert_eq!(n, 0, "allocations per step");
}
