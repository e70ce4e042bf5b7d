//! Core affinity, scheduling priority and memory locking of the calling
//! process (DESIGN.md "Real time on 2 cores"). Each setting that the system
//! refuses yields one warning line and a fallback — never an abort:
//! - affinity via `core_affinity` (the stage processes are single-threaded,
//!   so pinning the thread pins the process);
//! - SCHED_FIFO at the configured priority, else SCHED_OTHER at the
//!   configured nice value (else unchanged);
//! - `mlockall(MCL_CURRENT | MCL_FUTURE)`, else page faults stay possible.

use serde::{Deserialize, Serialize};

/// Real-time settings of one process.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RtSettings {
    /// Core to pin to (None: let the scheduler place it).
    #[serde(default)]
    pub core: Option<usize>,
    /// SCHED_FIFO priority 1–99 (None or 0: SCHED_OTHER).
    #[serde(default)]
    pub fifo_priority: Option<u8>,
    /// Nice value −20…19 under SCHED_OTHER (also the fallback when
    /// SCHED_FIFO is refused).
    #[serde(default)]
    pub nice: i32,
    /// Lock all current and future memory (no page faults on the hot path).
    #[serde(default)]
    pub mlock: bool,
}

/// What was actually applied.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RtApplied {
    /// Core pinned to.
    pub core: Option<usize>,
    /// Running under SCHED_FIFO.
    pub fifo: bool,
    /// Nice value in effect (SCHED_OTHER).
    pub nice: Option<i32>,
    /// mlockall succeeded.
    pub mlocked: bool,
    /// One line per refused setting, saying what fallback is in effect.
    pub warnings: Vec<String>,
}

impl RtSettings {
    /// Check ranges; the message names the offending field.
    pub fn validate(&self) -> Result<(), String> {
        if let Some(p) = self.fifo_priority {
            if p > 99 {
                return Err(format!("fifo_priority must be 0..=99, got {p}"));
            }
        }
        if !(-20..=19).contains(&self.nice) {
            return Err(format!("nice must be -20..=19, got {}", self.nice));
        }
        Ok(())
    }
}

/// Number of cores this process may run on.
pub fn available_cores() -> usize {
    core_affinity::get_core_ids().map(|v| v.len()).unwrap_or(1)
}

fn os_err() -> String {
    std::io::Error::last_os_error().to_string()
}

/// Pin the calling thread to `core`.
pub fn pin_to_core(core: usize) -> Result<(), String> {
    let ids = core_affinity::get_core_ids().ok_or("cannot list cores")?;
    let id = ids
        .into_iter()
        .find(|c| c.id == core)
        .ok_or(format!("core {core} is not available to this process"))?;
    if core_affinity::set_for_current(id) {
        Ok(())
    } else {
        Err(format!("sched_setaffinity failed: {}", os_err()))
    }
}

/// Switch the calling process to SCHED_FIFO at `prio`.
pub fn set_fifo(prio: u8) -> Result<(), String> {
    let param = libc::sched_param {
        sched_priority: prio as libc::c_int,
    };
    // SAFETY: sched_setscheduler on ourselves with a valid param.
    let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if r == 0 {
        Ok(())
    } else {
        Err(os_err())
    }
}

/// Set the nice value of the calling process.
pub fn set_nice(nice: i32) -> Result<(), String> {
    // SAFETY: setpriority on ourselves.
    let r = unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, nice) };
    if r == 0 {
        Ok(())
    } else {
        Err(os_err())
    }
}

/// Lock current and future memory.
pub fn lock_memory() -> Result<(), String> {
    // SAFETY: mlockall has no memory-safety preconditions.
    let r = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if r == 0 {
        Ok(())
    } else {
        Err(os_err())
    }
}

/// Apply `s` to the calling process; `who` names it in warnings.
pub fn apply(who: &str, s: &RtSettings) -> RtApplied {
    let mut a = RtApplied::default();
    if let Some(core) = s.core {
        match pin_to_core(core) {
            Ok(()) => a.core = Some(core),
            Err(e) => a.warnings.push(format!(
                "{who}: cannot pin to core {core} ({e}); running unpinned"
            )),
        }
    }
    let fifo = s.fifo_priority.filter(|&p| p > 0);
    if let Some(p) = fifo {
        match set_fifo(p) {
            Ok(()) => a.fifo = true,
            Err(e) => a.warnings.push(format!(
                "{who}: SCHED_FIFO {p} not permitted ({e}); falling back to SCHED_OTHER nice {}",
                s.nice
            )),
        }
    }
    if !a.fifo && s.nice != 0 {
        match set_nice(s.nice) {
            Ok(()) => a.nice = Some(s.nice),
            Err(e) => a.warnings.push(format!(
                "{who}: nice {} not permitted ({e}); keeping the default priority",
                s.nice
            )),
        }
    }
    if s.mlock {
        match lock_memory() {
            Ok(()) => a.mlocked = true,
            Err(e) => a.warnings.push(format!(
                "{who}: mlockall not permitted ({e}); memory may page"
            )),
        }
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_names_the_field() {
        let mut s = RtSettings::default();
        assert!(s.validate().is_ok());
        s.fifo_priority = Some(120);
        assert!(s.validate().unwrap_err().contains("fifo_priority"));
        s.fifo_priority = None;
        s.nice = 25;
        assert!(s.validate().unwrap_err().contains("nice"));
    }

    #[test]
    fn pinning_in_a_thread_moves_it_to_that_core() {
        // Run in a thread so the test harness's threads keep their affinity.
        let target = core_affinity::get_core_ids()
            .and_then(|ids| ids.last().map(|c| c.id))
            .unwrap_or(0);
        std::thread::spawn(move || {
            let a = apply(
                "test",
                &RtSettings {
                    core: Some(target),
                    ..RtSettings::default()
                },
            );
            assert_eq!(a.core, Some(target), "{:?}", a.warnings);
            // SAFETY: sched_getcpu has no preconditions.
            let cpu = unsafe { libc::sched_getcpu() };
            assert_eq!(cpu as usize, target);
        })
        .join()
        .unwrap();
    }

    #[test]
    fn an_unavailable_core_is_a_warning_not_an_error() {
        std::thread::spawn(|| {
            let a = apply(
                "test",
                &RtSettings {
                    core: Some(10_000),
                    ..RtSettings::default()
                },
            );
            assert_eq!(a.core, None);
            assert_eq!(a.warnings.len(), 1);
            assert!(a.warnings[0].contains("unpinned"));
        })
        .join()
        .unwrap();
    }
}
