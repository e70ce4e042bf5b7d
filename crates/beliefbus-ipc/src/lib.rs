//! All iceoryx2 code of beliefbus: message types, service names and QoS,
//! typed ports, wake-ups and shared-memory cleanup. Nothing outside this
//! module names iceoryx2; stages see [`Bus`], [`Publisher`], [`Subscriber`]
//! and [`run_loop`].
//!
//! - A [`Bus`] is one iceoryx2 node of one pipeline instance under one
//!   shared-memory prefix (`iceoryx2::Config::global.prefix`). Different
//!   prefixes never interact, so every test and every `beliefbus run` gets
//!   its own, and [`cleanup`] removes everything a prefix left behind.
//! - Services are named `beliefbus/<instance>/<channel>`; each channel has one
//!   message type and one QoS ([`Message`]), so every participant opens a
//!   service with identical settings in any start order.
//! - QoS (DESIGN.md): `belief`/`control` are latest-value channels (history
//!   1, subscriber buffer 1, safe overflow: the newest value replaces the
//!   unread one); `obs` keeps a small queue; every service uses safe
//!   overflow, so a publisher never blocks on a slow subscriber.
//! - Wake-ups: a publisher sends the sample, then notifies the event service
//!   of the same name (skipped while it has no listener: spinning readers); a subscriber's listener is attached to a WaitSet
//!   ([`run_loop`]); [`WakeMode::SpinThenBlock`] polls for a bounded time
//!   before blocking, for the latency-critical path.

// The lower layers under the names the ipc code uses.
use beliefbus_core::{belief, rng};
use beliefbus_core::{MAX_CONTROL, MAX_OBS, MAX_STATE};
use beliefbus_rt as rt;

pub mod cleanup;
pub mod control_check;
pub mod messages;
mod ports;
pub mod sensor_api;
mod signals;
mod slice;
pub mod trust;
mod wait;

pub use control_check::{ControlLimits, ControlReject};
pub use messages::*;
pub use ports::{Message, Origin, Publisher, Qos, Subscriber};
pub use signals::install_stop_handler;
pub use slice::{SliceElem, SlicePublisher, SliceQos, SliceSample, SliceSubscriber};
pub use trust::PublisherGate;
pub use wait::{run_loop, Wake, WakeMode, Wakeable, STOP_POLL};

use iceoryx2::prelude::*;

/// Why an iceoryx2 operation failed (the iceoryx2 error is kept as text so
/// its types do not leak out of this module).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IpcError {
    /// A prefix, instance or node name that iceoryx2 cannot use.
    #[error("invalid {what} '{value}': {reason}")]
    InvalidName {
        what: &'static str,
        value: String,
        reason: String,
    },
    /// The node could not be created.
    #[error("cannot create iceoryx2 node '{node}': {reason}")]
    Node { node: String, reason: String },
    /// A service could not be opened or created (e.g. incompatible QoS or
    /// payload type of an existing service).
    #[error("cannot open service '{service}': {reason}")]
    Service { service: String, reason: String },
    /// A port could not be created.
    #[error("cannot create {port} on '{service}': {reason}")]
    Port {
        port: &'static str,
        service: String,
        reason: String,
    },
    /// Sending failed.
    #[error("send on '{service}' failed: {reason}")]
    Send { service: String, reason: String },
    /// Receiving failed.
    #[error("receive on '{service}' failed: {reason}")]
    Receive { service: String, reason: String },
    /// Waiting for events failed.
    #[error("wait failed: {0}")]
    Wait(String),
    /// Listing or removing resources failed.
    #[error("cleanup of prefix '{prefix}' failed: {reason}")]
    Cleanup { prefix: String, reason: String },
}

/// Where a bus lives: shared-memory prefix and pipeline instance.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BusConfig {
    /// File-name prefix of every iceoryx2 resource (e.g. `iox2_bb1a2b_`).
    pub prefix: String,
    /// Pipeline instance, the `<instance>` in `beliefbus/<instance>/<channel>`.
    pub instance: String,
}

impl BusConfig {
    /// Check that iceoryx2 accepts the prefix and that the instance is a
    /// plain identifier (`[A-Za-z0-9_-]+`).
    pub fn validate(&self) -> Result<(), IpcError> {
        validate_prefix(&self.prefix)?;
        validate_instance(&self.instance)
    }

    /// The iceoryx2 configuration of this prefix.
    fn iox_config(&self) -> Result<Config, IpcError> {
        let mut c = Config::global_config().clone();
        c.global.prefix = prefix_file_name(&self.prefix)?;
        Ok(c)
    }
}

