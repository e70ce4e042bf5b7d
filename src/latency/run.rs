//! The pinging side of a latency run: it owns the run's prefix, starts the
//! pong process, walks the interleaved schedule, and cleans up.
//!
//! Schedule: with P paths there are 2P slots per round (each path through
//! ours and through bare). A slot lasts `slot` (at most a quarter of
//! `duration / 2P`, so every slot gets at least four rounds), and the run
//! has `⌊duration / (2P · slot)⌋` rounds after one unrecorded warm-up round
//! of short slots. Both processes derive the same slot sequence from
//! [`super::paths::slot`]; a [`SWITCH`] echo closes each slot.

use super::drive::{self, ping_bare, ping_ours, Recorder, SlotEnd, SLOT_WARMUP};
use super::hdr::HdrLog;
use super::load::LoadSample;
use super::paths::{slot, Impl, Mode, PathKind};
use super::report::{now_iso8601, LatencyReport, PathReport, RunInfo};
use super::stats::PctBlock;
use super::wire::{BareEnds, OursEnds, Side, QUIT};
use super::LatencyError;
use crate::ipc::cleanup;
use crate::rt::clock::now_ns;
use crate::rt::{sched, LatencyHist};
use std::io::BufRead;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant, SystemTime};

/// Settings of one latency run.
#[derive(Clone, Debug)]
pub struct LatencyConfig {
    pub mode: Mode,
    /// Polling time before blocking, hybrid mode.
    pub spin: Duration,
    pub paths: Vec<PathKind>,
    /// Measured time in total (all paths, ours and bare).
    pub duration: Duration,
    /// Longest slot.
    pub slot: Duration,
    /// Cores of the ping (this) and the pong process.
    pub cores: Option<(usize, usize)>,
    /// SCHED_FIFO priority for both processes (None: SCHED_OTHER).
    pub fifo: Option<u8>,
    /// Executable of the pong process and the arguments that select its
    /// pong mode (the `beliefbus` binary and `["latency-pong"]`).
    pub pong_exe: PathBuf,
    pub pong_args: Vec<String>,
    /// Keep one HdrHistogram interval per slot.
    pub hdr_logs: bool,
}

impl LatencyConfig {
    /// Defaults: event mode, every path, 10 s, 100 ms slots, cores 0 and 1
    /// when there are two, SCHED_OTHER, hybrid spin 50 µs.
    pub fn new(pong_exe: PathBuf, pong_args: Vec<String>) -> Self {
        let cores = (sched::available_cores() >= 2).then_some((0, 1));
        Self {
            mode: Mode::Event,
            spin: Duration::from_micros(50),
            paths: PathKind::all(),
            duration: Duration::from_secs(10),
            slot: Duration::from_millis(100),
            cores,
            fifo: None,
            pong_exe,
            pong_args,
            hdr_logs: false,
        }
    }

    /// Check the settings before anything starts.
    pub fn validate(&self) -> Result<(), LatencyError> {
        if self.paths.is_empty() {
            return Err(LatencyError::BadArg("no path to measure".into()));
        }
        if self.duration < Duration::from_millis(100) || self.duration > Duration::from_secs(86_400)
        {
            return Err(LatencyError::BadArg(
                "--duration must be between 0.1 and 86400 seconds".into(),
            ));
        }
        if self.slot < Duration::from_millis(2) {
            return Err(LatencyError::BadArg("slot must be at least 2 ms".into()));
        }
        if let Some(p) = self.fifo {
            if !(1..=99).contains(&p) {
                return Err(LatencyError::BadArg(format!(
                    "--fifo must be 1..=99, got {p}"
                )));
            }
        }
        if let Some((a, b)) = self.cores {
            let n = sched::available_cores();
            if a >= n || b >= n {
                return Err(LatencyError::BadArg(format!(
                    "--cores {a},{b}: this process may use cores 0..{}",
                    n - 1
                )));
            }
        }
        Ok(())
    }

