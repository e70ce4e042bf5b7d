//! Host stall probe (after `hwlatdetect` and the spinning mode of
//! latency tests): how often, and for how long, a core is taken away from a
//! thread that never gives it up.
//!
//! One thread per core, pinned, at SCHED_FIFO when permitted, reads
//! CLOCK_MONOTONIC in a tight loop. Two consecutive reads are normally a few
//! tens of nanoseconds apart; a gap `g ≥ min_gap` between them is time the
//! thread did not get. Each gap is told apart by what the guest kernel saw
//! of it:
//!
//! ```text
//! switched  the thread's context-switch count moved across the gap:
//!           the guest scheduled another task (the machine's own business)
//! charged   no switch, and the thread's CPU clock moved by ≥ g/2: the guest
//!           believes the thread ran. The host took the core without
//!           reporting steal (VM exits handled in the host, host interrupts),
//!           or a guest interrupt handler ran (without IRQ time accounting
//!           both land on the thread's clock)
//! steal     no switch, and the CPU clock moved by < g/2: the hypervisor
//!           reported the time as steal and the guest left it off the thread
//! ```
//!
//! A stage's budget split ([`crate::budget`]) can only call a miss the
//! host's when its CPU clock stayed within the budget, so a *charged* stall
//! inside a stage's compute is counted as that stage's own overrun; the
//! probe measures how often the host produces such stalls on an otherwise
//! idle core, which is what those overruns are to be compared with.
//!
//! The loop spins in bursts of [`BURST_NS`] with a [`REST_NS`] sleep between
//! them (the gap across the sleep is not a stall), so the kernel's
//! real-time throttling (by default SCHED_FIFO may take 95 % of each
//! second) never cuts in and other tasks keep a share of the core.

use super::clock::{now_ns, thread_cpu_ns, thread_switches};
use super::hist::LatencyHist;
use super::sched;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// Length of one spinning burst.
pub const BURST_NS: u64 = 9_000_000;
/// Sleep between bursts.
pub const REST_NS: u64 = 1_000_000;
/// Shortest gap recorded as a stall.
pub const MIN_GAP_NS: u64 = 20_000;
/// Shortest host stall (charged or steal) whose start time is kept, for
/// [`crate::grid`]: on this scale the guest's own tick never reaches it.
pub const GRID_MIN_GAP_NS: u64 = 200_000;
/// Most start times kept per core (allocated up front).
pub const STARTS_MAX: usize = 4096;

/// What the guest saw of a stall (module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StallKind {
    Switched = 0,
    Charged = 1,
    Steal = 2,
}

impl StallKind {
    pub const ALL: [StallKind; 3] = [StallKind::Switched, StallKind::Charged, StallKind::Steal];

    pub fn name(self) -> &'static str {
        match self {
            StallKind::Switched => "switched",
            StallKind::Charged => "charged",
            StallKind::Steal => "steal",
        }
    }
}

/// Classify a gap of `wall_ns` during which the thread CPU clock moved by
/// `cpu_ns`; `switched`: the context-switch count moved.
pub fn classify(wall_ns: u64, cpu_ns: u64, switched: bool) -> StallKind {
    if switched {
        StallKind::Switched
    } else if 2 * cpu_ns >= wall_ns {
        StallKind::Charged
    } else {
        StallKind::Steal
    }
}

/// The three readings the probe takes.
pub trait ProbeClock {
    /// CLOCK_MONOTONIC, ns.
    fn wall(&mut self) -> u64;
    /// The thread's CPU clock, ns.
    fn cpu(&mut self) -> u64;
    /// The thread's context switches so far.
    fn switches(&mut self) -> u64;
}

/// The real clocks of the calling thread.
pub struct ThreadClocks;

impl ProbeClock for ThreadClocks {
    fn wall(&mut self) -> u64 {
        now_ns()
    }
    fn cpu(&mut self) -> u64 {
        thread_cpu_ns()
    }
    fn switches(&mut self) -> u64 {
        thread_switches()
    }
}

/// One core's stalls.
#[derive(Clone, Debug)]
pub struct CoreStalls {
    pub core: usize,
    /// Ran under SCHED_FIFO.
    pub fifo: bool,
    /// Wall time spent spinning (the sleeps between bursts left out).
    pub spun_ns: u64,
    /// Gap lengths by [`StallKind`] (index = the kind's value).
    pub gaps: [LatencyHist; 3],
    /// Start times (CLOCK_MONOTONIC, ns) of the first [`STARTS_MAX`]
    /// charged or steal stalls of at least [`GRID_MIN_GAP_NS`].
    pub starts: Vec<u64>,
    pub warnings: Vec<String>,
}

impl CoreStalls {
    pub fn new(core: usize) -> Self {
        Self {
            core,
            fifo: false,
            spun_ns: 0,
            gaps: [LatencyHist::new(), LatencyHist::new(), LatencyHist::new()],
            starts: Vec::with_capacity(STARTS_MAX),
            warnings: Vec::new(),
        }
    }

