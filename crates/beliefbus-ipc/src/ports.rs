//! Typed ports: a publisher paired with a notifier, a subscriber paired with
//! an (optional) listener, over one channel's pub-sub and event services of
//! the same name.

use super::messages::*;
use super::IpcError;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;
use std::fmt::Debug;

/// Quality of service of a channel: identical for every participant, so any
/// of them may create the service and the others open it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Qos {
    /// Samples a late subscriber receives on connection.
    pub history: usize,
    /// Largest subscriber buffer the service allows.
    pub max_buffer: usize,
    /// Buffer of a stage's subscriber (1 = latest value).
    pub default_buffer: usize,
    pub max_publishers: usize,
    pub max_subscribers: usize,
    pub max_nodes: usize,
}

mod sealed {
    pub trait Sealed: iceoryx2::prelude::ZeroCopySend {}
}

/// A message type bound to its channel. Implemented by the message types of
/// [`super::messages`] only.
pub trait Message: sealed::Sealed + Copy + Debug + Default + 'static {
    /// Channel name (last component of the service name).
    const CHANNEL: &'static str;
    /// The channel's QoS.
    const QOS: Qos;
    /// The message's header fields.
    fn header(&self) -> Header;
}

macro_rules! message {
    ($t:ty, $channel:literal, $qos:expr, |$m:ident| $header:expr) => {
        impl sealed::Sealed for $t {}
        impl Message for $t {
            const CHANNEL: &'static str = $channel;
            const QOS: Qos = $qos;
            fn header(&self) -> Header {
                let $m = self;
                $header
            }
        }
    };
}

// Many publishers (one per sensor), a generous queue: ingest sorts by time.
message!(
    SensorSample,
    "sensor",
    Qos {
        history: 0,
        max_buffer: 256,
        default_buffer: 64,
        max_publishers: 16,
        max_subscribers: 8,
        max_nodes: 32,
    },
    |m| m.header()
);
// Every observation should be filtered: after a stall of its core the
// plant catches up by up to `plant.catch_up_periods` at once, and the
// filter's queue is sized to hold such a burst whole (at most 256). A
// stalled filter still never holds back ingest: a full queue drops its
// oldest, which the filter counts as lost.
message!(
    Observation,
    "obs",
    Qos {
        history: 0,
        max_buffer: 256,
        default_buffer: 32,
        max_publishers: 2,
        max_subscribers: 8,
        max_nodes: 20,
    },
    |m| m.header
);
// Latest value; the large max buffer is for the launcher's polling monitor.
message!(
    Belief,
    "belief",
    Qos {
        history: 1,
        max_buffer: 256,
        default_buffer: 1,
        max_publishers: 2,
        max_subscribers: 6,
        max_nodes: 20,
    },
    |m| m.header
);
message!(
    Control,
    "control",
    Qos {
        history: 1,
        max_buffer: 256,
        default_buffer: 1,
        max_publishers: 2,
        max_subscribers: 6,
        max_nodes: 20,
    },
    |m| m.header
);
message!(
    Truth,
    "truth",
    Qos {
        history: 0,
        max_buffer: 512,
        default_buffer: 512,
        max_publishers: 2,
        max_subscribers: 4,
        max_nodes: 20,
    },
    |m| m.header
);
message!(
    StageStats,
    "stats",
    Qos {
        history: 0,
        max_buffer: 64,
        default_buffer: 64,
        max_publishers: 16,
        max_subscribers: 4,
        max_nodes: 32,
    },
    |m| m.header
);

fn service_name(name: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(name).map_err(|e| IpcError::InvalidName {
        what: "service name",
        value: name.to_string(),
        reason: format!("{e:?}"),
    })
}

fn pubsub<M: Message>(
    node: &Node<ipc::Service>,
    name: &ServiceName,
) -> Result<
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, M, ()>,
    IpcError,