    /// Slot length and number of measured rounds.
    pub fn schedule(&self) -> (Duration, usize) {
        let slots = 2 * self.paths.len();
        let total = self.duration.as_secs_f64();
        let slot = self
            .slot
            .as_secs_f64()
            .min(total / (4.0 * slots as f64))
            .max(0.002);
        let rounds = ((total / (slot * slots as f64)).floor() as usize).max(1);
        (Duration::from_secs_f64(slot), rounds)
    }
}

/// One path's results.
#[derive(Debug)]
pub struct PathRun {
    pub kind: PathKind,
    pub ours: LatencyHist,
    pub bare: LatencyHist,
    /// Interval logs (with `hdr_logs`).
    pub ours_log: Option<HdrLog>,
    pub bare_log: Option<HdrLog>,
}

/// A finished run.
#[derive(Debug)]
pub struct LatencyRun {
    pub paths: Vec<PathRun>,
    pub report: LatencyReport,
    /// Ctrl-C (the stop flag) ended it early.
    pub stopped: bool,
}

/// Removes the run's prefix when dropped (error paths included).
struct PrefixGuard(String);

impl Drop for PrefixGuard {
    fn drop(&mut self) {
        let _ = cleanup::remove_prefix(&self.0);
    }
}

/// Kills and reaps the pong process when dropped, unless it was reaped.
struct ChildGuard(Option<Child>);

impl ChildGuard {
    fn alive(&mut self) -> bool {
        match self.0.as_mut() {
            Some(c) => matches!(c.try_wait(), Ok(None)),
            None => false,
        }
    }

    /// Wait up to `timeout` for the child to exit, then kill it.
    fn finish(&mut self, timeout: Duration) -> Result<(), LatencyError> {
        let Some(mut c) = self.0.take() else {
            return Ok(());
        };
        let t = Instant::now();
        loop {
            match c.try_wait() {
                Ok(Some(status)) if status.success() => return Ok(()),
                Ok(Some(status)) => {
                    return Err(LatencyError::Spawn(format!("exited with {status}")))
                }
                Ok(None) if t.elapsed() < timeout => std::thread::sleep(Duration::from_millis(5)),
                _ => {
                    let _ = c.kill();
                    let _ = c.wait();
                    return Err(LatencyError::Spawn("did not exit; killed".into()));
                }
            }
        }
    }
}

