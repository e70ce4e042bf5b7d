//! Clocks. Every stamp on the wire is CLOCK_MONOTONIC nanoseconds: one clock
//! shared by all processes of a host, never stepped by NTP.
//!
//! Stage loops take a [`Clock`] so a test can run the simulated plant on a
//! [`SimClock`] (time advances only when the loop sleeps: deterministic and
//! faster than real time) while production uses [`MonotonicClock`].

use std::sync::atomic::{AtomicU64, Ordering};

/// CLOCK_MONOTONIC now, in nanoseconds.
pub fn now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Sleep until CLOCK_MONOTONIC reaches `t_ns` (absolute, so periodic loops do
/// not accumulate drift). Returns early on a signal.
pub fn sleep_until_ns(t_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (t_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (t_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: plain absolute clock_nanosleep; EINTR simply returns.
    unsafe {
        libc::clock_nanosleep(
            libc::CLOCK_MONOTONIC,
            libc::TIMER_ABSTIME,
            &ts,
            std::ptr::null_mut(),
        )
    };
}

/// A source of time for stage loops.
pub trait Clock: Send + Sync {
    /// Now, in nanoseconds on this clock.
    fn now_ns(&self) -> u64;
    /// Block until `t_ns` (may return early on a signal).
    fn sleep_until_ns(&self, t_ns: u64);
}

/// The real CLOCK_MONOTONIC.
#[derive(Clone, Copy, Debug, Default)]
pub struct MonotonicClock;

impl Clock for MonotonicClock {
    fn now_ns(&self) -> u64 {
        now_ns()
    }
    fn sleep_until_ns(&self, t_ns: u64) {
        sleep_until_ns(t_ns)
    }
}

/// Simulated time: `now` only moves when someone sleeps (or calls
/// [`SimClock::advance`]).
#[derive(Debug)]
pub struct SimClock {
    now: AtomicU64,
}

impl SimClock {
    /// A clock reading `start_ns`.
    pub fn new(start_ns: u64) -> Self {
        Self {
            now: AtomicU64::new(start_ns),
        }
    }
    /// Move time forward by `dt_ns`.
    pub fn advance(&self, dt_ns: u64) {
        self.now.fetch_add(dt_ns, Ordering::SeqCst);
    }
}

impl Clock for SimClock {
    fn now_ns(&self) -> u64 {
        self.now.load(Ordering::SeqCst)
    }
    fn sleep_until_ns(&self, t_ns: u64) {
        self.now.fetch_max(t_ns, Ordering::SeqCst);
    }
}

/// CPU time of the calling thread in ns (CLOCK_THREAD_CPUTIME_ID). Unlike
/// wall time it leaves out the time the thread was descheduled, so compute
/// percentiles stay meaningful on a shared, loaded machine (benchmarks and
/// experiments report it beside wall time). With the kernel's steal
/// accounting (common hypervisors) it also leaves out the time the host took
/// the virtual CPU away.
pub fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec through a valid pointer.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// What `getrusage(RUSAGE_THREAD)` says about the calling thread so far:
/// its context switches and page faults. One system call gives all three,
/// so a stage that marks a message's start reads the faults at no extra
/// cost beside the switches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ThreadUsage {
    /// Voluntary + involuntary context switches ([`thread_switches`]).
    pub switches: u64,
    /// Minor page faults: pages mapped without I/O (first touch of a fresh
    /// page, a page reclaimed from the page cache, copy-on-write).
    pub minor_faults: u64,
    /// Major page faults: pages read from disk.
    pub major_faults: u64,
}

impl ThreadUsage {
    /// Every count unknown (`getrusage` failed): `u64::MAX` throughout.
    pub const UNKNOWN: ThreadUsage = ThreadUsage {
        switches: u64::MAX,
        minor_faults: u64::MAX,
        major_faults: u64::MAX,
    };
}

/// The calling thread's [`ThreadUsage`] ([`ThreadUsage::UNKNOWN`] if
/// `getrusage` fails).
pub fn thread_usage() -> ThreadUsage {
    // SAFETY: an all-zero rusage is a valid value of the plain C struct.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage writes one rusage through a valid pointer.
    if unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut ru) } != 0 {
        return ThreadUsage::UNKNOWN;
    }
    ThreadUsage {
        switches: ru.ru_nvcsw as u64 + ru.ru_nivcsw as u64,
        minor_faults: ru.ru_minflt as u64,
        major_faults: ru.ru_majflt as u64,
    }
}

/// Context switches of the calling thread so far, voluntary and
/// involuntary (`getrusage(RUSAGE_THREAD)`): if the count did not move
/// across a stretch of wall time the thread was never taken off its CPU
/// by the kernel, so any of that time it did not run went to interrupt
/// handlers or to the hypervisor. `u64::MAX` if unreadable.
pub fn thread_switches() -> u64 {
    thread_usage().switches
}

/// Map `pages` fresh anonymous pages, write one byte to each (at least one
/// minor fault a page: mmap maps nothing until the first touch), unmap
/// them. For the tests of the fault counts.
#[cfg(test)]
pub(crate) fn touch_fresh_pages(pages: usize) {
    let page = 4096;
    let len = pages * page;
    // SAFETY: a private anonymous mapping, unmapped below.
    let p = unsafe {
        libc::mmap(
            std::ptr::null_mut(),
            len,
            libc::PROT_READ | libc::PROT_WRITE,
            libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
            -1,
            0,
        )
    };
    assert_ne!(p, libc::MAP_FAILED);
    for i in 0..pages {
        // SAFETY: inside the mapping.
        unsafe { std::ptr::write_volatile((p as *mut u8).add(i * page), 1) };
    }
    // SAFETY: the mapping made above.
    unsafe { libc::munmap(p, len) };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_clock_moves_forward_and_sleeps_until_the_deadline() {
        let c = MonotonicClock;
        let a = c.now_ns();
        let target = a + 2_000_000;
        c.sleep_until_ns(target);
        let b = c.now_ns();
        assert!(b >= target, "woke {} ns early", target - b);
    }

    #[test]
    fn sim_clock_advances_only_on_sleep() {
        let c = SimClock::new(10);
        assert_eq!(c.now_ns(), 10);
        c.sleep_until_ns(5);
        assert_eq!(c.now_ns(), 10);
        c.sleep_until_ns(1_000);
        assert_eq!(c.now_ns(), 1_000);
        c.advance(24);
        assert_eq!(c.now_ns(), 1_024);
    }

    #[test]
    fn a_sleep_is_a_context_switch() {
        let a = thread_switches();
        std::thread::sleep(std::time::Duration::from_millis(2));
        let b = thread_switches();
        assert!(b > a && b != u64::MAX, "{a} -> {b}");
    }

    #[test]
    fn touching_fresh_pages_is_counted_as_minor_faults() {
        // 64 fresh anonymous pages, each touched once: at least one minor
        // fault per page (none before the touch: mmap maps nothing yet).
        const PAGES: usize = 64;
        let a = thread_usage();
        touch_fresh_pages(PAGES);
        let b = thread_usage();
        assert_ne!(a, ThreadUsage::UNKNOWN);
        assert!(
            b.minor_faults - a.minor_faults >= PAGES as u64,
            "{a:?} -> {b:?}"
        );
        // Nothing was read from disk.
        assert_eq!(b.major_faults, a.major_faults);
    }
}