> {
    let q = M::QOS;
    node.service_builder(name)
        .publish_subscribe::<M>()
        .history_size(q.history)
        .subscriber_max_buffer_size(q.max_buffer)
        .enable_safe_overflow(true)
        .max_publishers(q.max_publishers)
        .max_subscribers(q.max_subscribers)
        .max_nodes(q.max_nodes)
        .open_or_create()
        .map_err(|e| IpcError::Service {
            service: name.as_str().to_string(),
            reason: format!("{e:?}"),
        })
}

fn event(
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

/// Publishes `M` on its channel and wakes the channel's listeners.
pub struct Publisher<M: Message> {
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, M, ()>,
    notifier: Notifier<ipc::Service>,
    /// The event service, to see whether anyone listens.
    events: iceoryx2::service::port_factory::event::PortFactory<ipc::Service>,
    service: String,
    sent: u64,
    notify_failures: u64,
    notified: u64,
}

impl<M: Message> Debug for Publisher<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Publisher")
            .field("service", &self.service)
            .field("sent", &self.sent)
            .finish()
    }
}

impl<M: Message> Publisher<M> {
    pub(super) fn open(node: &Node<ipc::Service>, name: &str) -> Result<Self, IpcError> {
        let sn = service_name(name)?;
        let port_err = |port, e: String| IpcError::Port {
            port,
            service: name.to_string(),
            reason: e,
        };
        let publisher = pubsub::<M>(node, &sn)?
            .publisher_builder()
            .create()
            .map_err(|e| port_err("publisher", format!("{e:?}")))?;
        let events = event(node, &sn)?;
        let notifier = events
            .notifier_builder()
            .create()
            .map_err(|e| port_err("notifier", format!("{e:?}")))?;
        Ok(Self {
            publisher,
            notifier,
            events,
            service: name.to_string(),
            sent: 0,
            notify_failures: 0,
            notified: 0,
        })
    }

    /// Send a copy of `msg` to every subscriber, then notify their listeners.
    /// Never blocks: a full subscriber buffer drops its oldest sample.
    pub fn publish(&mut self, msg: &M) -> Result<(), IpcError> {
        self.publisher.send_copy(*msg).map_err(|e| IpcError::Send {
            service: self.service.clone(),
            reason: format!("{e:?}"),
        })?;
        self.sent += 1;
        // No listener (every subscriber spins or polls): nothing to wake,
        // so skip the notifier's pass over its connection slots (one
        // atomic read instead; a listener attaching meanwhile is what
        // `notify` itself would miss too, and its loop's periodic data
        // check finds the sample). A failed wake-up is not a failed send:
        // the sample is delivered and a polling or spinning subscriber
        // still finds it.
        if self.events.dynamic_config().number_of_listeners() > 0 {
            match self.notifier.notify() {
                Ok(_) => self.notified += 1,
                Err(_) => self.notify_failures += 1,
            }
        }
        Ok(())
    }

    /// Sends that notified listeners (those with none to wake skip it).
    pub fn notified(&self) -> u64 {
        self.notified
    }

    /// Messages sent so far.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// Notifications that failed (samples were still delivered).
    pub fn notify_failures(&self) -> u64 {
        self.notify_failures
    }

    /// The service name.
    pub fn service(&self) -> &str {
        &self.service
    }
}

/// Who published a received sample, as iceoryx2 records it: the
/// publishing port, its node, and the process that created that node.
///
/// The port id is the subscriber's own record of the connection the sample
/// came through; the node id and pid are in the sample's header, written by
/// the publisher's iceoryx2 library (a process that writes the shared
/// memory by hand instead of through iceoryx2 can forge them; see
/// `docs/security.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Origin {
    pub publisher: u128,
    pub node: u128,
    /// The node's process (0: unknown).
    pub pid: i32,
}

/// Receives `M` from its channel.
pub struct Subscriber<M: Message> {
    subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, M, ()>,
    /// The service, to see which publishers are connected.
    factory: iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, M, ()>,
    pub(super) listener: Option<Listener<ipc::Service>>,
    service: String,
    /// One sample taken off the queue by a spinning loop's poll
    /// ([`Self::poll`]), handed out first by the next receive: the spin
    /// path scans the queue once per message, as a bare `receive` loop does,
    /// instead of `has_samples` and then `receive`. The iceoryx2 sample
    /// itself is kept (a borrowed chunk of shared memory, a few words), not
    /// a copy of its payload: a 704 B belief is then read in place once,
    /// as bare iceoryx2 reads it, instead of copied in and out of the stash.
    stash: std::cell::RefCell<Option<Sample<M>>>,
}