impl ChildGuard {
    /// SIGTERM (the pong drops its ports and exits cleanly), then SIGKILL
    /// after 2 s; reaps it.
    fn terminate(&mut self) {
        if let Some(mut c) = self.0.take() {
            // SAFETY: signalling our own child by pid.
            unsafe { libc::kill(c.id() as libc::pid_t, libc::SIGTERM) };
            let t = Instant::now();
            while t.elapsed() < Duration::from_secs(2) {
                if let Ok(Some(_)) = c.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        self.terminate();
    }
}

/// Run a latency measurement; `stop` ends it early (Ctrl-C).
///
/// The measurement runs on a thread of its own (pinned and prioritised as
/// configured), so the caller's thread keeps its settings.
pub fn run(cfg: &LatencyConfig, stop: &AtomicBool) -> Result<LatencyRun, LatencyError> {
    cfg.validate()?;
    std::thread::scope(|s| {
        std::thread::Builder::new()
            .name("latency-ping".into())
            .spawn_scoped(s, || ping_side(cfg, stop))
            .map_err(|e| LatencyError::Spawn(e.to_string()))?
            .join()
            .map_err(|_| LatencyError::Protocol("the ping thread panicked".into()))?
    })
}

fn spawn_pong(cfg: &LatencyConfig, prefix: &str) -> Result<Child, LatencyError> {
    let names: Vec<String> = cfg.paths.iter().map(|p| p.name()).collect();
    let mut cmd = Command::new(&cfg.pong_exe);
    cmd.args(&cfg.pong_args)
        .arg("--prefix")
        .arg(prefix)
        .arg("--mode")
        .arg(cfg.mode.name())
        .arg("--spin-us")
        .arg(cfg.spin.as_micros().to_string())
        .arg("--paths")
        .arg(names.join(","));
    if let Some((_, b)) = cfg.cores {
        cmd.arg("--core").arg(b.to_string());
    }
    if let Some(p) = cfg.fifo {
        cmd.arg("--fifo").arg(p.to_string());
    }
    cmd.stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| LatencyError::Spawn(format!("cannot start {}: {e}", cfg.pong_exe.display())))
}

/// Wait for the pong's `ready` line.
fn await_ready(child: &mut ChildGuard, stop: &AtomicBool) -> Result<(), LatencyError> {
    let out = child
        .0
        .as_mut()
        .and_then(|c| c.stdout.take())
        .ok_or_else(|| LatencyError::Spawn("no stdout".into()))?;
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let r = std::io::BufReader::new(out).read_line(&mut line);
        let _ = tx.send(r.map(|_| line));
    });
    let t = Instant::now();
    loop {
        match rx.recv_timeout(Duration::from_millis(50)) {
            Ok(Ok(line)) if line.trim() == "ready" => return Ok(()),
            Ok(Ok(line)) if line.is_empty() => return Err(LatencyError::PeerDied),
            Ok(Ok(line)) => {
                return Err(LatencyError::Protocol(format!(
                    "unexpected pong output '{}'",
                    line.trim()
                )))
            }
            Ok(Err(e)) => return Err(LatencyError::Spawn(e.to_string())),
            Err(_) => {
                if stop.load(std::sync::atomic::Ordering::Relaxed) {
                    return Err(LatencyError::Protocol("stopped before start".into()));
                }
                if !child.alive() {
                    return Err(LatencyError::PeerDied);
                }
                if t.elapsed() > Duration::from_secs(60) {
                    return Err(LatencyError::Protocol("pong not ready after 60 s".into()));
                }
            }
        }
    }
}