    /// Stalls of `kind` longer than `ns`.
    pub fn above(&self, kind: StallKind, ns: u64) -> u64 {
        let h = self.gaps[kind as usize].inner();
        if h.is_empty() {
            return 0;
        }
        // Values equivalent to `ns` at the histogram's precision count as
        // not above it.
        h.len() - h.count_between(0, h.highest_equivalent(ns))
    }

    /// Total stalled time of `kind`, ns (histogram precision, 0.1 %).
    pub fn total_ns(&self, kind: StallKind) -> u64 {
        self.gaps[kind as usize]
            .inner()
            .iter_recorded()
            .map(|v| v.value_iterated_to() * v.count_at_value())
            .sum()
    }

    /// Stalls of `kind` longer than `ns` per minute of spinning.
    pub fn per_minute(&self, kind: StallKind, ns: u64) -> f64 {
        if self.spun_ns == 0 {
            return 0.0;
        }
        self.above(kind, ns) as f64 * 60e9 / self.spun_ns as f64
    }
}

/// Spin until `until_ns` on `clock`, recording every gap of at least
/// `min_gap_ns` into `out`. The context-switch count is read only after a
/// gap longer than a microsecond (a switch always leaves one), so the loop
/// costs one wall and one CPU clock read per turn.
pub fn spin<C: ProbeClock>(clock: &mut C, until_ns: u64, min_gap_ns: u64, out: &mut CoreStalls) {
    let mut prev_wall = clock.wall();
    let mut prev_cpu = clock.cpu();
    let mut prev_sw = clock.switches();
    let start = prev_wall;
    while prev_wall < until_ns {
        let w = clock.wall();
        let c = clock.cpu();
        let g = w.saturating_sub(prev_wall);
        if g > 1_000 {
            let sw = clock.switches();
            if g >= min_gap_ns {
                let kind = classify(g, c.saturating_sub(prev_cpu), sw != prev_sw);
                out.gaps[kind as usize].record(g);
                if g >= GRID_MIN_GAP_NS
                    && kind != StallKind::Switched
                    && out.starts.len() < STARTS_MAX
                {
                    out.starts.push(prev_wall);
                }
            }
            prev_sw = sw;
        }
        prev_wall = w;
        prev_cpu = c;
    }
    out.spun_ns += prev_wall.saturating_sub(start);
}

fn probe_core(core: usize, duration: Duration, fifo: Option<u8>, stop: &AtomicBool) -> CoreStalls {
    let mut out = CoreStalls::new(core);
    if let Err(e) = sched::pin_to_core(core) {
        out.warnings
            .push(format!("stall probe core {core}: cannot pin ({e})"));
    }
    if let Some(p) = fifo {
        match sched::set_fifo(p) {
            Ok(()) => out.fifo = true,
            Err(e) => out.warnings.push(format!(
                "stall probe core {core}: SCHED_FIFO {p} not permitted ({e}); SCHED_OTHER"
            )),
        }
    }
    let end = now_ns() + duration.as_nanos() as u64;
    let mut clock = ThreadClocks;
    while !stop.load(Ordering::Relaxed) {
        let now = now_ns();
        if now >= end {
            break;
        }
        spin(&mut clock, (now + BURST_NS).min(end), MIN_GAP_NS, &mut out);
        std::thread::sleep(Duration::from_nanos(REST_NS));
    }
    out
}

