//! Keep the pipeline's cores out of idle: one thread per core, pinned there
//! at `SCHED_IDLE` (the lowest class), spinning until dropped, and yielding
//! the core every [`YIELD_EVERY`].
//!
//! Why the yield: the idle class is not "only when nothing else runs". A
//! thread that wakes preempts the spinner at once, but a thread that is
//! merely runnable — refine at nice 19, in the middle of a round — competes
//! with it by weight (3 against 15: the spinner is owed a sixth of the
//! core), and once the scheduler picks the spinner it keeps the core until
//! the next tick (4 ms at HZ = 250). Refine's 3 ms rounds then took up to
//! 10 ms of wall time (p99 6.2–6.8 ms in the default run, against 3.2–3.4
//! ms with no spinner); yielding every 50 µs hands the core back within
//! 50 µs (p99 3.4–3.6 ms, docs/performance.md).
//!
//! Why: on a virtual machine an idle vCPU halts, and the host then lets the
//! physical core sleep and clock down; the next message's wake-up pays the
//! halt exit, and the work after it runs at the lowered clock. A loop that
//! computes 100 µs per millisecond leaves its cores idle 90 % of the time,
//! so every stage of it pays this. A spinner in the idle class keeps the
//! core running without taking time from anything that wants it — the
//! user-space equivalent of the kernel's `idle=poll`, and the same trade:
//! the cores show 100 % busy and draw full power for as long as the run
//! lasts. Off by default; latency-critical configurations turn it on.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long a spinner keeps its core before it yields it to any runnable
/// thread (a `sched_yield` costs about a microsecond).
pub const YIELD_EVERY: Duration = Duration::from_micros(50);

/// Spinners on a set of cores; dropping the guard stops and joins them.
pub struct KeepWarm {
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    warnings: Vec<String>,
}

impl KeepWarm {
    /// Start one idle-class spinner on each core of `cores` (duplicates are
    /// started once). A core that cannot be pinned or a class that cannot
    /// be set gives a warning (see [`Self::warnings`]), not an error: the
    /// pipeline runs the same without it, only slower to wake.
    pub fn start(cores: &[usize]) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let mut unique: Vec<usize> = cores.to_vec();
        unique.sort_unstable();
        unique.dedup();
        let mut threads = Vec::with_capacity(unique.len());
        let mut warnings = Vec::new();
        for core in unique {
            let s = Arc::clone(&stop);
            let (tx, rx) = std::sync::mpsc::channel();
            let spawned = std::thread::Builder::new()
                .name(format!("keep-warm-{core}"))
                .spawn(move || {
                    let setup = crate::sched::pin_to_core(core).and_then(|()| set_idle_class());
                    let ok = setup.is_ok();
                    let _ = tx.send(setup);
                    if !ok {
                        return;
                    }
                    let mut next = Instant::now() + YIELD_EVERY;
                    while !s.load(Ordering::Relaxed) {
                        std::hint::spin_loop();
                        let now = Instant::now();
                        if now >= next {
                            // SAFETY: sched_yield takes no arguments.
                            unsafe { libc::sched_yield() };
                            next = now + YIELD_EVERY;
                        }
                    }
                });
            match spawned {
                Ok(h) => {
                    if let Ok(Err(e)) = rx.recv() {
                        warnings.push(format!("keep-warm on core {core}: {e}"));
                    }
                    threads.push(h);
                }
                Err(e) => warnings.push(format!("keep-warm on core {core}: {e}")),
            }
        }
        Self {
            stop,
            threads,
            warnings,
        }
    }

    /// What could not be set up (empty when every core is kept warm).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }
}

impl Drop for KeepWarm {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for h in self.threads.drain(..) {
            let _ = h.join();
        }
    }
}

