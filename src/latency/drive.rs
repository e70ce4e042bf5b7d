//! One slot of the ping-pong, on either side, for either implementation.
//!
//! Ping: `t₀ = now; send(seq); wait for seq back; t₁ = now`; record
//! `(t₁ − t₀)/2`; repeat until the slot's end, then send [`SWITCH`] and wait
//! for its echo. Pong: echo every sequence number it receives; after
//! echoing `SWITCH` it moves to the next slot, after [`QUIT`] it ends.
//!
//! Ours waits the way a beliefbus stage waits — [`run_loop`] with the
//! mode's [`WakeMode`]. Bare waits the way iceoryx2's own examples do: a
//! `Listener::timed_wait` (event), a `receive` poll (spin), or a bounded
//! poll then the listener (hybrid).

use super::stats::one_way_ns;
use super::wire::{BareRx, OursRx, Tx, QUIT, SWITCH};
use super::LatencyError;
use crate::ipc::{run_loop, Wake, WakeMode};
use crate::rt::clock::now_ns;
use crate::rt::LatencyHist;
use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// How long without an answer before the peer counts as gone.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(10);
/// Housekeeping period of the waits (stop flag, peer liveness).
const TICK: Duration = Duration::from_millis(50);
/// Round trips dropped at the start of each slot (caches and branch
/// predictors still hold the previous slot's path).
pub const SLOT_WARMUP: u64 = 8;

/// Where a slot's one-way latencies go.
pub struct Recorder<'a> {
    /// None: a warm-up slot, nothing is recorded.
    pub hist: Option<&'a mut LatencyHist>,
    seen: u64,
}

impl<'a> Recorder<'a> {
    pub fn new(hist: Option<&'a mut LatencyHist>) -> Self {
        Self { hist, seen: 0 }
    }

    fn record(&mut self, one_way: u64) {
        self.seen += 1;
        if self.seen > SLOT_WARMUP {
            if let Some(h) = self.hist.as_deref_mut() {
                h.record(one_way);
            }
        }
    }
}

/// How a slot ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SlotEnd {
    /// The slot ran its course ([`SWITCH`] echoed / received).
    Switch,
    /// The pong received [`QUIT`].
    Quit,
    /// The stop flag was raised.
    Stopped,
}

/// How the ping side's waits learn that the peer died.
pub type Alive<'a> = &'a mut dyn FnMut() -> bool;

/// The wake mode of ours for a run mode.
pub fn ours_wake(mode: super::Mode, spin: Duration) -> WakeMode {
    match mode {
        super::Mode::Event => WakeMode::Event,
        // No listener exists in spin mode: spin "forever" (1 s between
        // stop checks); the loop never blocks while a reply is in flight.
        super::Mode::Spin => WakeMode::SpinThenBlock {
            spin: Duration::from_secs(1),
        },
        super::Mode::Hybrid => WakeMode::SpinThenBlock { spin },
    }
}

/// Ping side of one slot, ours.
pub fn ping_ours(
    tx: &mut dyn Tx,
    rx: &dyn OursRx,
    wake: WakeMode,
    until_ns: u64,
    rec: &mut Recorder,
    stop: &AtomicBool,
    alive: Alive,
) -> Result<SlotEnd, LatencyError> {
    let mut seq = 0u64;
    let mut expect = 0u64;
    let mut err: Option<LatencyError> = None;
    let mut end = SlotEnd::Stopped;
    let mut t0 = now_ns();
    tx.send(expect)?;
    run_loop(&[rx.wakeable()], wake, TICK, stop, |w| {
        match w {
            Wake::Data => loop {
                let got = match rx.recv() {
                    Ok(Some(s)) => s,
                    Ok(None) => break,
                    Err(e) => {
                        err = Some(e);
                        return ControlFlow::Break(());
                    }
                };
                if got != expect {
                    continue; // a stale echo: not ours to time
                }
                let t1 = now_ns();
                if expect == SWITCH {
                    end = SlotEnd::Switch;
                    return ControlFlow::Break(());
                }
                rec.record(one_way_ns(t0, t1));
                if t1 >= until_ns {
                    expect = SWITCH;
                } else {
                    seq += 1;
                    expect = seq;
                }
                t0 = now_ns();
                if let Err(e) = tx.send(expect) {
                    err = Some(e);
                    return ControlFlow::Break(());
                }
            },
            Wake::Tick => {
                if let Some(e) = overdue(t0, alive) {
                    err = Some(e);
                    return ControlFlow::Break(());
                }
            }
        }
        ControlFlow::Continue(())
    })?;
    match err {
        Some(e) => Err(e),
        None => Ok(end),
    }
}

