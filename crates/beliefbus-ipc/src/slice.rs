//! Slice channels: variable-length arrays of plain numbers (`u8`, `u32`,
//! `u64`, `f64`) published **in place** — the publisher loans a slice in
//! shared memory, writes it there and sends an offset; a subscriber reads it
//! where it lies. Nothing is copied or serialised on the way, so the cost of
//! a send does not grow with the slice length (DESIGN.md: "large data go on
//! slice services, written once in place by the publisher and read in place
//! by subscribers"). Chain snapshots and the latency tool's
//! zero-copy paths use them.
//!
//! A slice channel is `beliefbus/<instance>/<channel>` like a message
//! channel, with its own element type, maximum length and [`SliceQos`].
//! Memory is bounded: the data segment holds a fixed number of slices of the
//! maximum length (static allocation strategy), so a loan beyond the
//! maximum is an error, never a reallocation.

use super::ports::Qos;
use super::{Bus, IpcError};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;
use std::fmt::Debug;

mod sealed {
    pub trait Sealed {}
}

/// An element type of a slice channel: a plain number for which every bit
/// pattern is a valid value (this is what makes in-place loans sound, see
/// [`SlicePublisher::publish_with`]).
pub trait SliceElem: sealed::Sealed + ZeroCopySend + Copy + Default + Debug + 'static {}

macro_rules! elem {
    ($($t:ty),*) => {$(
        impl sealed::Sealed for $t {}
        impl SliceElem for $t {}
    )*};
}
elem!(u8, u32, u64, f64);

/// Quality of service of a slice channel (identical for every participant).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SliceQos {
    /// Largest slice, in elements.
    pub max_len: usize,
    /// Buffer, history and port limits, as for message channels.
    pub qos: Qos,
}

impl SliceQos {
    /// A latest-value slice channel (history 1, buffer 1: a subscriber
    /// always reads the newest slice) of at most `max_len` elements, for a
    /// few publishers and subscribers.
    pub const fn latest(max_len: usize) -> Self {
        Self {
            max_len,
            qos: Qos {
                history: 1,
                max_buffer: 2,
                default_buffer: 1,
                max_publishers: 1,
                max_subscribers: 4,
                max_nodes: 8,
            },
        }
    }
}

fn service_name(name: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(name).map_err(|e| IpcError::InvalidName {
        what: "service name",
        value: name.to_string(),
        reason: format!("{e:?}"),
    })
}

type SliceFactory<T> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [T], ()>;

fn slice_service<T: SliceElem>(
    node: &Node<ipc::Service>,
    name: &ServiceName,
    q: &SliceQos,
) -> Result<SliceFactory<T>, IpcError> {
    node.service_builder(name)
        .publish_subscribe::<[T]>()
        .history_size(q.qos.history)
        .subscriber_max_buffer_size(q.qos.max_buffer)
        .enable_safe_overflow(true)
        .max_publishers(q.qos.max_publishers)
        .max_subscribers(q.qos.max_subscribers)
        .max_nodes(q.qos.max_nodes)
        .open_or_create()
        .map_err(|e| IpcError::Service {
            service: name.as_str().to_string(),
            reason: format!("{e:?}"),
        })
}

fn event_service(
    node: &Node<ipc::Service>,
    name: &ServiceName,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>, IpcError> {
    node.service_builder(name)
        .event()
        .open_or_create()
        .map_err(|e| IpcError::Service {
            service: format!("{} (event)", name.as_str()),
            reason: format!("{e:?}"),
        })
}

/// Publishes slices of `T`, written in place, and wakes listeners.
pub struct SlicePublisher<T: SliceElem> {
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, [T], ()>,
    notifier: Notifier<ipc::Service>,
    service: String,
    max_len: usize,
    sent: u64,
}

impl<T: SliceElem> Debug for SlicePublisher<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SlicePublisher")
            .field("service", &self.service)
            .field("max_len", &self.max_len)
            .field("sent", &self.sent)
            .finish()
    }
}

