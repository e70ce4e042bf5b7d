//! Time the machine took from each core: the kernel's per-CPU accounting of
//! interrupt, soft-interrupt and *steal* time (`/proc/stat`, `man 5 proc`).
//!
//! Steal is the time a virtual CPU was runnable but the hypervisor ran
//! something else: on a cloud or CI virtual machine the host can stop a
//! vCPU for a millisecond or more while every thread on it, whatever its
//! priority, stands still. A stage pinned there misses its budget and no
//! setting inside the guest can prevent it. Reading the counters at the
//! start and end of a run puts that time in the report beside the misses
//! ([`crate::budget`] classes each miss during which the thread was never
//! switched out as the host's).
//!
//! The counters are in USER_HZ ticks (`sysconf(_SC_CLK_TCK)`, 100 on
//! Linux), so a run's figure is exact to 10 ms per core: enough to tell a
//! host that stole 20 ms a minute from one that stole nothing.

/// Cumulative interrupt, soft-interrupt and steal time of one core, ns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CoreTimes {
    pub core: usize,
    pub irq_ns: u64,
    pub softirq_ns: u64,
    pub steal_ns: u64,
}

/// What one core lost between two snapshots, ms.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CoreLoss {
    pub core: usize,
    pub steal_ms: f64,
    pub irq_ms: f64,
    pub softirq_ms: f64,
}

/// The per-core counters of a `/proc/stat` text (`cpuN user nice system
/// idle iowait irq softirq steal ...`; the aggregate `cpu` line is
/// skipped). Lines it cannot read are skipped: a kernel without steal
/// accounting gives steal 0.
pub fn parse_proc_stat(text: &str, ns_per_tick: u64) -> Vec<CoreTimes> {
    text.lines()
        .filter_map(|l| {
            let mut f = l.split_ascii_whitespace();
            let core = f.next()?.strip_prefix("cpu")?.parse::<usize>().ok()?;
            let v: Vec<u64> = f.map_while(|x| x.parse().ok()).collect();
            let at = |i: usize| v.get(i).copied().unwrap_or(0) * ns_per_tick;
            (v.len() >= 4).then(|| CoreTimes {
                core,
                irq_ns: at(5),
                softirq_ns: at(6),
                steal_ns: at(7),
            })
        })
        .collect()
}

/// Nanoseconds per USER_HZ tick (10 ms when unknown).
fn ns_per_tick() -> u64 {
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if hz > 0 {
        1_000_000_000 / hz as u64
    } else {
        10_000_000
    }
}

/// A snapshot of every core's counters (empty where `/proc/stat` cannot be
/// read: not Linux, or no procfs).
pub fn snapshot() -> Vec<CoreTimes> {
    std::fs::read_to_string("/proc/stat")
        .map(|t| parse_proc_stat(&t, ns_per_tick()))
        .unwrap_or_default()
}

/// What each core of `cores` lost from `before` to `after` (a core missing
/// from either snapshot is left out).
pub fn loss(before: &[CoreTimes], after: &[CoreTimes], cores: &[usize]) -> Vec<CoreLoss> {
    let ms = |a: u64, b: u64| a.saturating_sub(b) as f64 / 1e6;
    cores
        .iter()
        .filter_map(|&c| {
            let b = before.iter().find(|t| t.core == c)?;
            let a = after.iter().find(|t| t.core == c)?;
            Some(CoreLoss {
                core: c,
                steal_ms: ms(a.steal_ns, b.steal_ns),
                irq_ms: ms(a.irq_ns, b.irq_ns),
                softirq_ms: ms(a.softirq_ns, b.softirq_ns),
            })
        })
        .collect()
}

/// One line: `core 0 steal 10 ms irq 0 ms softirq 0 ms; core 1 ...`.
pub fn describe(losses: &[CoreLoss]) -> String {
    losses
        .iter()
        .map(|l| {
            format!(
                "core {} steal {:.0} ms, irq {:.0} ms, softirq {:.0} ms",
                l.core, l.steal_ms, l.irq_ms, l.softirq_ms
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
}

#[cfg(test)]
mod tests {
    use super::*;

    const STAT: &str = "cpu  11697309 163784 414696 2697277 12355 0 21655 14918 0 0
cpu0 5891626 35906 208895 1351075 6918 3 15793 7420 0 0
cpu1 5805683 127877 205801 1346201 5436 0 5862 7497 0 0
intr 1 2 3
ctxt 123
";

    #[test]
    fn reads_each_cores_irq_softirq_and_steal() {
        let t = parse_proc_stat(STAT, 10_000_000);
        assert_eq!(t.len(), 2);
        assert_eq!(
            t[0],
            CoreTimes {
                core: 0,
                irq_ns: 30_000_000,
                softirq_ns: 157_930_000_000,
                steal_ns: 74_200_000_000,
            }
        );
        assert_eq!(t[1].steal_ns, 74_970_000_000);
    }

    #[test]
    fn a_kernel_without_steal_columns_reads_as_zero() {
        let t = parse_proc_stat("cpu0 1 2 3 4\n", 10_000_000);
        assert_eq!(t[0].steal_ns, 0);
        assert!(parse_proc_stat("cpu0 1 2\nnonsense\n", 1).is_empty());
    }

    #[test]
    fn loss_is_the_difference_on_the_cores_asked_for() {
        let a = parse_proc_stat(STAT, 10_000_000);
        let later = STAT.replace("7497 0 0", "7499 0 0");
        let b = parse_proc_stat(&later, 10_000_000);
        let l = loss(&a, &b, &[1, 7]);
        assert_eq!(l.len(), 1, "core 7 does not exist");
        assert_eq!(l[0].core, 1);
        assert!((l[0].steal_ms - 20.0).abs() < 1e-9);
        assert_eq!(l[0].irq_ms, 0.0);
        assert!(describe(&l).starts_with("core 1 steal 20 ms"));
    }

    #[test]
    fn this_machine_has_a_line_per_core() {
        // Linux CI and development machines have procfs: one line per
        // online CPU.
        // SAFETY: sysconf has no preconditions.
        let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
        assert_eq!(snapshot().len() as i64, n as i64);
    }
}