/// Pong side of one slot, ours.
pub fn pong_ours(
    tx: &mut dyn Tx,
    rx: &dyn OursRx,
    wake: WakeMode,
    stop: &AtomicBool,
    parent_alive: Alive,
) -> Result<SlotEnd, LatencyError> {
    let mut err: Option<LatencyError> = None;
    let mut end = SlotEnd::Stopped;
    run_loop(&[rx.wakeable()], wake, TICK, stop, |w| {
        match w {
            Wake::Data => loop {
                let got = match rx.recv() {
                    Ok(Some(s)) => s,
                    Ok(None) => break,
                    Err(e) => {
                        err = Some(e);
                        return ControlFlow::Break(());
                    }
                };
                if let Err(e) = tx.send(got) {
                    err = Some(e);
                    return ControlFlow::Break(());
                }
                if got == SWITCH || got == QUIT {
                    end = if got == QUIT {
                        SlotEnd::Quit
                    } else {
                        SlotEnd::Switch
                    };
                    return ControlFlow::Break(());
                }
            },
            Wake::Tick => {
                if !parent_alive() {
                    return ControlFlow::Break(());
                }
            }
        }
        ControlFlow::Continue(())
    })?;
    match err {
        Some(e) => Err(e),
        None => Ok(end),
    }
}

/// The peer is overdue when no answer came for [`REPLY_TIMEOUT`], or dead.
fn overdue(t0_ns: u64, alive: Alive) -> Option<LatencyError> {
    if !alive() {
        return Some(LatencyError::PeerDied);
    }
    if now_ns().saturating_sub(t0_ns) > REPLY_TIMEOUT.as_nanos() as u64 {
        return Some(LatencyError::Protocol(format!(
            "no answer for {} s",
            REPLY_TIMEOUT.as_secs()
        )));
    }
    None
}

/// Wait for the next sequence number on a bare receiving end; None when
/// stopped. `peer_ok` is asked at every housekeeping tick.
fn bare_wait(
    rx: &dyn BareRx,
    mode: super::Mode,
    spin: Duration,
    stop: &AtomicBool,
    peer_ok: &mut dyn FnMut() -> Result<(), LatencyError>,
) -> Result<Option<u64>, LatencyError> {
    if mode != super::Mode::Event {
        // Spin: poll for up to `spin` (forever in spin mode, with
        // housekeeping every TICK).
        let start = Instant::now();
        let mut next_check = start + TICK;
        let mut n = 0u32;
        loop {
            if let Some(s) = rx.recv()? {
                if let Some(l) = rx.listener() {
                    // Consume the notification that came with it.
                    let _ = l.try_wait(|_| {});
                }
                return Ok(Some(s));
            }
            std::hint::spin_loop();
            n = n.wrapping_add(1);
            if n.is_multiple_of(64) {
                let now = Instant::now();
                if mode == super::Mode::Hybrid && now >= start + spin {
                    break;
                }
                if now >= next_check {
                    next_check = now + TICK;
                    if stop.load(Ordering::Relaxed) {
                        return Ok(None);
                    }
                    peer_ok()?;
                }
            }
        }
    }
    let Some(l) = rx.listener() else {
        return Err(LatencyError::Protocol(
            "a blocking wait needs a listener".into(),
        ));
    };
    loop {
        l.timed_wait(|_| {}, TICK)
            .map_err(|e| LatencyError::Bare(format!("wait: {e:?}")))?;
        if let Some(s) = rx.recv()? {
            return Ok(Some(s));
        }
        if stop.load(Ordering::Relaxed) {
            return Ok(None);
        }
        peer_ok()?;
    }
}

/// Ping side of one slot, bare.
pub fn ping_bare(
    tx: &mut dyn Tx,
    rx: &dyn BareRx,
    mode: super::Mode,
    spin: Duration,
    until_ns: u64,
    rec: &mut Recorder,
    stop: &AtomicBool,
    alive: Alive,
) -> Result<SlotEnd, LatencyError> {
    let mut seq = 0u64;
    let mut expect = 0u64;
    loop {
        let t0 = now_ns();
        tx.send(expect)?;
        let mut peer_ok = || match overdue(t0, alive) {
            Some(e) => Err(e),
            None => Ok(()),
        };
        loop {
            match bare_wait(rx, mode, spin, stop, &mut peer_ok)? {
                None => return Ok(SlotEnd::Stopped),
                Some(s) if s == expect => break,
                Some(_) => continue, // a stale echo
            }
        }
        let t1 = now_ns();
        if expect == SWITCH {
            return Ok(SlotEnd::Switch);
        }
        rec.record(one_way_ns(t0, t1));
        if t1 >= until_ns {
            expect = SWITCH;
        } else {
            seq += 1;
            expect = seq;
        }
    }
}

/// Pong side of one slot, bare.
pub fn pong_bare(
    tx: &mut dyn Tx,
    rx: &dyn BareRx,
    mode: super::Mode,
    spin: Duration,
    stop: &AtomicBool,
    parent_alive: Alive,
) -> Result<SlotEnd, LatencyError> {
    let mut peer_ok = || {
        if parent_alive() {
            Ok(())
        } else {
            Err(LatencyError::PeerDied)
        }
    };
    loop {
        let Some(got) = bare_wait(rx, mode, spin, stop, &mut peer_ok)? else {
            return Ok(SlotEnd::Stopped);
        };
        tx.send(got)?;
        if got == SWITCH {
            return Ok(SlotEnd::Switch);
        }
        if got == QUIT {
            return Ok(SlotEnd::Quit);
        }
    }
}