impl<T: SliceElem> SlicePublisher<T> {
    /// Loan a slice of `len` elements in shared memory, let `write` fill it
    /// in place, send it and notify listeners. Nothing is copied.
    ///
    /// The slice's previous contents are unspecified (zeros, or what an
    /// earlier sample left there): `write` must set every element a reader
    /// will look at.
    pub fn publish_with<R>(
        &mut self,
        len: usize,
        write: impl FnOnce(&mut [T]) -> R,
    ) -> Result<R, IpcError> {
        if len > self.max_len {
            return Err(IpcError::Send {
                service: self.service.clone(),
                reason: format!(
                    "slice of {len} elements exceeds the maximum {}",
                    self.max_len
                ),
            });
        }
        let send_err = |e: String| IpcError::Send {
            service: self.service.clone(),
            reason: e,
        };
        let sample = self
            .publisher
            .loan_slice_uninit(len)
            .map_err(|e| send_err(format!("{e:?}")))?;
        // SAFETY: `T` is a plain number type for which every bit pattern is
        // valid (sealed `SliceElem`), and the loaned memory is always
        // defined: POSIX shared memory is zero-filled when the segment is
        // created, and afterwards holds what earlier samples wrote. Marking
        // it initialised without writing every element (which would cost
        // O(len)) therefore yields valid, merely unspecified, values.
        let mut sample = unsafe { sample.assume_init() };
        let r = write(sample.payload_mut());
        sample.send().map_err(|e| send_err(format!("{e:?}")))?;
        self.sent += 1;
        // A failed wake-up is not a failed send (see `Publisher::publish`).
        let _ = self.notifier.notify();
        Ok(r)
    }

    /// Largest slice this publisher can loan, in elements.
    pub fn max_len(&self) -> usize {
        self.max_len
    }

    /// Slices sent so far.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// The service name.
    pub fn service(&self) -> &str {
        &self.service
    }
}

/// Receives slices of `T`, read in place.
pub struct SliceSubscriber<T: SliceElem> {
    subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, [T], ()>,
    pub(super) listener: Option<Listener<ipc::Service>>,
    service: String,
}

impl<T: SliceElem> Debug for SliceSubscriber<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SliceSubscriber")
            .field("service", &self.service)
            .field("wakes", &self.listener.is_some())
            .finish()
    }
}

/// A received slice held in place until dropped (the chain filter reads its
/// active snapshot from it for as long as it filters on it). While held, the
/// publisher cannot reuse that memory; a subscriber may hold at most the
/// service's `subscriber_max_borrowed_samples` (iceoryx2 default 2) at once,
/// and a held sample stays mapped even if its publisher dies.
pub struct SliceSample<T: SliceElem> {
    sample: iceoryx2::sample::Sample<ipc::Service, [T], ()>,
}

impl<T: SliceElem> Debug for SliceSample<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SliceSample")
            .field("len", &self.sample.payload().len())
            .finish()
    }
}

impl<T: SliceElem> AsRef<[T]> for SliceSample<T> {
    fn as_ref(&self) -> &[T] {
        self.sample.payload()
    }
}

impl<T: SliceElem> SliceSubscriber<T> {
    /// Read the oldest unread slice in place with `read`; the sample is
    /// released when `read` returns.
    pub fn receive_with<R>(&self, read: impl FnOnce(&[T]) -> R) -> Result<Option<R>, IpcError> {
        match self.subscriber.receive() {
            Ok(Some(s)) => Ok(Some(read(s.payload()))),
            Ok(None) => Ok(None),
            Err(e) => Err(IpcError::Receive {
                service: self.service.clone(),
                reason: format!("{e:?}"),
            }),
        }
    }

    /// Take the oldest unread slice and hold it in place (see
    /// [`SliceSample`]).
    pub fn receive_sample(&self) -> Result<Option<SliceSample<T>>, IpcError> {
        match self.subscriber.receive() {
            Ok(s) => Ok(s.map(|sample| SliceSample { sample })),
            Err(e) => Err(IpcError::Receive {
                service: self.service.clone(),
                reason: format!("{e:?}"),
            }),
        }
    }

    /// Whether a slice is waiting.
    pub fn has_data(&self) -> bool {
        self.subscriber.has_samples().unwrap_or(false)
    }

    /// Consume pending wake-up notifications.
    pub fn drain_wakeups(&self) {
        if let Some(l) = &self.listener {
            let _ = l.try_wait(|_| {});
        }
    }

    /// Connect to publishers that appeared since the last receive.
    pub fn refresh(&self) {
        use iceoryx2::port::update_connections::UpdateConnections;
        let _ = self.subscriber.update_connections();
    }

    /// The service name.
    pub fn service(&self) -> &str {
        &self.service
    }
}

impl Bus {
    /// A publisher on the slice channel `channel` with QoS `q`; it can loan
    /// slices of up to `q.max_len` elements.
    pub fn slice_publisher<T: SliceElem>(
        &self,
        channel: &str,
        q: &SliceQos,
    ) -> Result<SlicePublisher<T>, IpcError> {
        let name = self.service_name(channel);
        let sn = service_name(&name)?;
        let port_err = |port, e: String| IpcError::Port {
            port,
            service: name.clone(),
            reason: e,
        };
        let publisher = slice_service::<T>(&self.node, &sn, q)?
            .publisher_builder()
            .initial_max_slice_len(q.max_len.max(1))
            .allocation_strategy(AllocationStrategy::Static)
            .create()
            .map_err(|e| port_err("slice publisher", format!("{e:?}")))?;
        let notifier = event_service(&self.node, &sn)?
            .notifier_builder()
            .create()
            .map_err(|e| port_err("notifier", format!("{e:?}")))?;
        Ok(SlicePublisher {
            publisher,
            notifier,
            service: name.clone(),
            max_len: q.max_len.max(1),
            sent: 0,
        })
    }