/// Switch the calling thread to `SCHED_IDLE`.
fn set_idle_class() -> Result<(), String> {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: sched_setscheduler on the calling thread with a valid param.
    let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) };
    if r == 0 {
        Ok(())
    } else {
        Err(format!("SCHED_IDLE: {}", std::io::Error::last_os_error()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// CPU time of this process's thread named `name` (ns), from
    /// /proc/self/task/*/schedstat.
    fn thread_cpu_ns(name: &str) -> u64 {
        let task = std::fs::read_dir("/proc/self/task")
            .unwrap()
            .filter_map(|e| e.ok())
            .find(|e| {
                std::fs::read_to_string(e.path().join("comm"))
                    .map(|c| c.trim() == name)
                    .unwrap_or(false)
            })
            .expect("the thread");
        let s = std::fs::read_to_string(task.path().join("schedstat")).unwrap();
        s.split_whitespace().next().unwrap().parse().unwrap()
    }

    /// A runnable thread at nice 19 on the spinner's core gets the core:
    /// the spinner takes under 5 % of it while that thread computes. By
    /// weight alone (idle class 3, nice 19 15) the scheduler would owe the
    /// spinner a sixth, in slices up to a tick long; yielding every 50 µs
    /// gives it back. Other load on the core only lowers the spinner's share.
    #[test]
    fn a_runnable_nice_19_thread_takes_the_core_from_the_spinner() {
        let core = 1.min(core_affinity::get_core_ids().map_or(1, |c| c.len()) - 1);
        let w = KeepWarm::start(&[core]);
        assert!(w.warnings().is_empty(), "{:?}", w.warnings());
        let name = format!("keep-warm-{core}");
        // The busy thread computes until the measurement is over, however
        // late a loaded machine wakes the measuring thread: a window that
        // outlasted it would count the spinner's time on an idle core.
        let running = Arc::new(AtomicBool::new(false));
        let done = Arc::new(AtomicBool::new(false));
        let (r, d) = (running.clone(), done.clone());
        let busy = std::thread::spawn(move || {
            crate::sched::pin_to_core(core).unwrap();
            // SAFETY: setpriority on the calling thread (its tid).
            let tid = unsafe { libc::gettid() } as libc::id_t;
            assert_eq!(unsafe { libc::setpriority(libc::PRIO_PROCESS, tid, 19) }, 0);
            r.store(true, Ordering::Relaxed);
            let mut x = 0u64;
            while !d.load(Ordering::Relaxed) {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
            }
            x
        });
        while !running.load(Ordering::Relaxed) {
            std::thread::sleep(Duration::from_millis(1));
        }
        std::thread::sleep(Duration::from_millis(50));
        let (c0, t0) = (thread_cpu_ns(&name), Instant::now());
        std::thread::sleep(Duration::from_millis(300));
        let (c1, t1) = (thread_cpu_ns(&name), Instant::now());
        done.store(true, Ordering::Relaxed);
        busy.join().unwrap();
        let share = (c1 - c0) as f64 / (t1 - t0).as_nanos() as f64;
        assert!(
            share < 0.05,
            "the spinner took {:.1} % of the core",
            100.0 * share
        );
    }

    /// The spinners run in the idle class on their core and stop on drop.
    #[test]
    fn spinners_run_idle_class_and_stop_on_drop() {
        let w = KeepWarm::start(&[0, 0]);
        assert!(w.warnings().is_empty(), "{:?}", w.warnings());
        assert_eq!(w.threads.len(), 1, "one spinner per distinct core");
        // The spinner's scheduling class, read from /proc.
        let tid = std::fs::read_dir("/proc/self/task")
            .unwrap()
            .filter_map(|e| e.ok())
            .find(|e| {
                std::fs::read_to_string(e.path().join("comm"))
                    .map(|c| c.trim() == "keep-warm-0")
                    .unwrap_or(false)
            })
            .map(|e| e.path())
            .expect("the spinner thread");
        let stat = std::fs::read_to_string(tid.join("stat")).unwrap();
        // Field 41 (policy) counted after the parenthesised comm.
        let after = &stat[stat.rfind(')').unwrap() + 2..];
        let policy: i32 = after.split_whitespace().nth(38).unwrap().parse().unwrap();
        assert_eq!(policy, libc::SCHED_IDLE);
        drop(w);
        assert!(std::fs::read_dir("/proc/self/task")
            .unwrap()
            .filter_map(|e| e.ok())
            .all(|e| std::fs::read_to_string(e.path().join("comm"))
                .map(|c| c.trim() != "keep-warm-0")
                .unwrap_or(true)));
    }
}
