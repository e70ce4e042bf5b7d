//! The timer baseline: one pinned thread per core sleeping to absolute
//! deadlines, its wake-up latency, period jitter and misses.

use crate::latency::hdr::HdrLog;
use crate::latency::LatencyError;
use crate::rt::clock::{now_ns, sleep_until_ns};
use crate::rt::{sched, LatencyHist};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, SystemTime};

/// Settings of the timer baseline.
#[derive(Clone, Debug)]
pub struct TimerConfig {
    /// Wake-ups per second.
    pub rate_hz: f64,
    pub duration: Duration,
    /// Cores to measure (one thread each).
    pub cores: Vec<usize>,
    /// SCHED_FIFO priority (None: SCHED_OTHER).
    pub fifo: Option<u8>,
    /// Keep one HdrHistogram interval per second.
    pub hdr_logs: bool,
}

impl TimerConfig {
    /// Check ranges before starting.
    pub fn validate(&self) -> Result<(), LatencyError> {
        if !(self.rate_hz.is_finite() && (1.0..=100_000.0).contains(&self.rate_hz)) {
            return Err(LatencyError::BadArg(format!(
                "--rate must be 1..=100000 Hz, got {}",
                self.rate_hz
            )));
        }
        if self.duration < Duration::from_millis(100) || self.duration > Duration::from_secs(86_400)
        {
            return Err(LatencyError::BadArg(
                "--duration must be between 0.1 and 86400 seconds".into(),
            ));
        }
        if self.cores.is_empty() {
            return Err(LatencyError::BadArg("no core to measure".into()));
        }
        let n = sched::available_cores();
        if let Some(c) = self.cores.iter().find(|&&c| c >= n) {
            return Err(LatencyError::BadArg(format!(
                "core {c} is not available (0..{})",
                n - 1
            )));
        }
        if let Some(p) = self.fifo {
            if !(1..=99).contains(&p) {
                return Err(LatencyError::BadArg(format!(
                    "--fifo must be 1..=99, got {p}"
                )));
            }
        }
        Ok(())
    }

    /// The period in ns.
    pub fn period_ns(&self) -> u64 {
        (1e9 / self.rate_hz).round() as u64
    }
}

/// One core's timer results.
#[derive(Debug)]
pub struct CoreTimer {
    pub core: usize,
    /// Ran under SCHED_FIFO.
    pub fifo: bool,
    pub wake: LatencyHist,
    pub period_jitter: LatencyHist,
    pub misses: u64,
    pub wakeups: u64,
    pub warnings: Vec<String>,
    pub wake_log: Option<HdrLog>,
    pub jitter_log: Option<HdrLog>,
}

/// One filled pair of interval histograms (wake-up latency, period
/// jitter) on its way to the log writer, with its start and length.
type Interval = (Duration, Duration, [LatencyHist; 2]);

/// The timer thread's end of the log writer: full intervals out, empty
/// histograms back (a small pool, so the timer thread never allocates,
/// serialises or blocks — a late writer only makes an interval longer).
struct IntervalTx {
    full: crossbeam::channel::Sender<Interval>,
    empty: crossbeam::channel::Receiver<[LatencyHist; 2]>,
}

/// Histogram pairs in flight per core.
const POOL: usize = 4;
/// Length of a log interval.
const IV_NS: u64 = 1_000_000_000;

/// Write intervals into the two logs until the timer thread hangs up.
fn log_writer(
    mut logs: [HdrLog; 2],
    full: crossbeam::channel::Receiver<Interval>,
    empty: crossbeam::channel::Sender<[LatencyHist; 2]>,
) -> Result<[HdrLog; 2], LatencyError> {
    let mut err = None;
    for (a, d, mut pair) in full {
        for (log, h) in logs.iter_mut().zip(pair.iter_mut()) {
            if let Err(e) = log.add(h, a, d) {
                err.get_or_insert(e);
            }
            h.reset();
        }
        let _ = empty.send(pair);
    }
    match err {
        Some(e) => Err(LatencyError::Output {
            path: "hdr log".into(),
            reason: e.to_string(),
        }),
        None => Ok(logs),
    }
}

