//! The most recent deadline misses of a stage, each with when it started
//! and what it looked like, so that a user can line a miss up with the
//! machine's own record of that instant (an `ftrace` or `perf sched` trace
//! on the same CLOCK_MONOTONIC, or their own logs).
//!
//! A fixed ring of [`MISS_LOG_CAPACITY`] entries, written in place: no
//! allocation after construction. When it is full the oldest entry is
//! overwritten and counted ([`MissLog::overwritten`]), so every miss is
//! either listed or counted: misses = [`MissLog::len`] +
//! [`MissLog::overwritten`].

/// Misses a [`MissLog`] keeps (the most recent ones).
pub const MISS_LOG_CAPACITY: usize = 32;

/// One deadline miss.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Miss {
    /// When the message's work started, on the stage's clock (ns; in a
    /// running pipeline CLOCK_MONOTONIC, the clock of every wire stamp).
    pub start_ns: u64,
    /// Wall-clock time from start to end (ns), above the budget.
    pub wall_ns: u64,
    /// The thread's CPU time (ns) from the last start mark to the record
    /// of the message; `None` without any mark. A stage that records after
    /// publishing its output (its end stamp) counts the publishing here
    /// too, so this can exceed `wall_ns`.
    pub cpu_ns: Option<u64>,
    /// The thread's context switches (voluntary + involuntary) over the
    /// message; `None` without a start mark or when unreadable.
    pub switches: Option<u64>,
    /// The thread's page faults over the message (same marks as
    /// `switches`); `None` without a start mark or when unreadable.
    pub faults: Option<Faults>,
    /// Whose miss it was (the rule of `crate::budget`).
    pub kind: MissKind,
}

/// A filler for the unused slots (never listed).
const EMPTY: Miss = Miss {
    start_ns: 0,
    wall_ns: 0,
    cpu_ns: None,
    switches: None,
    faults: None,
    kind: MissKind::Overrun,
};

/// Page faults of a thread over a stretch of time (`getrusage`'s
/// `ru_minflt`, `ru_majflt`): a fault stops the thread while the kernel
/// maps the page (µs for a minor one, a disk read for a major one), so a
/// miss with many of them spent its time making memory present, not
/// computing or waiting for the core.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Faults {
    /// Pages mapped without I/O (first touch, page cache, copy-on-write).
    pub minor: u64,
    /// Pages read from disk.
    pub major: u64,
}

impl Faults {
    /// Minor + major.
    pub fn total(&self) -> u64 {
        self.minor + self.major
    }
}

/// Ring of the most recent [`Miss`]es.
#[derive(Clone, Debug)]
pub struct MissLog {
    slots: [Miss; MISS_LOG_CAPACITY],
    /// Slot the next miss goes to.
    next: usize,
    /// Slots in use (≤ capacity).
    len: usize,
    /// Misses pushed out of the ring by newer ones.
    overwritten: u64,
}

impl Default for MissLog {
    fn default() -> Self {
        Self::new()
    }
}

impl MissLog {
    /// An empty log.
    pub const fn new() -> Self {
        Self {
            slots: [EMPTY; MISS_LOG_CAPACITY],
            next: 0,
            len: 0,
            overwritten: 0,
        }
    }

    /// Add a miss; a full log drops its oldest entry and counts it.
    pub fn push(&mut self, m: Miss) {
        self.slots[self.next] = m;
        self.next = (self.next + 1) % MISS_LOG_CAPACITY;
        if self.len < MISS_LOG_CAPACITY {
            self.len += 1;
        } else {
            self.overwritten += 1;
        }
    }

    /// Misses listed.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Nothing listed.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Misses no longer listed (pushed out by newer ones).
    pub fn overwritten(&self) -> u64 {
        self.overwritten
    }

    /// The listed misses, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &Miss> + '_ {
        // The oldest entry sits at `next` once the ring has wrapped, at 0
        // before.
        let first = (self.next + MISS_LOG_CAPACITY - self.len) % MISS_LOG_CAPACITY;
        (0..self.len).map(move |i| &self.slots[(first + i) % MISS_LOG_CAPACITY])
    }
}

/// Who a deadline miss belongs to (the discriminant is its wire id).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum MissKind {
    /// The stage's own CPU time exceeded the budget (or was not measured:
    /// a miss without a start mark is never called someone else's).
    Overrun = 1,
    /// Within budget on the CPU, but the thread was switched out: another
    /// thread of this machine ran in its place.
    Preempted = 2,
    /// Within budget on the CPU and never switched out: interrupts or the
    /// hypervisor took the time.
    Host = 3,
}

impl MissKind {
    /// Every kind, by wire id.
    pub const ALL: [MissKind; 3] = [MissKind::Overrun, MissKind::Preempted, MissKind::Host];

    /// `overrun`, `preempted` or `host` (the report's word).
    pub fn name(self) -> &'static str {
        match self {
            MissKind::Overrun => "overrun",
            MissKind::Preempted => "preempted",
            MissKind::Host => "host",
        }
    }

    /// Decode a wire id.
    pub fn from_id(id: u32) -> Option<MissKind> {
        MissKind::ALL.into_iter().find(|k| *k as u32 == id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn miss(i: u64) -> Miss {
        Miss {
            start_ns: 1_000 * i,
            wall_ns: 200 + i,
            cpu_ns: Some(i),
            switches: Some(i % 3),
            faults: Some(Faults {
                minor: 10 * i,
                major: i % 2,
            }),
            kind: [MissKind::Overrun, MissKind::Preempted, MissKind::Host][(i % 3) as usize],
        }
    }

    fn starts(l: &MissLog) -> Vec<u64> {
        l.iter().map(|m| m.start_ns / 1_000).collect()
    }

    #[test]
    fn lists_misses_oldest_first_until_full() {
        let mut l = MissLog::new();
        assert!(l.is_empty());
        assert_eq!(l.iter().count(), 0);
        for i in 1..=3 {
            l.push(miss(i));
        }
        assert_eq!(l.len(), 3);
        assert_eq!(l.overwritten(), 0);
        assert_eq!(
            l.iter().copied().collect::<Vec<_>>(),
            [miss(1), miss(2), miss(3)]
        );
        for i in 4..=MISS_LOG_CAPACITY as u64 {
            l.push(miss(i));
        }
        // Exactly full: nothing lost yet.
        assert_eq!(l.len(), MISS_LOG_CAPACITY);
        assert_eq!(l.overwritten(), 0);
        assert_eq!(
            starts(&l),
            (1..=MISS_LOG_CAPACITY as u64).collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_full_log_drops_its_oldest_and_counts_it() {
        let mut l = MissLog::new();
        let cap = MISS_LOG_CAPACITY as u64;
        for i in 1..=cap + 1 {
            l.push(miss(i));
        }
        assert_eq!((l.len() as u64, l.overwritten()), (cap, 1));
        assert_eq!(starts(&l), (2..=cap + 1).collect::<Vec<_>>());
        // Around the ring more than twice: 2·cap + 7 misses in all.
        for i in cap + 2..=3 * cap + 7 {
            l.push(miss(i));
        }
        assert_eq!(l.overwritten(), 2 * cap + 7);
        assert_eq!(l.len() as u64 + l.overwritten(), 3 * cap + 7);
        assert_eq!(starts(&l), (2 * cap + 8..=3 * cap + 7).collect::<Vec<_>>());
        // Every field of an entry survives the wrap.
        assert_eq!(l.iter().last(), Some(&miss(3 * cap + 7)));
        assert_eq!(l.iter().next(), Some(&miss(2 * cap + 8)));
    }
}
