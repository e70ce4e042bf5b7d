//! The actuator side of the API: [`ControlSubscriber`] receives the
//! pipeline's controls and refuses those an actuator must not apply.

use super::super::control_check::ControlLimits;
use super::super::messages::Control;
use super::super::ports::Subscriber;
use super::super::{Bus, BusConfig, IpcError};
use crate::MAX_CONTROL;
use std::time::{Duration, Instant};

/// Receives the controls of a pipeline instance, for an actuator.
///
/// The control channel is a latest-value channel: an actuator that is slower
/// than the controller sees only the newest control, and one that connects
/// late gets the last control sent.
///
/// ```
/// use beliefbus_ipc::cleanup;
/// use beliefbus_ipc::sensor_api::ControlSubscriber;
/// use std::time::Duration;
///
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// let prefix = cleanup::run_prefix(); // normally: the prefix the run printed
/// let mut actuator = ControlSubscriber::connect("doc", &prefix)?;
/// // Nothing publishes controls here, so the wait times out.
/// assert!(actuator.wait(Duration::from_millis(20))?.is_none());
/// // With a running pipeline: apply c.u[..c.dim as usize] on each control.
/// if let Some(c) = actuator.try_latest()? {
///     let _u = &c.u[..c.dim as usize];
/// }
/// drop(actuator);
/// cleanup::remove_prefix(&prefix)?;
/// # Ok(())
/// # }
/// ```
pub struct ControlSubscriber {
    subscriber: Subscriber<Control>,
    received: u64,
    rejected: u64,
    limits: Option<ControlLimits>,
    bus: Bus,
}

impl std::fmt::Debug for ControlSubscriber {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ControlSubscriber")
            .field("bus", &self.bus)
            .field("received", &self.received)
            .finish()
    }
}

impl ControlSubscriber {
    /// Join pipeline `instance` under shared-memory `prefix` as node
    /// `actuator`.
    pub fn connect(instance: &str, prefix: &str) -> Result<Self, IpcError> {
        let cfg = BusConfig {
            prefix: prefix.to_string(),
            instance: instance.to_string(),
        };
        Self::connect_with(&cfg, "actuator")
    }

    /// Join the pipeline of `cfg` as node `node_name`.
    pub fn connect_with(cfg: &BusConfig, node_name: &str) -> Result<Self, IpcError> {
        let bus = Bus::open(cfg, node_name)?;
        let subscriber = bus.subscriber::<Control>()?;
        Ok(Self {
            subscriber,
            received: 0,
            rejected: 0,
            limits: None,
            bus,
        })
    }

    /// Accept only controls inside `limits` (the run's control dimension
    /// and the controller's limits, `PipelineConfig::control_limits`).
    /// Without it a control is accepted when its `dim` is at most
    /// [`MAX_CONTROL`] and its values are finite.
    pub fn with_limits(mut self, limits: ControlLimits) -> Self {
        self.limits = Some(limits);
        self
    }

    /// Controls refused (wrong dimension, non-finite, outside the limits):
    /// anything that can open the control service can publish on it.
    pub fn rejected(&self) -> u64 {
        self.rejected
    }

    fn acceptable(&self, c: &Control) -> bool {
        match &self.limits {
            Some(l) => l.check(c).is_ok(),
            None => {
                let n = c.dim as usize;
                n <= MAX_CONTROL && ControlLimits::finite(n).check(c).is_ok()
            }
        }
    }

    /// The bus (prefix, instance) it listens on.
    pub fn config(&self) -> &BusConfig {
        self.bus.config()
    }

    /// Controls received so far.
    pub fn received(&self) -> u64 {
        self.received
    }

    /// The newest acceptable control not yet read, without blocking
    /// (refused ones are counted in [`Self::rejected`] and skipped: the
    /// actuator keeps applying the last good one).
    pub fn try_latest(&mut self) -> Result<Option<Control>, IpcError> {
        self.subscriber.drain_wakeups();
        let mut last = None;
        while let Some(c) = self.subscriber.receive()? {
            if self.acceptable(&c) {
                last = Some(c);
            } else {
                self.rejected += 1;
            }
        }
        self.received += last.is_some() as u64;
        Ok(last)
    }

    /// Block until a new control arrives (returned) or `timeout` passes
    /// (`None`). Event-driven: the controller notifies after each send.
    pub fn wait(&mut self, timeout: Duration) -> Result<Option<Control>, IpcError> {
        let until = Instant::now() + timeout;
        loop {
            if let Some(c) = self.try_latest()? {
                return Ok(Some(c));
            }
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            match &self.subscriber.listener {
                Some(l) => {
                    l.timed_wait(|_| {}, left)
                        .map_err(|e| IpcError::Wait(format!("{e:?}")))?;
                }
                None => std::thread::sleep(left.min(Duration::from_millis(1))),
            }
        }
    }
}