type Sample<M> = iceoryx2::sample::Sample<ipc::Service, M, ()>;

impl<M: Message> Debug for Subscriber<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Subscriber")
            .field("service", &self.service)
            .field("wakes", &self.listener.is_some())
            .finish()
    }
}

impl<M: Message> Subscriber<M> {
    pub(super) fn open(
        node: &Node<ipc::Service>,
        name: &str,
        buffer: usize,
        wake: bool,
    ) -> Result<Self, IpcError> {
        let sn = service_name(name)?;
        let port_err = |port, e: String| IpcError::Port {
            port,
            service: name.to_string(),
            reason: e,
        };
        let buffer = buffer.clamp(1, M::QOS.max_buffer);
        let factory = pubsub::<M>(node, &sn)?;
        let subscriber = factory
            .subscriber_builder()
            .buffer_size(buffer)
            .create()
            .map_err(|e| port_err("subscriber", format!("{e:?}")))?;
        let listener = if wake {
            Some(
                event(node, &sn)?
                    .listener_builder()
                    .create()
                    .map_err(|e| port_err("listener", format!("{e:?}")))?,
            )
        } else {
            None
        };
        Ok(Self {
            subscriber,
            factory,
            listener,
            service: name.to_string(),
            stash: std::cell::RefCell::new(None),
        })
    }

    fn recv_err(&self, e: impl Debug) -> IpcError {
        IpcError::Receive {
            service: self.service.clone(),
            reason: format!("{e:?}"),
        }
    }

    /// The oldest unread sample: the stashed one, else the queue's.
    fn next_sample(&self) -> Result<Option<Sample<M>>, IpcError> {
        if let Some(s) = self.stash.borrow_mut().take() {
            return Ok(Some(s));
        }
        self.subscriber.receive().map_err(|e| self.recv_err(e))
    }

    /// The oldest unread message, copied out.
    pub fn receive(&self) -> Result<Option<M>, IpcError> {
        Ok(self.next_sample()?.map(|s| *s.payload()))
    }

    /// The oldest unread message, copied out, with who published it.
    pub fn receive_from(&self) -> Result<Option<(M, Origin)>, IpcError> {
        use iceoryx2::service::header::payload_header::PayloadHeader;
        Ok(self.next_sample()?.map(|s| {
            let node = s.header().node_id();
            let origin = Origin {
                publisher: s.origin().value(),
                node: node.value(),
                pid: node.pid::<ipc::Service>().map(|p| p.value()).unwrap_or(0),
            };
            (*s.payload(), origin)
        }))
    }

    /// Whether the publisher `publisher` ([`Origin::publisher`]) is still
    /// connected to the service.
    pub fn publisher_connected(&self, publisher: u128) -> bool {
        let mut found = false;
        self.factory.dynamic_config().list_publishers(|d| {
            if d.publisher_id.value() == publisher {
                found = true;
                CallbackProgression::Stop
            } else {
                CallbackProgression::Continue
            }
        });
        found
    }

    /// Read the oldest unread message in place (no copy) with `f`.
    pub fn receive_with<R>(&self, f: impl FnOnce(&M) -> R) -> Result<Option<R>, IpcError> {
        Ok(self.next_sample()?.map(|s| f(s.payload())))
    }

    /// The newest unread message; older unread ones are discarded and
    /// counted in the second element.
    pub fn latest(&self) -> Result<(Option<M>, u64), IpcError> {
        let mut last = None;
        let mut skipped = 0;
        while let Some(m) = self.receive()? {
            if last.is_some() {
                skipped += 1;
            }
            last = Some(m);
        }
        Ok((last, skipped))
    }

