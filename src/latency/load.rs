//! How busy the machine was during a measurement: a measurement on a shared
//! machine is only honest next to this. From `/proc/stat` (all CPUs' busy
//! and idle time), `/proc/loadavg`, and `getrusage` for the CPU time of the
//! measuring processes themselves, so the others' share can be told apart.

use serde::{Deserialize, Serialize};
use std::time::Instant;

/// One reading.
#[derive(Clone, Copy, Debug)]
pub struct LoadSample {
    at: Instant,
    /// Total and idle (idle + iowait) jiffies of all CPUs.
    total: u64,
    idle: u64,
    /// 1-minute load average.
    loadavg_1m: f64,
    /// CPU time of this process and of its reaped children, ns.
    own_ns: u64,
}

/// Load over an interval.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LoadReport {
    /// CPUs online.
    pub cpus: usize,
    /// 1-minute load average at the start and the end.
    pub loadavg_1m_start: f64,
    pub loadavg_1m_end: f64,
    /// Busy share of all CPUs over the interval, %.
    pub busy_pct: f64,
    /// Of which the measuring processes, % of all CPUs.
    pub ours_pct: f64,
    /// Everything else, % of all CPUs.
    pub others_pct: f64,
}

fn read_cpu() -> (u64, u64) {
    let Ok(s) = std::fs::read_to_string("/proc/stat") else {
        return (0, 0);
    };
    let Some(line) = s.lines().next() else {
        return (0, 0);
    };
    let v: Vec<u64> = line
        .split_whitespace()
        .skip(1)
        .filter_map(|x| x.parse().ok())
        .collect();
    // user nice system idle iowait irq softirq steal (guest is in user).
    let total: u64 = v.iter().take(8).sum();
    let idle = v.get(3).copied().unwrap_or(0) + v.get(4).copied().unwrap_or(0);
    (total, idle)
}

fn read_loadavg() -> f64 {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(f64::NAN)
}

fn rusage_ns(who: libc::c_int) -> u64 {
    // SAFETY: getrusage fills the struct we own.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(who, &mut ru) };
    let tv = |t: libc::timeval| t.tv_sec as u64 * 1_000_000_000 + t.tv_usec as u64 * 1_000;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

/// CPUs online (of the machine, not of this thread's affinity mask).
pub fn cpus() -> usize {
    // SAFETY: sysconf has no preconditions.
    let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
    if n > 0 {
        n as usize
    } else {
        1
    }
}

impl LoadSample {
    /// Read now.
    pub fn now() -> Self {
        let (total, idle) = read_cpu();
        Self {
            at: Instant::now(),
            total,
            idle,
            loadavg_1m: read_loadavg(),
            own_ns: rusage_ns(libc::RUSAGE_SELF) + rusage_ns(libc::RUSAGE_CHILDREN),
        }
    }

    /// The load between `self` and a later reading (`later` taken after the
    /// measuring children were reaped, so their CPU time is counted).
    pub fn until(&self, later: &LoadSample) -> LoadReport {
        let cpus = cpus();
        let dt = later.total.saturating_sub(self.total);
        let di = later.idle.saturating_sub(self.idle);
        let busy = if dt > 0 {
            100.0 * (dt - di.min(dt)) as f64 / dt as f64
        } else {
            f64::NAN
        };
        let wall_ns = later.at.duration_since(self.at).as_nanos() as f64;
        let ours = if wall_ns > 0.0 {
            100.0 * later.own_ns.saturating_sub(self.own_ns) as f64 / (wall_ns * cpus as f64)
        } else {
            f64::NAN
        };
        let ours = ours.min(busy);
        LoadReport {
            cpus,
            loadavg_1m_start: self.loadavg_1m,
            loadavg_1m_end: later.loadavg_1m,
            busy_pct: busy,
            ours_pct: ours,
            others_pct: (busy - ours).max(0.0),
        }
    }
}

impl LoadReport {
    /// One line for the console.
    pub fn line(&self) -> String {
        format!(
            "machine: {} CPUs, load avg {:.2} -> {:.2}, busy {:.0}% (measurement {:.0}%, others {:.0}%)",
            self.cpus,
            self.loadavg_1m_start,
            self.loadavg_1m_end,
            self.busy_pct,
            self.ours_pct,
            self.others_pct
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_busy_thread_shows_up_as_our_load() {
        let a = LoadSample::now();
        let t = Instant::now();
        let mut x = 0u64;
        while t.elapsed().as_millis() < 300 {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
            std::hint::black_box(x);
        }
        let r = a.until(&LoadSample::now());
        assert_eq!(r.cpus, cpus());
        // One busy thread is about 1/cpus of the machine (scheduling noise
        // aside): it must register, and the shares must add up.
        assert!(r.ours_pct > 100.0 / (16.0 * r.cpus as f64), "{r:?}");
        assert!(r.busy_pct >= r.ours_pct - 1e-9);
        assert!((r.ours_pct + r.others_pct - r.busy_pct).abs() < 1e-6 || r.others_pct == 0.0);
    }
}
