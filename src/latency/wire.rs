//! The two ends of every measured path, for both implementations.
//!
//! - **ours**: beliefbus's ports — [`crate::ipc::Publisher`] /
//!   [`crate::ipc::Subscriber`] for the fixed-size messages (with each
//!   channel's real QoS) and [`crate::ipc::SlicePublisher`] /
//!   [`crate::ipc::SliceSubscriber`] for chain slices; the ping direction
//!   is the pipeline instance `lat-ping`, the pong direction `lat-pong`.
//! - **bare**: the least iceoryx2 code that does the same job, the pattern
//!   of iceoryx2's own benchmarks: `send_copy` / `loan_slice_uninit` +
//!   `send`, `receive`, and a `Listener` waited on directly (no WaitSet).
//!   Same payload types, same QoS, same prefix. This module is the only
//!   place outside `crate::ipc` that names iceoryx2, because it *is* the
//!   baseline.
//!
//! A message carries only its sequence number as content that matters: the
//! fixed messages in `header.seq`, a chain slice in its first and last f64
//! (bit pattern), written and read in place — so a slice send costs the
//! same whatever its length, which is what zero copy means.

use super::paths::{Mode, PathKind};
use super::LatencyError;
use crate::ipc::{
    Belief, Bus, BusConfig, Control, Message, Observation, Publisher, Qos, SlicePublisher,
    SliceQos, SliceSubscriber, Subscriber, Wakeable,
};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;

/// Sequence number that ends a slot (echoed, then both sides move on).
pub const SWITCH: u64 = u64::MAX - 1;
/// Sequence number that ends the run (echoed, then the pong exits).
pub const QUIT: u64 = u64::MAX;

/// Instance of the ping → pong direction.
pub const PING_INSTANCE: &str = "lat-ping";
/// Instance of the pong → ping direction.
pub const PONG_INSTANCE: &str = "lat-pong";

/// QoS of the chain-slice paths: one publisher, one subscriber, a
/// one-slice buffer — the leanest segment that can ping-pong (the data
/// segment of a 16 MiB path then holds 5 slices, not 19).
pub fn chain_qos(bytes: usize) -> SliceQos {
    SliceQos {
        max_len: bytes / 8,
        qos: Qos {
            history: 0,
            max_buffer: 1,
            default_buffer: 1,
            max_publishers: 1,
            max_subscribers: 1,
            max_nodes: 4,
        },
    }
}

/// Sends one sequence number.
pub trait Tx {
    fn send(&mut self, seq: u64) -> Result<(), LatencyError>;
}

/// Receives one sequence number (None: nothing waiting).
pub trait Rx {
    fn recv(&self) -> Result<Option<u64>, LatencyError>;
}

/// A receiving end of ours: waitable by [`crate::ipc::run_loop`].
pub trait OursRx: Rx {
    fn wakeable(&self) -> &dyn Wakeable;
}

/// A receiving end of bare: its listener, when the mode notifies.
pub trait BareRx: Rx {
    fn listener(&self) -> Option<&Listener<ipc::Service>>;
}

/// The fixed-size messages' sequence number.
pub trait Stamped: Message {
    fn seq(&self) -> u64;
    fn set_seq(&mut self, seq: u64);
}

macro_rules! stamped {
    ($($t:ty),*) => {$(
        impl Stamped for $t {
            fn seq(&self) -> u64 {
                self.header.seq
            }
            fn set_seq(&mut self, seq: u64) {
                self.header.seq = seq;
            }
        }
    )*};
}
stamped!(Observation, Belief, Control);

// ---------------------------------------------------------------- ours

struct OursMsgTx<M: Stamped> {
    publisher: Publisher<M>,
    msg: M,
}

impl<M: Stamped> Tx for OursMsgTx<M> {
    fn send(&mut self, seq: u64) -> Result<(), LatencyError> {
        self.msg.set_seq(seq);
        Ok(self.publisher.publish(&self.msg)?)
    }
}

impl<M: Stamped> Rx for Subscriber<M> {
    fn recv(&self) -> Result<Option<u64>, LatencyError> {
        Ok(self.receive_with(|m| m.seq())?)
    }
}

impl<M: Stamped> OursRx for Subscriber<M> {
    fn wakeable(&self) -> &dyn Wakeable {
        self
    }
}

struct OursSliceTx {
    publisher: SlicePublisher<f64>,
    len: usize,
}

impl Tx for OursSliceTx {
    fn send(&mut self, seq: u64) -> Result<(), LatencyError> {
        let len = self.len;
        self.publisher.publish_with(len, |xs| {
            xs[0] = f64::from_bits(seq);
            xs[len - 1] = f64::from_bits(seq);
        })?;
        Ok(())
    }
}

