//! Core affinity, scheduling priority and memory locking of the calling
//! process (DESIGN.md "Real time on 2 cores"). Each setting that the system
//! refuses yields one warning line and a fallback — never an abort:
//! - affinity via `core_affinity` (the stage processes are single-threaded,
//!   so pinning the thread pins the process);
//! - SCHED_FIFO at the configured priority, else SCHED_OTHER at the
//!   configured nice value (else unchanged);
//! - memory locking, once the stage has allocated what it needs (its first
//!   statistics report): `mlockall(MCL_CURRENT)` if what is mapped then is
//!   at most [`mlock_cap`], else a warning ([`lock_current_memory`]) — a
//!   config that sizes a stage large cannot lock gigabytes.
//!
//! A SCHED_FIFO process that never blocks owns its core: lower-priority
//! stages there get no CPU, not even to die of a SIGKILL. So every FIFO
//! stage also gets `RLIMIT_RTTIME` ([`RT_CPU_SOFT`], [`RT_CPU_HARD`]): the
//! kernel signals a real-time task that has run that long without
//! blocking. Our stages block on every message, so only a runaway reaches
//! it; it then exits with [`RT_CPU_EXIT`] (SIGXCPU handler) and the
//! supervisor restarts it like any failed stage.

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
    /// Lock the stage's memory once it is set up (no page faults on the
    /// hot path), if it is at most [`mlock_cap`].
    #[serde(default)]
    pub mlock: bool,
}

/// Real-time CPU a FIFO stage may use without blocking before the kernel
/// sends SIGXCPU (the stage then exits with [`RT_CPU_EXIT`]).
pub const RT_CPU_SOFT: std::time::Duration = std::time::Duration::from_secs(2);
/// ... and before it sends SIGKILL, should the SIGXCPU handler not run.
pub const RT_CPU_HARD: std::time::Duration = std::time::Duration::from_secs(3);
/// Exit status of a stage stopped by its real-time CPU limit.
pub const RT_CPU_EXIT: i32 = 71;

extern "C" fn on_sigxcpu(_: libc::c_int) {
    // SAFETY: _exit is async-signal-safe.
    unsafe { libc::_exit(RT_CPU_EXIT) }
}

/// Bound the real-time CPU the calling process may use without blocking
/// (`RLIMIT_RTTIME`), exiting with [`RT_CPU_EXIT`] at the soft limit.
pub fn limit_rt_cpu(soft: std::time::Duration, hard: std::time::Duration) -> Result<(), String> {
    let lim = libc::rlimit {
        rlim_cur: soft.as_micros() as libc::rlim_t,
        rlim_max: hard.as_micros().max(soft.as_micros()) as libc::rlim_t,
    };
    // SAFETY: a plain handler that only calls _exit; `sa` is fully
    // initialised (zeroed, then the handler and an empty mask).
    let r = unsafe {
        let mut sa: libc::sigaction = std::mem::zeroed();
        sa.sa_sigaction = on_sigxcpu as *const () as libc::sighandler_t;
        libc::sigemptyset(&mut sa.sa_mask);
        libc::sigaction(libc::SIGXCPU, &sa, std::ptr::null_mut())
    };
    if r != 0 {
        return Err(os_err());
    }
    // SAFETY: setrlimit on ourselves with a valid struct.
    if unsafe { libc::setrlimit(libc::RLIMIT_RTTIME, &lim) } != 0 {
        return Err(os_err());
    }
    Ok(())
}

/// Fault injection (`beliefbus run --chaos-spin STAGE:SECONDS`): a stage
/// started with this variable set to a number of seconds busy-loops from
/// then on, as a runaway would ([`spin_after_from_env`]).
pub const SPIN_AFTER_ENV: &str = "BELIEFBUS_CHAOS_SPIN_AFTER_S";

extern "C" fn spin_forever(_: libc::c_int) {
    loop {
        std::hint::spin_loop();
    }
}

/// Arm the runaway fault of [`SPIN_AFTER_ENV`], if set: a one-shot timer
/// whose handler never returns, so the main thread stops blocking and
/// spins at its scheduling priority. Returns the delay armed.
pub fn spin_after_from_env() -> Option<f64> {
    let t: f64 = std::env::var(SPIN_AFTER_ENV).ok()?.parse().ok()?;
    if !(t.is_finite() && t >= 0.0) {
        return None;
    }
    let secs = t.floor();
    let it = libc::itimerval {
        it_interval: libc::timeval {
            tv_sec: 0,
            tv_usec: 0,
        },
        it_value: libc::timeval {
            tv_sec: secs as libc::time_t,
            tv_usec: (((t - secs) * 1e6) as libc::suseconds_t).max(1),
        },
    };
    // SAFETY: the handler only spins; `sa` is fully initialised; setitimer
    // with valid structs.
    unsafe {
        let mut sa: libc::sigaction = std::mem::zeroed();
        sa.sa_sigaction = spin_forever as *const () as libc::sighandler_t;
        libc::sigemptyset(&mut sa.sa_mask);
        libc::sigaction(libc::SIGALRM, &sa, std::ptr::null_mut());
        libc::setitimer(libc::ITIMER_REAL, &it, std::ptr::null_mut());
    }
    Some(t)
}