fn timer_thread(
    cfg: &TimerConfig,
    core: usize,
    start_ns: u64,
    stop: &AtomicBool,
    logs: Option<IntervalTx>,
) -> CoreTimer {
    let mut warnings = Vec::new();
    if let Err(e) = sched::pin_to_core(core) {
        warnings.push(format!("timer core {core}: cannot pin ({e})"));
    }
    let mut fifo = false;
    if let Some(p) = cfg.fifo {
        match sched::set_fifo(p) {
            Ok(()) => fifo = true,
            Err(e) => warnings.push(format!(
                "timer core {core}: SCHED_FIFO {p} not permitted ({e}); SCHED_OTHER"
            )),
        }
    }
    let mut out = CoreTimer {
        core,
        fifo,
        wake: LatencyHist::new(),
        period_jitter: LatencyHist::new(),
        misses: 0,
        wakeups: 0,
        warnings,
        wake_log: None,
        jitter_log: None,
    };
    let mut iv = [LatencyHist::new(), LatencyHist::new()];
    let t_ns = cfg.period_ns();
    let end_ns = start_ns + cfg.duration.as_nanos() as u64;
    let mut next = start_ns + t_ns;
    let mut prev_wake: Option<u64> = None;
    let mut iv_start = start_ns;
    // Hand the interval's pair to the writer if a fresh pair is at hand;
    // otherwise keep recording into this one (the interval grows).
    let flush = |iv: &mut [LatencyHist; 2], from: u64, to: u64| -> bool {
        let Some(l) = &logs else {
            return false;
        };
        let Ok(fresh) = l.empty.try_recv() else {
            return false;
        };
        let pair = std::mem::replace(iv, fresh);
        let at = Duration::from_nanos(from - start_ns);
        let len = Duration::from_nanos(to - from);
        // The channel holds every pair there is, so this never fails.
        let _ = l.full.try_send((at, len, pair));
        true
    };
    while next <= end_ns && !stop.load(Ordering::Relaxed) {
        sleep_until_ns(next);
        let t = now_ns();
        if t < next {
            continue; // a signal woke us early: sleep again
        }
        let lat = t - next;
        out.wake.record(lat);
        iv[0].record(lat);
        out.wakeups += 1;
        if let Some(pw) = prev_wake {
            let j = (t - pw).abs_diff(t_ns);
            out.period_jitter.record(j);
            iv[1].record(j);
        }
        prev_wake = Some(t);
        next += t_ns;
        while next <= t {
            // A deadline passed while we were late: missed (if it lies
            // within the run).
            out.misses += (next <= end_ns) as u64;
            next += t_ns;
        }
        if t - iv_start >= IV_NS && flush(&mut iv, iv_start, t) {
            iv_start = t;
        }
    }
    let t = now_ns().max(iv_start);
    if let Some(l) = &logs {
        // The last, partial interval: the run is over, a blocking hand-off
        // costs nothing now.
        let (at, len) = (
            Duration::from_nanos(iv_start - start_ns),
            Duration::from_nanos(t - iv_start),
        );
        let _ = l.full.send((at, len, iv));
    }
    out
}

/// Run the timer baseline on every configured core at once.
pub fn timer_baseline(
    cfg: &TimerConfig,
    stop: &AtomicBool,
) -> Result<Vec<CoreTimer>, LatencyError> {
    cfg.validate()?;
    // A common start a little ahead, so every thread is set up in time.
    let start_ns = now_ns() + 20_000_000;
    let start_wall = SystemTime::now() + Duration::from_millis(20);
    let new_log = |core: usize, what: &str| {
        let c = [format!(
            "beliefbus jitter: timer {what}, core {core}, {} Hz, fifo {:?}",
            cfg.rate_hz, cfg.fifo
        )];
        HdrLog::new(start_wall, &c).map_err(|e| LatencyError::Output {
            path: "hdr log".into(),
            reason: e.to_string(),
        })
    };
    std::thread::scope(|s| {
        let mut jobs = Vec::with_capacity(cfg.cores.len());
        for &core in &cfg.cores {
            // The writer is spawned first, from this (unpinned, SCHED_OTHER)
            // thread, so it does not inherit the timer's core or priority.
            let (tx, writer) = if cfg.hdr_logs {
                let logs = [
                    new_log(core, "wake-up latency")?,
                    new_log(core, "period jitter")?,
                ];
                let (full_tx, full_rx) = crossbeam::channel::bounded(POOL + 1);
                let (empty_tx, empty_rx) = crossbeam::channel::bounded(POOL + 1);
                for _ in 0..POOL {
                    let _ = empty_tx.send([LatencyHist::new(), LatencyHist::new()]);
                }
                let w = std::thread::Builder::new()
                    .name(format!("timer-log-{core}"))
                    .spawn_scoped(s, move || log_writer(logs, full_rx, empty_tx))
                    .map_err(|e| LatencyError::Spawn(e.to_string()))?;
                (
                    Some(IntervalTx {
                        full: full_tx,
                        empty: empty_rx,
                    }),
                    Some(w),
                )
            } else {
                (None, None)
            };
            let t = std::thread::Builder::new()
                .name(format!("timer-{core}"))
                .spawn_scoped(s, move || timer_thread(cfg, core, start_ns, stop, tx))
                .map_err(|e| LatencyError::Spawn(e.to_string()))?;
            jobs.push((t, writer));
        }
        let mut out = Vec::with_capacity(jobs.len());
        for (t, w) in jobs {
            let mut c = t
                .join()
                .map_err(|_| LatencyError::Protocol("a timer thread panicked".into()))?;
            if let Some(w) = w {
                let [wake, jit] = w
                    .join()
                    .map_err(|_| LatencyError::Protocol("a log writer panicked".into()))??;
                c.wake_log = Some(wake);
                c.jitter_log = Some(jit);
            }
            out.push(c);
        }
        Ok(out)
    })
}