/// The sequence number of a slice: first and last element must agree (a
/// torn or short slice is an error, not a sample).
fn slice_seq(xs: &[f64], len: usize) -> Result<u64, LatencyError> {
    if xs.len() != len {
        return Err(LatencyError::Protocol(format!(
            "slice of {} elements, expected {len}",
            xs.len()
        )));
    }
    let (a, b) = (xs[0].to_bits(), xs[len - 1].to_bits());
    if a != b {
        return Err(LatencyError::Protocol(format!(
            "slice ends disagree ({a} vs {b})"
        )));
    }
    Ok(a)
}

struct OursSliceRx {
    subscriber: SliceSubscriber<f64>,
    len: usize,
}

impl Rx for OursSliceRx {
    fn recv(&self) -> Result<Option<u64>, LatencyError> {
        let len = self.len;
        self.subscriber
            .receive_with(|xs| slice_seq(xs, len))?
            .transpose()
    }
}

impl OursRx for OursSliceRx {
    fn wakeable(&self) -> &dyn Wakeable {
        &self.subscriber
    }
}

/// Ours: one process's end of every path.
pub struct OursEnds {
    // Ports before buses: ports must drop before their node.
    pub tx: Vec<Box<dyn Tx>>,
    pub rx: Vec<Box<dyn OursRx>>,
    _buses: (Bus, Bus),
}

/// Which end of the ping-pong a process is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    Ping,
    Pong,
}

impl OursEnds {
    /// Open this side's publishers and subscribers of every path.
    pub fn open(
        prefix: &str,
        side: Side,
        mode: Mode,
        paths: &[PathKind],
    ) -> Result<Self, LatencyError> {
        let (tx_inst, rx_inst) = match side {
            Side::Ping => (PING_INSTANCE, PONG_INSTANCE),
            Side::Pong => (PONG_INSTANCE, PING_INSTANCE),
        };
        let bus = |inst: &str, node: &str| {
            Bus::open(
                &BusConfig {
                    prefix: prefix.to_string(),
                    instance: inst.to_string(),
                },
                node,
            )
        };
        let tag = match side {
            Side::Ping => "ping",
            Side::Pong => "pong",
        };
        let txb = bus(tx_inst, &format!("{tag}-tx"))?;
        let rxb = bus(rx_inst, &format!("{tag}-rx"))?;
        let wake = mode.notifies();
        let mut tx: Vec<Box<dyn Tx>> = Vec::with_capacity(paths.len());
        let mut rx: Vec<Box<dyn OursRx>> = Vec::with_capacity(paths.len());
        fn msg<M: Stamped>(
            txb: &Bus,
            rxb: &Bus,
            wake: bool,
            tx: &mut Vec<Box<dyn Tx>>,
            rx: &mut Vec<Box<dyn OursRx>>,
        ) -> Result<(), LatencyError> {
            tx.push(Box::new(OursMsgTx {
                publisher: txb.publisher::<M>()?,
                msg: M::default(),
            }));
            rx.push(Box::new(
                rxb.subscriber_with::<M>(M::QOS.default_buffer, wake)?,
            ));
            Ok(())
        }
        for p in paths {
            match *p {
                PathKind::Observation => msg::<Observation>(&txb, &rxb, wake, &mut tx, &mut rx)?,
                PathKind::Belief => msg::<Belief>(&txb, &rxb, wake, &mut tx, &mut rx)?,
                PathKind::Control => msg::<Control>(&txb, &rxb, wake, &mut tx, &mut rx)?,
                PathKind::Chain { bytes } => {
                    let q = chain_qos(bytes);
                    let channel = p.name();
                    tx.push(Box::new(OursSliceTx {
                        publisher: txb.slice_publisher::<f64>(&channel, &q)?,
                        len: q.max_len,
                    }));
                    rx.push(Box::new(OursSliceRx {
                        subscriber: rxb.slice_subscriber::<f64>(&channel, &q, wake)?,
                        len: q.max_len,
                    }));
                }
            }
        }
        Ok(Self {
            tx,
            rx,
            _buses: (txb, rxb),
        })
    }
}

// ---------------------------------------------------------------- bare

fn iox_err(what: &str, e: impl std::fmt::Debug) -> LatencyError {
    LatencyError::Bare(format!("{what}: {e:?}"))
}

type Pub<P> = iceoryx2::port::publisher::Publisher<ipc::Service, P, ()>;
type Sub<P> = iceoryx2::port::subscriber::Subscriber<ipc::Service, P, ()>;

