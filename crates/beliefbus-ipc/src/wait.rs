//! Wake-ups without busy polling: a stage's loop blocks in an iceoryx2
//! WaitSet on the listeners of its inputs (the publisher sends, then
//! notifies), with a periodic tick for housekeeping and stop checks.
//! [`WakeMode::SpinThenBlock`] first polls the inputs for a bounded time — on
//! two cores only the latency-critical stages should use it.

use super::ports::{Message, Subscriber};
use super::slice::{SliceElem, SliceSubscriber};
use super::IpcError;
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// How a loop waits for its inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WakeMode {
    /// Block in the WaitSet until notified (default).
    Event,
    /// Poll the inputs for up to `spin` after each wake-up, then block.
    SpinThenBlock { spin: Duration },
}

/// Why the loop body runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wake {
    /// An input was notified or has data: drain the subscribers.
    Data,
    /// The periodic tick: housekeeping (stats), no data implied.
    Tick,
}

mod sealed {
    pub trait Sealed {
        fn listener(
            &self,
        ) -> Option<&iceoryx2::port::listener::Listener<iceoryx2::prelude::ipc::Service>>;
        fn has_data(&self) -> bool;
        /// The spin path's test: may take a message into the input's stash.
        fn poll(&self) -> bool;
        fn drain_wakeups(&self);
        fn refresh(&self);
    }
}

/// An input a loop can wait on (any [`Subscriber`]).
pub trait Wakeable: sealed::Sealed {}

impl<M: Message> sealed::Sealed for Subscriber<M> {
    fn listener(&self) -> Option<&Listener<ipc::Service>> {
        self.listener.as_ref()
    }
    fn has_data(&self) -> bool {
        Subscriber::has_data(self)
    }
    fn poll(&self) -> bool {
        Subscriber::poll(self)
    }
    fn drain_wakeups(&self) {
        Subscriber::drain_wakeups(self)
    }
    fn refresh(&self) {
        Subscriber::refresh(self)
    }
}
impl<M: Message> Wakeable for Subscriber<M> {}

impl<T: SliceElem> sealed::Sealed for SliceSubscriber<T> {
    fn listener(&self) -> Option<&Listener<ipc::Service>> {
        self.listener.as_ref()
    }
    fn has_data(&self) -> bool {
        SliceSubscriber::has_data(self)
    }
    // Snapshots are not latency-critical: no stash, the queue is scanned
    // twice.
    fn poll(&self) -> bool {
        SliceSubscriber::has_data(self)
    }
    fn drain_wakeups(&self) {
        SliceSubscriber::drain_wakeups(self)
    }
    fn refresh(&self) {
        SliceSubscriber::refresh(self)
    }
}
impl<T: SliceElem> Wakeable for SliceSubscriber<T> {}

/// Longest blocking wait between stop-flag checks (and connection refreshes).
pub const STOP_POLL: Duration = Duration::from_millis(50);

/// Run `body` until it breaks or `stop` is set: `body(Wake::Data)` whenever
/// an input was notified or (spin mode) has data, `body(Wake::Tick)` every
/// `tick`. The body must drain its subscribers on `Data`.
///
/// With no wakeable inputs (e.g. a stage that only has a timer) the loop just
/// ticks.
pub fn run_loop<F>(
    inputs: &[&dyn Wakeable],
    mode: WakeMode,
    tick: Duration,
    stop: &AtomicBool,
    mut body: F,
) -> Result<(), IpcError>
where
    F: FnMut(Wake) -> ControlFlow<()>,
{
    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| IpcError::Wait(format!("{e:?}")))?;
    let mut guards = Vec::with_capacity(inputs.len());
    for i in inputs {
        if let Some(l) = sealed::Sealed::listener(*i) {
            guards.push(
                waitset
                    .attach_notification(l)
                    .map_err(|e| IpcError::Wait(format!("{e:?}")))?,
            );
        }
    }
    let tick = tick.max(Duration::from_millis(1));
    let mut next_tick = Instant::now() + tick;
    let any_data = || inputs.iter().any(|i| sealed::Sealed::has_data(*i));
    // Spinning takes the first waiting message into its subscriber's stash:
    // one queue scan per message on the wake-up path.
    let any_polled = || inputs.iter().any(|i| sealed::Sealed::poll(*i));

    while !stop.load(Ordering::Relaxed) {
        let mut data = false;
        if let WakeMode::SpinThenBlock { spin } = mode {
            let until = Instant::now() + spin;
            let mut n = 0u32;
            loop {
                if any_polled() {
                    data = true;
                    break;
                }
                std::hint::spin_loop();
                n = n.wrapping_add(1);
                // (Same clock-read cadence as the bare spin of `latency`.)
                if n.is_multiple_of(64) && Instant::now() >= until {
                    break;
                }
            }
        }
        if !data {
            let now = Instant::now();
            let timeout = next_tick.saturating_duration_since(now).min(STOP_POLL);
            if guards.is_empty() {
                std::thread::sleep(timeout);
            } else {
                let mut woke = false;
                waitset
                    .wait_and_process_once_with_timeout(
                        |_| {
                            woke = true;
                            CallbackProgression::Continue
                        },
                        timeout,
                    )
                    .map_err(|e| IpcError::Wait(format!("{e:?}")))?;
                // A timeout with data waiting (e.g. a notification consumed
                // with an earlier batch) still runs the body.
                data = woke || any_data();
                if !woke {
                    // Idle: connect to publishers that appeared meanwhile.
                    for i in inputs {
                        sealed::Sealed::refresh(*i);
                    }
                }
            }
        }
        if data {
            for i in inputs {
                sealed::Sealed::drain_wakeups(*i);
            }
            if body(Wake::Data).is_break() {
                return Ok(());
            }
        }
        if Instant::now() >= next_tick {
            next_tick += tick;
            if next_tick < Instant::now() {
                next_tick = Instant::now() + tick;
            }
            if body(Wake::Tick).is_break() {
                return Ok(());
            }
        }
    }
    Ok(())
}
