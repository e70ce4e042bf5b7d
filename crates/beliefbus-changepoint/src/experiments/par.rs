//! Monte-Carlo repetitions in parallel with `std::thread::scope`: workers
//! take run indices from a shared counter, results come back in run order,
//! so the output does not depend on the number of threads.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// `f(i)` for i in 0..runs on `threads` workers, in index order.
pub fn par_map<T: Send, F: Fn(usize) -> T + Sync>(runs: usize, threads: usize, f: F) -> Vec<T> {
    let next = AtomicUsize::new(0);
    let out: Mutex<Vec<Option<T>>> = Mutex::new((0..runs).map(|_| None).collect());
    std::thread::scope(|sc| {
        for _ in 0..threads.clamp(1, runs.max(1)) {
            sc.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= runs {
                    break;
                }
                let r = f(i);
                if let Ok(mut o) = out.lock() {
                    o[i] = Some(r);
                }
            });
        }
    });
    out.into_inner()
        .unwrap_or_default()
        .into_iter()
        .flatten()
        .collect()
}

/// Default worker count: the machine's parallelism, at most 2 (the shared
/// machine's budget; override with the `threads` parameter).
pub fn default_threads() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get().min(2))
        .unwrap_or(1)
}
