//! The pong process: echoes every sequence number on the path of the
//! current slot, following the same schedule as the ping
//! ([`super::paths::slot`]). Started by [`super::run::run`] as
//! `beliefbus latency-pong ...` (a hidden subcommand); prints `ready` once
//! all its ports exist, exits after [`super::wire::QUIT`], on SIGINT or
//! SIGTERM, or when its parent dies.

use super::drive::{ours_wake, pong_bare, pong_ours, SlotEnd};
use super::paths::{slot, Impl, Mode, PathKind};
use super::wire::{BareEnds, OursEnds, Side};
use super::LatencyError;
use crate::rt::sched;
use std::io::Write;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

/// Settings of the pong process (its command line).
#[derive(Clone, Debug)]
pub struct PongConfig {
    pub prefix: String,
    pub mode: Mode,
    pub spin: Duration,
    pub paths: Vec<PathKind>,
    pub core: Option<usize>,
    pub fifo: Option<u8>,
}

/// Run the pong until the ping quits, `stop` is raised or the parent dies.
pub fn serve(cfg: &PongConfig, stop: &AtomicBool) -> Result<(), LatencyError> {
    // Die with the parent (SIGTERM → the stop flag → clean exit).
    // SAFETY: prctl with PR_SET_PDEATHSIG only sets a signal number.
    unsafe { libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) };
    // SAFETY: getppid has no preconditions.
    let parent = unsafe { libc::getppid() };
    let mut parent_alive = || unsafe { libc::getppid() } == parent;
    if !parent_alive() {
        return Err(LatencyError::PeerDied);
    }
    if let Some(c) = cfg.core {
        if let Err(e) = sched::pin_to_core(c) {
            eprintln!("warning: pong: cannot pin to core {c} ({e})");
        }
    }
    if let Some(p) = cfg.fifo {
        if let Err(e) = sched::set_fifo(p) {
            eprintln!("warning: pong: SCHED_FIFO {p} not permitted ({e}); running SCHED_OTHER");
        }
    }
    crate::ipc::validate_prefix(&cfg.prefix)?;
    let mut ours = OursEnds::open(&cfg.prefix, Side::Pong, cfg.mode, &cfg.paths)?;
    let mut bare = BareEnds::open(&cfg.prefix, Side::Pong, cfg.mode, &cfg.paths)?;
    {
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "ready");
        let _ = out.flush();
    }
    let n = cfg.paths.len();
    let wake = ours_wake(cfg.mode, cfg.spin);
    for k in 0.. {
        let (p, which) = slot(k, n);
        let end = match which {
            Impl::Ours => pong_ours(
                &mut *ours.tx[p],
                &*ours.rx[p],
                wake,
                stop,
                &mut parent_alive,
            )?,
            Impl::Bare => pong_bare(
                &mut *bare.tx[p],
                &*bare.rx[p],
                cfg.mode,
                cfg.spin,
                stop,
                &mut parent_alive,
            )?,
        };
        if end != SlotEnd::Switch {
            break;
        }
        if !parent_alive() {
            break;
        }
    }
    Ok(())
}
