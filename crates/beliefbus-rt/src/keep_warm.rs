//! Keep the pipeline's cores out of idle: one thread per core, pinned there
//! at `SCHED_IDLE` (the lowest class: any other runnable thread preempts it
//! at once), spinning until dropped.
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
                    while !s.load(Ordering::Relaxed) {
                        std::hint::spin_loop();
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
