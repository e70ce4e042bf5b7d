//! Background load for jitter measurements: busy CPU threads and
//! memory-bandwidth threads (each streams copies between two buffers far
//! larger than the last-level cache), at normal priority and unpinned, so
//! they compete with the measured threads the way other work would.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// Bytes each memory-bandwidth thread streams through (two halves).
pub const MEM_BYTES: usize = 64 << 20;

/// Running stress threads; stopped and joined on [`Stress::stop`] or drop.
#[derive(Debug)]
pub struct Stress {
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<u64>>,
    cpu: usize,
    mem: usize,
}

fn cpu_burn(stop: &AtomicBool) -> u64 {
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let mut n = 0u64;
    while !stop.load(Ordering::Relaxed) {
        for _ in 0..4096 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
        }
        n += 1;
        std::hint::black_box(x);
    }
    n
}

fn mem_stream(stop: &AtomicBool, bytes: usize) -> u64 {
    let half = (bytes / 16).max(1);
    let mut a = vec![1u64; half];
    let mut b = vec![2u64; half];
    let mut n = 0u64;
    while !stop.load(Ordering::Relaxed) {
        b.copy_from_slice(&a);
        std::hint::black_box(&b);
        a.copy_from_slice(&b);
        std::hint::black_box(&a);
        n += 1;
    }
    n
}

impl Stress {
    /// Start `cpu` busy threads and `mem` memory-bandwidth threads.
    pub fn start(cpu: usize, mem: usize) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let mut threads = Vec::with_capacity(cpu + mem);
        for i in 0..cpu + mem {
            let s = stop.clone();
            let is_cpu = i < cpu;
            let name = if is_cpu {
                format!("stress-cpu-{i}")
            } else {
                format!("stress-mem-{}", i - cpu)
            };
            if let Ok(h) = std::thread::Builder::new().name(name).spawn(move || {
                if is_cpu {
                    cpu_burn(&s)
                } else {
                    mem_stream(&s, MEM_BYTES)
                }
            }) {
                threads.push(h);
            }
        }
        Self {
            stop,
            threads,
            cpu,
            mem,
        }
    }

    /// No stress at all.
    pub fn none() -> Self {
        Self::start(0, 0)
    }

    /// Threads running (CPU, memory).
    pub fn threads(&self) -> (usize, usize) {
        (self.cpu, self.mem)
    }

    /// Stop and join; returns the work done per thread (loop counts).
    pub fn stop(mut self) -> Vec<u64> {
        self.halt()
    }

    fn halt(&mut self) -> Vec<u64> {
        self.stop.store(true, Ordering::Relaxed);
        self.threads
            .drain(..)
            .map(|h| h.join().unwrap_or(0))
            .collect()
    }
}

impl Drop for Stress {
    fn drop(&mut self) {
        self.halt();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stress_threads_do_work_and_stop() {
        let s = Stress::start(1, 1);
        assert_eq!(s.threads(), (1, 1));
        std::thread::sleep(std::time::Duration::from_millis(300));
        let work = s.stop();
        assert_eq!(work.len(), 2);
        assert!(work.iter().all(|&w| w > 0), "{work:?}");
    }
}