fn ping_side(cfg: &LatencyConfig, stop: &AtomicBool) -> Result<LatencyRun, LatencyError> {
    let date = now_iso8601();
    let mut warnings = Vec::new();
    let prefix = cleanup::run_prefix();
    let _prefix_guard = PrefixGuard(prefix.clone());
    let mut ours = OursEnds::open(&prefix, Side::Ping, cfg.mode, &cfg.paths)?;
    // What earlier runs that were killed outright left behind (after the
    // ports opened: that set iceoryx2's log level).
    cleanup::sweep_stale_runs();
    let mut bare = BareEnds::open(&prefix, Side::Ping, cfg.mode, &cfg.paths)?;
    let mut child = ChildGuard(Some(spawn_pong(cfg, &prefix)?));
    await_ready(&mut child, stop)?;

    if let Some((a, _)) = cfg.cores {
        if let Err(e) = sched::pin_to_core(a) {
            warnings.push(format!("ping: cannot pin to core {a} ({e})"));
        }
    }
    let mut fifo = None;
    if let Some(p) = cfg.fifo {
        match sched::set_fifo(p) {
            Ok(()) => fifo = Some(p),
            Err(e) => warnings.push(format!(
                "ping: SCHED_FIFO {p} not permitted ({e}); running SCHED_OTHER"
            )),
        }
    }

    let n = cfg.paths.len();
    let (slot_len, rounds) = cfg.schedule();
    let warm_len = slot_len.min(Duration::from_millis(20));
    let wake = drive::ours_wake(cfg.mode, cfg.spin);
    let start_wall = SystemTime::now();
    let mut results: Vec<PathRun> = Vec::with_capacity(n);
    for kind in &cfg.paths {
        let log = |which: &str| -> Result<Option<HdrLog>, LatencyError> {
            if !cfg.hdr_logs {
                return Ok(None);
            }
            let comments = [format!(
                "beliefbus latency: path {} ({} B), {which}, mode {}, one-way = round trip / 2",
                kind.name(),
                kind.payload_bytes(),
                cfg.mode.name()
            )];
            HdrLog::new(start_wall, &comments)
                .map(Some)
                .map_err(|e| LatencyError::Output {
                    path: "hdr log".into(),
                    reason: e.to_string(),
                })
        };
        results.push(PathRun {
            kind: *kind,
            ours: LatencyHist::new(),
            bare: LatencyHist::new(),
            ours_log: log("ours")?,
            bare_log: log("bare")?,
        });
    }
    let mut slot_hist = LatencyHist::new();
    let load0 = LoadSample::now();
    let t_run = now_ns();
    let mut measured_ns = 0u64;
    let mut stopped = false;
    let mut k = 0usize;
    let mut alive = || child.alive();
    'run: for pass in 0..=rounds {
        let warm = pass == 0;
        let len = if warm { warm_len } else { slot_len };
        for _ in 0..2 * n {
            let (p, which) = slot(k, n);
            k += 1;
            slot_hist.reset();
            let t0 = now_ns();
            let until = t0 + len.as_nanos() as u64;
            let mut rec = Recorder::new((!warm).then_some(&mut slot_hist));
            let end = match which {
                Impl::Ours => ping_ours(
                    &mut *ours.tx[p],
                    &*ours.rx[p],
                    wake,
                    until,
                    &mut rec,
                    stop,
                    &mut alive,
                )?,
                Impl::Bare => ping_bare(
                    &mut *bare.tx[p],
                    &*bare.rx[p],
                    cfg.mode,
                    cfg.spin,
                    until,
                    &mut rec,
                    stop,
                    &mut alive,
                )?,
            };
            if end == SlotEnd::Stopped {
                stopped = true;
                break 'run;
            }
            if warm {
                continue;
            }
            let t1 = now_ns();
            measured_ns += t1 - t0;
            let r = &mut results[p];
            let (total, log) = match which {
                Impl::Ours => (&mut r.ours, &mut r.ours_log),
                Impl::Bare => (&mut r.bare, &mut r.bare_log),
            };
            total.merge(&slot_hist);
            if let Some(log) = log {
                log.add(
                    &slot_hist,
                    Duration::from_nanos(t0 - t_run),
                    Duration::from_nanos(t1 - t0),
                )
                .map_err(|e| LatencyError::Output {
                    path: "hdr log".into(),
                    reason: e.to_string(),
                })?;
            }
        }
    }
    if !stopped {
        // The pong now serves slot k: end the run there.
        let (p, which) = slot(k, n);
        match which {
            Impl::Ours => ours.tx[p].send(QUIT)?,
            Impl::Bare => bare.tx[p].send(QUIT)?,
        }
    }
    let finished = if stopped {
        // Ctrl-C may have reached only us: tell the pong.
        child.terminate();
        Ok(())
    } else {
        child.finish(Duration::from_secs(5))
    };
    let load = load0.until(&LoadSample::now());
    drop(ours);
    drop(bare);
    let _ = cleanup::remove_prefix(&prefix);
    let shm_left = cleanup::resources(&prefix).len();
    if !stopped {
        finished?;
    }

    let paths = results
        .iter()
        .map(|r| {
            PathReport::new(
                &r.kind.name(),
                cfg.mode.name(),
                r.kind.payload_bytes(),
                PctBlock::of(&r.ours),
                PctBlock::of(&r.bare),
            )
        })
        .collect();
    let report = LatencyReport {
        paths,
        run: RunInfo {
            date,
            mode: cfg.mode.name().into(),
            duration_s: measured_ns as f64 * 1e-9,
            slot_ms: slot_len.as_secs_f64() * 1e3,
            rounds,
            cores: cfg.cores.map(|(a, b)| [a, b]),
            fifo_priority: fifo,
            spin_us: cfg.spin.as_secs_f64() * 1e6,
            slot_warmup: SLOT_WARMUP,
            load,
            shm_left,
            warnings,
        },
    };
    Ok(LatencyRun {
        paths: results,
        report,
        stopped,
    })
}