    /// Whether a message is waiting.
    pub fn has_data(&self) -> bool {
        self.stash_full() || self.subscriber.has_samples().unwrap_or(false)
    }

    fn stash_full(&self) -> bool {
        self.stash.borrow().is_some()
    }

    /// The spin path's test for data: take the oldest message into the
    /// one-slot stash (one queue scan; the next receive returns it). True
    /// when a message is stashed — or when receiving failed, so that the
    /// loop body runs and its own receive reports the error.
    pub fn poll(&self) -> bool {
        if self.stash_full() {
            return true;
        }
        match self.subscriber.receive() {
            Ok(Some(s)) => {
                *self.stash.borrow_mut() = Some(s);
                true
            }
            Ok(None) => false,
            Err(_) => true,
        }
    }

    /// Connect to publishers that appeared since the last receive, so their
    /// first samples are not missed (a subscriber otherwise connects lazily,
    /// on its next receive).
    pub fn refresh(&self) {
        use iceoryx2::port::update_connections::UpdateConnections;
        let _ = self.subscriber.update_connections();
    }

    /// Consume pending wake-up notifications (so a WaitSet does not report
    /// them again).
    pub fn drain_wakeups(&self) {
        if let Some(l) = &self.listener {
            let _ = l.try_wait(|_| {});
        }
    }

    /// The service name.
    pub fn service(&self) -> &str {
        &self.service
    }
}

#[cfg(test)]
mod stash_tests {
    use crate::{cleanup, Bus, BusConfig, Observation};

    #[test]
    fn a_polled_message_is_received_first_and_counted_as_waiting() {
        let cfg = BusConfig {
            prefix: cleanup::run_prefix(),
            instance: "test".into(),
        };
        let bus = Bus::open(&cfg, "t").unwrap();
        let mut p = bus.publisher::<Observation>().unwrap();
        let s = bus.subscriber::<Observation>().unwrap();
        assert!(!s.poll() && !s.has_data());
        for i in 0..3u64 {
            let mut o = Observation::default();
            o.header.seq = i;
            p.publish(&o).unwrap();
        }
        // Poll stashes the oldest; polling again keeps it (no second take).
        assert!(s.poll() && s.poll() && s.has_data());
        assert_eq!(s.receive_with(|o| o.header.seq).unwrap(), Some(0));
        assert!(s.poll());
        // The stashed one is part of `latest`: newest returned, the rest
        // counted as skipped.
        let (last, skipped) = s.latest().unwrap();
        assert_eq!((last.map(|o| o.header.seq), skipped), (Some(2), 1));
        assert!(!s.poll() && !s.has_data());
        assert_eq!(s.receive().unwrap(), None);
        drop((p, s, bus));
        cleanup::remove_prefix(&cfg.prefix).unwrap();
    }

    #[test]
    fn a_publisher_notifies_only_while_someone_listens() {
        let cfg = BusConfig {
            prefix: cleanup::run_prefix(),
            instance: "test".into(),
        };
        let bus = Bus::open(&cfg, "t").unwrap();
        let mut p = bus.publisher::<Observation>().unwrap();
        // A spinning reader has no listener: delivered, nobody woken.
        let spin = bus.subscriber_with::<Observation>(8, false).unwrap();
        p.publish(&Observation::default()).unwrap();
        assert!(spin.receive().unwrap().is_some());
        assert_eq!((p.sent(), p.notified()), (1, 0));
        // A blocking reader's listener is woken.
        let wake = bus.subscriber::<Observation>().unwrap();
        p.publish(&Observation::default()).unwrap();
        assert_eq!((p.sent(), p.notified()), (2, 1));
        let mut events = 0;
        wake.listener
            .as_ref()
            .unwrap()
            .try_wait(|_| events += 1)
            .unwrap();
        assert!(events >= 1);
        assert!(wake.receive().unwrap().is_some());
        drop(wake);
        p.publish(&Observation::default()).unwrap();
        assert_eq!((p.sent(), p.notified()), (3, 1));
        drop((p, spin, bus));
        cleanup::remove_prefix(&cfg.prefix).unwrap();
    }
}
