//! SIGINT/SIGTERM → a stop flag.
//!
//! iceoryx2 installs its own handlers for SIGINT/SIGTERM the first time its
//! signal machinery is touched (e.g. when it zeroes a new shared-memory
//! segment), which would silently replace ours. So we initialise iceoryx2's
//! handler table first and install ours afterwards; iceoryx2 never registers
//! again, and our handler only stores to an atomic (async-signal-safe).

use std::sync::atomic::{AtomicBool, Ordering};

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_sig: libc::c_int) {
    STOP.store(true, Ordering::SeqCst);
}

/// Install SIGINT and SIGTERM handlers that set the returned flag. Idempotent.
pub fn install_stop_handler() -> &'static AtomicBool {
    // Force iceoryx2's one-time signal registration now, before ours.
    let _ = iceoryx2_bb_posix::signal::SignalHandler::last_signal();
    // SAFETY: a plain sigaction with a handler that only stores an atomic.
    unsafe {
        let mut sa: libc::sigaction = std::mem::zeroed();
        sa.sa_sigaction = on_signal as *const () as libc::sighandler_t;
        libc::sigemptyset(&mut sa.sa_mask);
        sa.sa_flags = 0; // no SA_RESTART: blocking waits return EINTR
        libc::sigaction(libc::SIGINT, &sa, std::ptr::null_mut());
        libc::sigaction(libc::SIGTERM, &sa, std::ptr::null_mut());
    }
    &STOP
}