struct BareMsgTx<M: Stamped> {
    publisher: Pub<M>,
    notifier: Option<Notifier<ipc::Service>>,
    msg: M,
}

impl<M: Stamped> Tx for BareMsgTx<M> {
    fn send(&mut self, seq: u64) -> Result<(), LatencyError> {
        self.msg.set_seq(seq);
        self.publisher
            .send_copy(self.msg)
            .map_err(|e| iox_err("send", e))?;
        if let Some(n) = &self.notifier {
            n.notify().map_err(|e| iox_err("notify", e))?;
        }
        Ok(())
    }
}

struct BareMsgRx<M: Stamped> {
    subscriber: Sub<M>,
    listener: Option<Listener<ipc::Service>>,
}

impl<M: Stamped> Rx for BareMsgRx<M> {
    fn recv(&self) -> Result<Option<u64>, LatencyError> {
        match self.subscriber.receive() {
            Ok(Some(s)) => Ok(Some(s.payload().seq())),
            Ok(None) => Ok(None),
            Err(e) => Err(iox_err("receive", e)),
        }
    }
}

impl<M: Stamped> BareRx for BareMsgRx<M> {
    fn listener(&self) -> Option<&Listener<ipc::Service>> {
        self.listener.as_ref()
    }
}

struct BareSliceTx {
    publisher: Pub<[f64]>,
    notifier: Option<Notifier<ipc::Service>>,
    len: usize,
}

impl Tx for BareSliceTx {
    fn send(&mut self, seq: u64) -> Result<(), LatencyError> {
        let mut s = self
            .publisher
            .loan_slice_uninit(self.len)
            .map_err(|e| iox_err("loan", e))?;
        let v = f64::from_bits(seq);
        let len = self.len;
        s.payload_mut()[0].write(v);
        s.payload_mut()[len - 1].write(v);
        // SAFETY: f64 accepts every bit pattern and shared memory is always
        // defined (zero-filled at creation, else an earlier sample's data);
        // the reader looks only at the two elements written above.
        let s = unsafe { s.assume_init() };
        s.send().map_err(|e| iox_err("send", e))?;
        if let Some(n) = &self.notifier {
            n.notify().map_err(|e| iox_err("notify", e))?;
        }
        Ok(())
    }
}

struct BareSliceRx {
    subscriber: Sub<[f64]>,
    listener: Option<Listener<ipc::Service>>,
    len: usize,
}

impl Rx for BareSliceRx {
    fn recv(&self) -> Result<Option<u64>, LatencyError> {
        match self.subscriber.receive() {
            Ok(Some(s)) => slice_seq(s.payload(), self.len).map(Some),
            Ok(None) => Ok(None),
            Err(e) => Err(iox_err("receive", e)),
        }
    }
}

impl BareRx for BareSliceRx {
    fn listener(&self) -> Option<&Listener<ipc::Service>> {
        self.listener.as_ref()
    }
}

/// Bare: one process's end of every path, on its own iceoryx2 node.
pub struct BareEnds {
    pub tx: Vec<Box<dyn Tx>>,
    pub rx: Vec<Box<dyn BareRx>>,
    _node: Node<ipc::Service>,
}

fn sname(s: &str) -> Result<ServiceName, LatencyError> {
    ServiceName::new(s).map_err(|e| iox_err("service name", e))
}

/// A notifier or a listener (or neither, when the mode does not notify).
type EventPorts = (
    Option<Notifier<ipc::Service>>,
    Option<Listener<ipc::Service>>,
);

fn events(
    node: &Node<ipc::Service>,
    name: &ServiceName,
    wake: bool,
    listen: bool,
) -> Result<EventPorts, LatencyError> {
    if !wake {
        return Ok((None, None));
    }
    let ev = node
        .service_builder(name)
        .event()
        .open_or_create()
        .map_err(|e| iox_err("event service", e))?;
    if listen {
        let l = ev
            .listener_builder()
            .create()
            .map_err(|e| iox_err("listener", e))?;
        Ok((None, Some(l)))
    } else {
        let n = ev
            .notifier_builder()
            .create()
            .map_err(|e| iox_err("notifier", e))?;
        Ok((Some(n), None))
    }
}