/// Probe every core in `cores` at once for `duration` of wall time (about
/// 90 % of it spinning).
pub fn probe(
    cores: &[usize],
    duration: Duration,
    fifo: Option<u8>,
    stop: &AtomicBool,
) -> Result<Vec<CoreStalls>, String> {
    std::thread::scope(|s| {
        let jobs: Vec<_> = cores
            .iter()
            .map(|&core| {
                std::thread::Builder::new()
                    .name(format!("stall-probe-{core}"))
                    .spawn_scoped(s, move || probe_core(core, duration, fifo, stop))
                    .map_err(|e| e.to_string())
            })
            .collect::<Result<_, _>>()?;
        jobs.into_iter()
            .map(|j| {
                j.join()
                    .map_err(|_| "a stall probe thread panicked".to_string())
            })
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scripted clock: each turn of the loop reads (wall, cpu); the
    /// switch count is a function of the wall time.
    struct Script {
        reads: Vec<(u64, u64)>,
        i: usize,
        switch_at: Vec<u64>,
        last_wall: u64,
        switch_reads: usize,
    }

    impl ProbeClock for Script {
        fn wall(&mut self) -> u64 {
            let (w, _) = self.reads[self.i.min(self.reads.len() - 1)];
            self.last_wall = w;
            w
        }
        fn cpu(&mut self) -> u64 {
            let (_, c) = self.reads[self.i.min(self.reads.len() - 1)];
            self.i += 1;
            c
        }
        fn switches(&mut self) -> u64 {
            self.switch_reads += 1;
            self.switch_at
                .iter()
                .filter(|&&t| t <= self.last_wall)
                .count() as u64
        }
    }

    #[test]
    fn classify_tells_switches_charged_and_steal_apart() {
        assert_eq!(classify(100_000, 100_000, true), StallKind::Switched);
        assert_eq!(classify(100_000, 0, true), StallKind::Switched);
        assert_eq!(classify(100_000, 50_000, false), StallKind::Charged);
        assert_eq!(classify(100_000, 49_999, false), StallKind::Steal);
        assert_eq!(classify(100_000, 0, false), StallKind::Steal);
    }

    #[test]
    fn spin_records_each_gap_once_under_its_kind() {
        // Reads 100 ns apart, with three gaps: 50 µs fully charged, 800 µs
        // with 10 µs charged (steal), 300 µs across a context switch; and a
        // 5 µs gap below the threshold.
        let mut reads = Vec::new();
        let (mut w, mut c) = (1_000_000u64, 0u64);
        let mut push = |dw: u64, dc: u64, reads: &mut Vec<(u64, u64)>| {
            w += dw;
            c += dc;
            reads.push((w, c));
        };
        push(0, 0, &mut reads);
        for _ in 0..10 {
            push(100, 100, &mut reads);
        }
        push(50_000, 50_000, &mut reads);
        push(100, 100, &mut reads);
        push(800_000, 10_000, &mut reads);
        push(100, 100, &mut reads);
        push(5_000, 5_000, &mut reads);
        push(100, 100, &mut reads);
        push(300_000, 300_000, &mut reads);
        let switch_time = reads.last().unwrap().0 - 1;
        for _ in 0..10 {
            push(100, 100, &mut reads);
        }
        let end = reads.last().unwrap().0;
        let mut clock = Script {
            reads: reads.clone(),
            i: 0,
            switch_at: vec![switch_time],
            last_wall: 0,
            switch_reads: 0,
        };
        let mut out = CoreStalls::new(0);
        spin(&mut clock, end, MIN_GAP_NS, &mut out);
        assert_eq!(out.gaps[StallKind::Charged as usize].count(), 1);
        assert_eq!(out.gaps[StallKind::Steal as usize].count(), 1);
        assert_eq!(out.gaps[StallKind::Switched as usize].count(), 1);
        assert_eq!(out.above(StallKind::Steal, 700_000), 1);
        assert_eq!(out.above(StallKind::Steal, 800_000), 0);
        assert_eq!(out.above(StallKind::Charged, 20_000), 1);
        assert_eq!(out.above(StallKind::Charged, 60_000), 0);
        assert_eq!(out.spun_ns, end - 1_000_000);
        // Of the stalls of 200 µs and more, the host's (the 800 µs steal)
        // keeps its start; the switched 300 µs does not.
        let before = reads
            .windows(2)
            .find(|p| p[1].0 - p[0].0 == 800_000)
            .unwrap();
        assert_eq!(out.starts, [before[0].0]);
        // The switch count is read at start and after each gap above 1 µs
        // only (4 of them), not on every turn.
        assert_eq!(clock.switch_reads, 5);
        let total = out.total_ns(StallKind::Steal);
        assert!(total.abs_diff(800_000) <= 800, "{total}");
        let pm = out.per_minute(StallKind::Steal, 0);
        assert!((pm - 60e9 / out.spun_ns as f64).abs() < 1e-9);
    }

    #[test]
    fn a_sleep_inside_the_loop_is_seen_as_a_switched_stall() {
        // The real clocks: a thread that blocks for 2 ms in the middle of
        // a burst is switched out, and that is what the probe must call it.
        struct Sleepy(ThreadClocks, u32);
        impl ProbeClock for Sleepy {
            fn wall(&mut self) -> u64 {
                self.1 += 1;
                if self.1 == 100 {
                    std::thread::sleep(Duration::from_millis(2));
                }
                self.0.wall()
            }
            fn cpu(&mut self) -> u64 {
                self.0.cpu()
            }
            fn switches(&mut self) -> u64 {
                self.0.switches()
            }
        }
        let mut out = CoreStalls::new(0);
        let mut sleepy = Sleepy(ThreadClocks, 0);
        spin(&mut sleepy, now_ns() + 5_000_000, MIN_GAP_NS, &mut out);
        assert!(
            out.above(StallKind::Switched, 1_900_000) >= 1,
            "{:?}",
            out.gaps.each_ref().map(|h| h.count())
        );
    }

    #[test]
    fn the_probe_runs_every_core_asked_for_and_spins_most_of_the_time() {
        let stop = AtomicBool::new(false);
        let r = probe(&[0], Duration::from_millis(200), None, &stop).unwrap();
        assert_eq!(r.len(), 1);
        assert_eq!(r[0].core, 0);
        assert!(!r[0].fifo);
        // 9 ms bursts with 1 ms rests: at least half of the time spinning
        // even on a loaded machine, never more than the duration.
        assert!(r[0].spun_ns <= 200_000_000, "{}", r[0].spun_ns);
        assert!(r[0].spun_ns >= 20_000_000, "{}", r[0].spun_ns);
    }
}