/// Check a shared-memory prefix: non-empty, at most 64 bytes, characters
/// `[A-Za-z0-9_.-]` (it becomes part of file names).
pub fn validate_prefix(prefix: &str) -> Result<(), IpcError> {
    let bad = |reason: &str| IpcError::InvalidName {
        what: "prefix",
        value: prefix.to_string(),
        reason: reason.to_string(),
    };
    if prefix.is_empty() || prefix.len() > 64 {
        return Err(bad("must have 1 to 64 characters"));
    }
    if !prefix
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-' || b == b'.')
    {
        return Err(bad("only A-Z a-z 0-9 _ - . are allowed"));
    }
    prefix_file_name(prefix).map(|_| ())
}

fn prefix_file_name(prefix: &str) -> Result<FileName, IpcError> {
    FileName::new(prefix.as_bytes()).map_err(|e| IpcError::InvalidName {
        what: "prefix",
        value: prefix.to_string(),
        reason: format!("{e:?}"),
    })
}

/// Check an instance name: non-empty, at most 64 characters of
/// `[A-Za-z0-9_-]`.
pub fn validate_instance(instance: &str) -> Result<(), IpcError> {
    if instance.is_empty()
        || instance.len() > 64
        || !instance
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
    {
        return Err(IpcError::InvalidName {
            what: "instance",
            value: instance.to_string(),
            reason: "must be 1 to 64 characters of A-Z a-z 0-9 _ -".into(),
        });
    }
    Ok(())
}

/// The service name of `channel` in `instance`: `beliefbus/<instance>/<channel>`.
pub fn service_name(instance: &str, channel: &str) -> String {
    format!("beliefbus/{instance}/{channel}")
}

/// Initialise iceoryx2's logger once: errors only, unless the
/// `IOX2_LOG_LEVEL` environment variable says otherwise.
fn init_logging() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| set_log_level_from_env_or(LogLevel::Error));
}

/// One participant (iceoryx2 node) of a pipeline instance.
///
/// A bus and its ports are `!Send`: create them on the thread that uses them.
pub struct Bus {
    node: Node<ipc::Service>,
    cfg: BusConfig,
}

impl std::fmt::Debug for Bus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bus")
            .field("prefix", &self.cfg.prefix)
            .field("instance", &self.cfg.instance)
            .field("node", &self.node.name().as_str())
            .finish()
    }
}

impl Bus {
    /// Join the pipeline `cfg` as node `node_name` (e.g. `"filter"`).
    ///
    /// iceoryx2's own SIGINT/SIGTERM handling is disabled: the stop flag of
    /// [`install_stop_handler`] (or the caller's) decides when a loop ends.
    pub fn open(cfg: &BusConfig, node_name: &str) -> Result<Bus, IpcError> {
        init_logging();
        cfg.validate()?;
        let iox = cfg.iox_config()?;
        let name = NodeName::new(node_name).map_err(|e| IpcError::InvalidName {
            what: "node name",
            value: node_name.to_string(),
            reason: format!("{e:?}"),
        })?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(&iox)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| IpcError::Node {
                node: node_name.to_string(),
                reason: format!("{e:?}"),
            })?;
        Ok(Bus {
            node,
            cfg: cfg.clone(),
        })
    }

    /// The bus configuration.
    pub fn config(&self) -> &BusConfig {
        &self.cfg
    }

    /// The full service name of `channel`.
    pub fn service_name(&self, channel: &str) -> String {
        service_name(&self.cfg.instance, channel)
    }

    /// A publisher on `M`'s channel; it notifies subscribers after each send.
    pub fn publisher<M: Message>(&self) -> Result<Publisher<M>, IpcError> {
        Publisher::open(&self.node, &self.service_name(M::CHANNEL))
    }

    /// A subscriber on `M`'s channel with the channel's default buffer, and a
    /// listener so it can wake a [`run_loop`].
    pub fn subscriber<M: Message>(&self) -> Result<Subscriber<M>, IpcError> {
        self.subscriber_with(M::QOS.default_buffer, true)
    }

    /// A subscriber with its own buffer size (at most the channel's
    /// `max_buffer`) and, if `wake`, a listener. A monitor that polls uses a
    /// large buffer and no listener (it receives no notifications, and the
    /// publisher pays nothing for it).
    pub fn subscriber_with<M: Message>(
        &self,
        buffer: usize,
        wake: bool,
    ) -> Result<Subscriber<M>, IpcError> {
        Subscriber::open(&self.node, &self.service_name(M::CHANNEL), buffer, wake)
    }
}

#[cfg(test)]
mod tests;