impl BareEnds {
    /// Open this side's bare ports of every path: services
    /// `bare/<path>/ping` and `bare/<path>/pong`.
    pub fn open(
        prefix: &str,
        side: Side,
        mode: Mode,
        paths: &[PathKind],
    ) -> Result<Self, LatencyError> {
        let mut config = Config::global_config().clone();
        config.global.prefix =
            FileName::new(prefix.as_bytes()).map_err(|e| iox_err("prefix", e))?;
        let node_name = match side {
            Side::Ping => "bare-ping",
            Side::Pong => "bare-pong",
        };
        let node = NodeBuilder::new()
            .name(&NodeName::new(node_name).map_err(|e| iox_err("node name", e))?)
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| iox_err("node", e))?;
        let wake = mode.notifies();
        let (tx_dir, rx_dir) = match side {
            Side::Ping => ("ping", "pong"),
            Side::Pong => ("pong", "ping"),
        };
        let mut tx: Vec<Box<dyn Tx>> = Vec::with_capacity(paths.len());
        let mut rx: Vec<Box<dyn BareRx>> = Vec::with_capacity(paths.len());

        fn msg<M: Stamped>(
            node: &Node<ipc::Service>,
            tx_name: &ServiceName,
            rx_name: &ServiceName,
            wake: bool,
            tx: &mut Vec<Box<dyn Tx>>,
            rx: &mut Vec<Box<dyn BareRx>>,
        ) -> Result<(), LatencyError> {
            let q = M::QOS;
            let service = |name: &ServiceName| {
                node.service_builder(name)
                    .publish_subscribe::<M>()
                    .history_size(q.history)
                    .subscriber_max_buffer_size(q.max_buffer)
                    .enable_safe_overflow(true)
                    .max_publishers(q.max_publishers)
                    .max_subscribers(q.max_subscribers)
                    .max_nodes(q.max_nodes)
                    .open_or_create()
                    .map_err(|e| iox_err("pub-sub service", e))
            };
            let publisher = service(tx_name)?
                .publisher_builder()
                .create()
                .map_err(|e| iox_err("publisher", e))?;
            let subscriber = service(rx_name)?
                .subscriber_builder()
                .buffer_size(q.default_buffer)
                .create()
                .map_err(|e| iox_err("subscriber", e))?;
            let (notifier, _) = events(node, tx_name, wake, false)?;
            let (_, listener) = events(node, rx_name, wake, true)?;
            tx.push(Box::new(BareMsgTx {
                publisher,
                notifier,
                msg: M::default(),
            }));
            rx.push(Box::new(BareMsgRx::<M> {
                subscriber,
                listener,
            }));
            Ok(())
        }

        for p in paths {
            let tx_name = sname(&format!("bare/{}/{tx_dir}", p.name()))?;
            let rx_name = sname(&format!("bare/{}/{rx_dir}", p.name()))?;
            match *p {
                PathKind::Observation => {
                    msg::<Observation>(&node, &tx_name, &rx_name, wake, &mut tx, &mut rx)?
                }
                PathKind::Belief => {
                    msg::<Belief>(&node, &tx_name, &rx_name, wake, &mut tx, &mut rx)?
                }
                PathKind::Control => {
                    msg::<Control>(&node, &tx_name, &rx_name, wake, &mut tx, &mut rx)?
                }
                PathKind::Chain { bytes } => {
                    let q = chain_qos(bytes);
                    let service = |name: &ServiceName| {
                        node.service_builder(name)
                            .publish_subscribe::<[f64]>()
                            .history_size(q.qos.history)
                            .subscriber_max_buffer_size(q.qos.max_buffer)
                            .enable_safe_overflow(true)
                            .max_publishers(q.qos.max_publishers)
                            .max_subscribers(q.qos.max_subscribers)
                            .max_nodes(q.qos.max_nodes)
                            .open_or_create()
                            .map_err(|e| iox_err("pub-sub service", e))
                    };
                    let publisher = service(&tx_name)?
                        .publisher_builder()
                        .initial_max_slice_len(q.max_len)
                        .allocation_strategy(AllocationStrategy::Static)
                        .create()
                        .map_err(|e| iox_err("publisher", e))?;
                    let subscriber = service(&rx_name)?
                        .subscriber_builder()
                        .buffer_size(q.qos.default_buffer)
                        .create()
                        .map_err(|e| iox_err("subscriber", e))?;
                    let (notifier, _) = events(&node, &tx_name, wake, false)?;
                    let (_, listener) = events(&node, &rx_name, wake, true)?;
                    tx.push(Box::new(BareSliceTx {
                        publisher,
                        notifier,
                        len: q.max_len,
                    }));
                    rx.push(Box::new(BareSliceRx {
                        subscriber,
                        listener,
                        len: q.max_len,
                    }));
                }
            }
        }
        Ok(Self {
            tx,
            rx,
            _node: node,
        })
    }
}