    /// A subscriber on the slice channel `channel` with the channel's
    /// default buffer and, if `wake`, a listener (for [`super::run_loop`]).
    pub fn slice_subscriber<T: SliceElem>(
        &self,
        channel: &str,
        q: &SliceQos,
        wake: bool,
    ) -> Result<SliceSubscriber<T>, IpcError> {
        let name = self.service_name(channel);
        let sn = service_name(&name)?;
        let port_err = |port, e: String| IpcError::Port {
            port,
            service: name.clone(),
            reason: e,
        };
        let subscriber = slice_service::<T>(&self.node, &sn, q)?
            .subscriber_builder()
            .buffer_size(q.qos.default_buffer.clamp(1, q.qos.max_buffer))
            .create()
            .map_err(|e| port_err("slice subscriber", format!("{e:?}")))?;
        let listener = if wake {
            Some(
                event_service(&self.node, &sn)?
                    .listener_builder()
                    .create()
                    .map_err(|e| port_err("listener", format!("{e:?}")))?,
            )
        } else {
            None
        };
        Ok(SliceSubscriber {
            subscriber,
            listener,
            service: name,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{cleanup, BusConfig};

    fn bus_cfg() -> BusConfig {
        BusConfig {
            prefix: cleanup::run_prefix(),
            instance: "slice".into(),
        }
    }

    #[test]
    fn slices_are_written_and_read_in_place_across_lengths() {
        let cfg = bus_cfg();
        {
            let bus = Bus::open(&cfg, "t").unwrap();
            let q = SliceQos::latest(1 << 16);
            let mut p = bus.slice_publisher::<f64>("chain", &q).unwrap();
            let s = bus.slice_subscriber::<f64>("chain", &q, false).unwrap();
            for len in [1usize, 7, 4096, 1 << 16] {
                p.publish_with(len, |xs| {
                    for (i, x) in xs.iter_mut().enumerate() {
                        *x = i as f64 * 0.5;
                    }
                })
                .unwrap();
                let got = s
                    .receive_with(|xs| {
                        assert_eq!(xs.len(), len);
                        xs.iter().enumerate().all(|(i, &x)| x == i as f64 * 0.5)
                    })
                    .unwrap();
                assert_eq!(got, Some(true));
            }
            assert_eq!(p.sent(), 4);
            // Beyond the maximum: a typed error, nothing sent.
            let e = p.publish_with(q.max_len + 1, |_| ()).unwrap_err();
            assert!(matches!(e, IpcError::Send { .. }), "{e}");
            assert_eq!(p.sent(), 4);
            assert!(s.receive_with(|_| ()).unwrap().is_none());
        }
        cleanup::remove_prefix(&cfg.prefix).unwrap();
        assert!(cleanup::resources(&cfg.prefix).is_empty());
    }

    #[test]
    fn a_slice_wakes_a_run_loop() {
        use crate::{run_loop, Wake, WakeMode};
        use std::ops::ControlFlow;
        use std::sync::atomic::AtomicBool;
        use std::time::Duration;
        let cfg = bus_cfg();
        {
            let bus = Bus::open(&cfg, "t").unwrap();
            let q = SliceQos::latest(1024);
            let mut p = bus.slice_publisher::<u8>("bytes", &q).unwrap();
            let s = bus.slice_subscriber::<u8>("bytes", &q, true).unwrap();
            p.publish_with(1024, |b| b.fill(7)).unwrap();
            let stop = AtomicBool::new(false);
            let (mut got, mut ticks) = (None, 0);
            run_loop(
                &[&s],
                WakeMode::Event,
                Duration::from_millis(10),
                &stop,
                |w| {
                    match w {
                        Wake::Data => got = s.receive_with(|b| (b.len(), b[1023])).unwrap(),
                        Wake::Tick => ticks += 1,
                    }
                    // Give up after a second of ticks rather than hang.
                    if got.is_some() || ticks > 100 {
                        ControlFlow::Break(())
                    } else {
                        ControlFlow::Continue(())
                    }
                },
            )
            .unwrap();
            assert_eq!(got, Some((1024, 7)));
            assert!(!s.has_data());
        }
        cleanup::remove_prefix(&cfg.prefix).unwrap();
    }
}