/// What was actually applied.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RtApplied {
    /// Core pinned to.
    pub core: Option<usize>,
    /// Running under SCHED_FIFO.
    pub fifo: bool,
    /// `RLIMIT_RTTIME` set (with `fifo`).
    pub rt_cpu_limited: bool,
    /// Nice value in effect (SCHED_OTHER).
    pub nice: Option<i32>,
    /// Locking was asked for: the stage locks its memory at its first
    /// report, up to this many bytes ([`lock_current_memory`]).
    pub mlock_cap: Option<u64>,
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

/// Leave SCHED_FIFO/SCHED_RR for SCHED_OTHER (the nice value stays) if
/// the calling thread runs under one of them; true if it did. A stage
/// calls it once its loop is over: tearing down its ports and exiting
/// (unmapping locked memory) then no longer preempts the stages of lower
/// real-time priority on its core that are still finishing their last
/// messages.
pub fn leave_real_time() -> bool {
    // SAFETY: sched_getscheduler on ourselves has no preconditions.
    let policy = unsafe { libc::sched_getscheduler(0) };
    if policy != libc::SCHED_FIFO && policy != libc::SCHED_RR {
        return false;
    }
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: sched_setscheduler on ourselves with a valid param.
    unsafe { libc::sched_setscheduler(0, libc::SCHED_OTHER, &param) == 0 }
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

/// The machine's physical memory (bytes).
pub fn physical_memory() -> u64 {
    // SAFETY: sysconf has no preconditions.
    let (pages, size) = unsafe {
        (
            libc::sysconf(libc::_SC_PHYS_PAGES),
            libc::sysconf(libc::_SC_PAGESIZE),
        )
    };
    if pages > 0 && size > 0 {
        (pages as u64).saturating_mul(size as u64)
    } else {
        // Unknown: assume a small machine.
        1 << 30
    }
}

/// The most memory one stage locks: 1/16 of physical memory.
pub fn mlock_cap() -> u64 {
    physical_memory() / 16
}

/// Bytes mapped by this process (`VmSize`), what `MCL_CURRENT` would lock.
pub fn mapped_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let kb: u64 = s
        .lines()
        .find_map(|l| l.strip_prefix("VmSize:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb * 1024)
}

/// Lock every page mapped now — after the stage allocated its buffers, so
/// the hot path takes no page fault — if they total at most `cap` bytes;
/// returns the bytes locked. Later mappings are not locked (MCL_FUTURE
/// would lock any later growth, unbounded).
pub fn lock_current_memory(cap: u64) -> Result<u64, String> {
    let mapped = mapped_bytes().ok_or("cannot read VmSize from /proc/self/status")?;
    if mapped > cap {
        return Err(format!(
            "{} MiB mapped is above the cap of {} MiB (1/16 of physical memory)",
            mapped >> 20,
            cap >> 20
        ));
    }
    // SAFETY: mlockall has no memory-safety preconditions.
    if unsafe { libc::mlockall(libc::MCL_CURRENT) } == 0 {
        Ok(mapped)
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
    if a.fifo {
        match limit_rt_cpu(RT_CPU_SOFT, RT_CPU_HARD) {
            Ok(()) => a.rt_cpu_limited = true,
            Err(e) => a.warnings.push(format!(
                "{who}: cannot set RLIMIT_RTTIME ({e}); a runaway would own its core"
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
        a.mlock_cap = Some(mlock_cap());
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
    fn a_runaway_real_time_thread_is_stopped_by_its_cpu_limit() {
        // In a child process: the limit and the handler are process-wide.
        // SAFETY: fork in a test; the child only calls async-signal-safe
        // functions and spins, the parent waits for it.
        let pid = unsafe { libc::fork() };
        assert!(pid >= 0);
        if pid == 0 {
            if set_fifo(1).is_err() {
                // SAFETY: _exit in the forked child.
                unsafe { libc::_exit(99) };
            }
            let short = std::time::Duration::from_millis(200);
            if limit_rt_cpu(short, short * 3).is_err() {
                // SAFETY: as above.
                unsafe { libc::_exit(98) };
            }
            loop {
                std::hint::spin_loop();
            }
        }
        let mut status = 0;
        // SAFETY: waitpid on our own child.
        unsafe { libc::waitpid(pid, &mut status, 0) };
        let code = libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status));
        if code == Some(99) {
            eprintln!("SKIPPED: SCHED_FIFO not permitted here, RLIMIT_RTTIME not exercised");
            return;
        }
        assert_eq!(code, Some(RT_CPU_EXIT), "raw status {status}");
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

    #[test]
    fn leaving_real_time_returns_a_fifo_thread_to_sched_other() {
        // On a thread of its own: the policy is per thread.
        std::thread::spawn(|| {
            // SAFETY: sched_getscheduler on ourselves.
            let policy = || unsafe { libc::sched_getscheduler(0) };
            // Not real-time: nothing to leave.
            assert_eq!(policy(), libc::SCHED_OTHER);
            assert!(!leave_real_time());
            // Real-time where permitted (root, or an rtprio limit).
            if set_fifo(1).is_ok() {
                assert_eq!(policy(), libc::SCHED_FIFO);
                assert!(leave_real_time());
                assert_eq!(policy(), libc::SCHED_OTHER);
                assert!(!leave_real_time());
            }
        })
        .join()
        .unwrap();
    }
}
