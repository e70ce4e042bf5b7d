//! The user-facing API for plugging a sensor or an actuator into a running
//! pipeline: [`SensorPublisher`] sends sensor samples (ABI v1, see
//! `docs/sensor-abi.md`), [`ControlSubscriber`] receives controls.
//!
//! Both join a pipeline by its **instance** (the `<instance>` of
//! `beliefbus/<instance>/<channel>`) and its shared-memory **prefix**
//! (printed by `beliefbus run`, `run.prefix` of the config). The publisher
//! enforces the publisher rules of the ABI before anything is sent — at
//! most [`SENSOR_MAX_DIM`] finite values, one σ > 0 per value when σ is
//! given, a non-zero measurement time that never goes backwards on a
//! channel and is not in the future — and numbers each channel's samples
//! 0, 1, 2, … itself; bad input is a typed [`SensorError`], nothing is
//! sent. [`SensorPublisher::publish_sample`] sends a sample as it is, for
//! replay and fault injection: ingest validates everything again, so a bad
//! sample is rejected and counted there, never filtered.
//!
//! ```
//! use beliefbus_ipc::cleanup;
//! use beliefbus_ipc::sensor_api::{monotonic_now_ns, SensorError, SensorPublisher};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let prefix = cleanup::run_prefix(); // normally: the prefix the run printed
//! let mut sensor = SensorPublisher::connect("doc", &prefix)?;
//! // Range and bearing measured just now on channel 0.
//! let seq = sensor.publish(0, monotonic_now_ns(), &[5.2, 0.31])?;
//! assert_eq!(seq, 0);
//! // Per-sample σ: one per value.
//! let seq = sensor.publish_with_std(0, monotonic_now_ns(), &[5.3, 0.30], &[0.2, 0.01])?;
//! assert_eq!(seq, 1);
//! // Bad input is refused before anything is sent.
//! let bad = sensor.publish(0, monotonic_now_ns(), &[f64::NAN, 0.3]);
//! assert!(matches!(bad, Err(SensorError::NonFinite { index: 0, .. })));
//! drop(sensor);
//! cleanup::remove_prefix(&prefix)?;
//! # Ok(())
//! # }
//! ```

use super::control_check::ControlLimits;
use super::messages::{Control, SensorSample, SENSOR_MAX_DIM};
use super::ports::{Message, Publisher, Subscriber};
use super::{Bus, BusConfig, IpcError};
use crate::MAX_CONTROL;
use iceoryx2::prelude::*;
use std::time::{Duration, Instant};

/// CLOCK_MONOTONIC now in nanoseconds: the clock of every stamp on the wire.
pub fn monotonic_now_ns() -> u64 {
    crate::rt::clock::now_ns()
}

/// The iceoryx2 type name of message `M` on the wire (e.g.
/// `beliefbus.SensorSample.v1`): a participant in another language must
/// declare its payload under exactly this name.
pub fn wire_type_name<M: Message>() -> &'static str {
    // SAFETY: `type_name` is unsafe to implement (names must be unique), not
    // to call.
    unsafe { <M as ZeroCopySend>::type_name() }
}

/// Why a sample was not sent.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SensorError {
    /// A sample carries 1 to [`SENSOR_MAX_DIM`] values.
    #[error("a sensor sample carries 1 to {max} values, got {got}", max = SENSOR_MAX_DIM)]
    Dimension { got: usize },
    /// A value is NaN or infinite.
    #[error("value {index} is not finite ({value})")]
    NonFinite { index: usize, value: f64 },
    /// σ was given, but not one per value.
    #[error("{values} values need {values} noise σ, got {std}")]
    NoiseLength { values: usize, std: usize },
    /// A σ is not finite and positive.
    #[error("noise σ {index} must be finite and > 0, got {value}")]
    BadNoise { index: usize, value: f64 },
    /// Measurement time 0 means "unset" and is rejected by ingest.
    #[error("measurement time must be CLOCK_MONOTONIC ns > 0")]
    ZeroTime,
    /// The measurement time is later than the clock now.
    #[error("measurement time {t_ns} ns is in the future (now {now_ns} ns)")]
    FutureTime { t_ns: u64, now_ns: u64 },
    /// The measurement time goes backwards on a channel.
    #[error("channel {channel}: measurement time {t_ns} ns is before the previous {last_ns} ns")]
    TimeBackwards {
        channel: u32,
        t_ns: u64,
        last_ns: u64,
    },
    /// The pipeline could not be joined or the send failed.
    #[error(transparent)]
    Ipc(#[from] IpcError),
}

/// Sequence and time state of one channel of a publisher.
#[derive(Clone, Copy, Debug)]
struct ChannelState {
    channel: u32,
    next_seq: u64,
    last_t_ns: u64,
}

/// Publishes sensor samples into a pipeline instance.
///
/// One publisher may serve several channels; each channel's samples are
/// numbered 0, 1, 2, … in publish order. `!Send` (iceoryx2 ports): create it
/// on the thread that publishes.
pub struct SensorPublisher {
    // Ports before the bus: fields drop in declaration order.
    publisher: Publisher<SensorSample>,
    service: iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        ipc::Service,
        SensorSample,
        (),
    >,
    channels: Vec<ChannelState>,
    bus: Bus,
}

impl std::fmt::Debug for SensorPublisher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SensorPublisher")
            .field("bus", &self.bus)
            .field("channels", &self.channels)
            .finish()
    }
}

impl SensorPublisher {
    /// Join pipeline `instance` under shared-memory `prefix` as node
    /// `sensor`.
    pub fn connect(instance: &str, prefix: &str) -> Result<Self, SensorError> {
        let cfg = BusConfig {
            prefix: prefix.to_string(),
            instance: instance.to_string(),
        };
        Self::connect_with(&cfg, "sensor")
    }

    /// Join the pipeline of `cfg` as node `node_name`.
    pub fn connect_with(cfg: &BusConfig, node_name: &str) -> Result<Self, SensorError> {
        let bus = Bus::open(cfg, node_name)?;
        let publisher = bus.publisher::<SensorSample>()?;
        // The publisher has created or opened the service; this second
        // handle only reads its live participant counts.
        let name = bus.service_name(SensorSample::CHANNEL);
        let sn = ServiceName::new(&name).map_err(|e| IpcError::InvalidName {
            what: "service name",
            value: name.clone(),
            reason: format!("{e:?}"),
        })?;
        let service = bus
            .node
            .service_builder(&sn)
            .publish_subscribe::<SensorSample>()
            .open()
            .map_err(|e| IpcError::Service {
                service: name.clone(),
                reason: format!("{e:?}"),
            })?;
        Ok(Self {
            publisher,
            service,
            channels: Vec::new(),
            bus,
        })
    }

    /// The bus (prefix, instance) it publishes on.
    pub fn config(&self) -> &BusConfig {
        self.bus.config()
    }

    /// The service name, `beliefbus/<instance>/sensor`.
    pub fn service(&self) -> &str {
        self.publisher.service()
    }

    /// Subscribers currently connected (ingest is one; monitors may add).
    pub fn subscribers(&self) -> usize {
        self.service.dynamic_config().number_of_subscribers()
    }

    /// Block until at least `n` subscribers are connected or `timeout`
    /// passes; returns whether they are. Samples sent before ingest connects
    /// are lost (the sensor channel keeps no history).
    pub fn wait_for_subscribers(&self, n: usize, timeout: Duration) -> bool {
        let until = Instant::now() + timeout;
        loop {
            if self.subscribers() >= n {
                return true;
            }
            if Instant::now() >= until {
                return false;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// The sequence number the next sample of `channel` gets.
    pub fn next_seq(&self, channel: u32) -> u64 {
        self.channels
            .iter()
            .find(|c| c.channel == channel)
            .map_or(0, |c| c.next_seq)
    }

    /// Samples sent so far (all channels, including [`Self::publish_sample`]).
    pub fn sent(&self) -> u64 {
        self.publisher.sent()
    }

    /// Publish `values` measured at `t_meas_ns` (CLOCK_MONOTONIC ns, see
    /// [`monotonic_now_ns`]) on `channel`, with the pipeline's configured
    /// noise. Returns the sample's sequence number.
    pub fn publish(
        &mut self,
        channel: u32,
        t_meas_ns: u64,
        values: &[f64],
    ) -> Result<u64, SensorError> {
        self.publish_checked(channel, t_meas_ns, values, None)
    }

    /// Like [`Self::publish`] with a per-sample σ for each value (same units
    /// as the values), overriding the configured noise for this sample.
    pub fn publish_with_std(
        &mut self,
        channel: u32,
        t_meas_ns: u64,
        values: &[f64],
        std: &[f64],
    ) -> Result<u64, SensorError> {
        self.publish_checked(channel, t_meas_ns, values, Some(std))
    }

    fn publish_checked(
        &mut self,
        channel: u32,
        t_meas_ns: u64,
        values: &[f64],
        std: Option<&[f64]>,
    ) -> Result<u64, SensorError> {
        check_values(values, std)?;
        if t_meas_ns == 0 {
            return Err(SensorError::ZeroTime);
        }
        let now_ns = monotonic_now_ns();
        if t_meas_ns > now_ns {
            return Err(SensorError::FutureTime {
                t_ns: t_meas_ns,
                now_ns,
            });
        }
        let idx = match self.channels.iter().position(|c| c.channel == channel) {
            Some(i) => i,
            None => {
                self.channels.push(ChannelState {
                    channel,
                    next_seq: 0,
                    last_t_ns: 0,
                });
                self.channels.len() - 1
            }
        };
        let st = self.channels[idx];
        if t_meas_ns < st.last_t_ns {
            return Err(SensorError::TimeBackwards {
                channel,
                t_ns: t_meas_ns,
                last_ns: st.last_t_ns,
            });
        }
        let mut s = SensorSample::new(channel, st.next_seq, t_meas_ns, values);
        if let Some(std) = std {
            s = s.with_noise_std(std);
        }
        s.t_pub_ns = monotonic_now_ns();
        self.publisher.publish(&s)?;
        let c = &mut self.channels[idx];
        c.next_seq += 1;
        c.last_t_ns = t_meas_ns;
        Ok(st.next_seq)
    }

    /// Send `sample` exactly as given except `t_pub_ns`, which is set to
    /// now when it is 0. No checks and no numbering: for replaying recorded
    /// samples and for fault injection (ingest rejects what is invalid).
    pub fn publish_sample(&mut self, sample: &SensorSample) -> Result<(), SensorError> {
        let mut s = *sample;
        if s.t_pub_ns == 0 {
            s.t_pub_ns = monotonic_now_ns();
        }
        self.publisher.publish(&s)?;
        Ok(())
    }
}

/// The value and σ rules of ABI v1.
fn check_values(values: &[f64], std: Option<&[f64]>) -> Result<(), SensorError> {
    if values.is_empty() || values.len() > SENSOR_MAX_DIM {
        return Err(SensorError::Dimension { got: values.len() });
    }
    if let Some((index, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(SensorError::NonFinite { index, value });
    }
    if let Some(std) = std {
        if std.len() != values.len() {
            return Err(SensorError::NoiseLength {
                values: values.len(),
                std: std.len(),
            });
        }
        if let Some((index, &value)) = std
            .iter()
            .enumerate()
            .find(|(_, v)| !(v.is_finite() && **v > 0.0))
        {
            return Err(SensorError::BadNoise { index, value });
        }
    }
    Ok(())
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cleanup;

    /// A fresh prefix, removed when dropped.
    struct Prefix(String);
    impl Prefix {
        fn new() -> Self {
            Self(cleanup::run_prefix())
        }
    }
    impl Drop for Prefix {
        fn drop(&mut self) {
            let _ = cleanup::remove_prefix(&self.0);
        }
    }

    fn ingest(p: &Prefix) -> (Bus, Subscriber<SensorSample>) {
        let cfg = BusConfig {
            prefix: p.0.clone(),
            instance: "t".into(),
        };
        let bus = Bus::open(&cfg, "ingest").unwrap();
        let sub = bus.subscriber::<SensorSample>().unwrap();
        (bus, sub)
    }

    #[test]
    fn samples_arrive_numbered_per_channel_with_every_field() {
        let p = Prefix::new();
        let (_bus, sub) = ingest(&p);
        let mut s = SensorPublisher::connect("t", &p.0).unwrap();
        assert_eq!(s.subscribers(), 1);
        let t0 = monotonic_now_ns();
        assert_eq!(s.publish(3, t0, &[1.5, -2.0]).unwrap(), 0);
        assert_eq!(s.publish(9, t0, &[7.0]).unwrap(), 0);
        assert_eq!(
            s.publish_with_std(3, t0 + 1, &[1.0, 2.0], &[0.5, 0.25])
                .unwrap(),
            1
        );
        assert_eq!(s.next_seq(3), 2);
        assert_eq!(s.next_seq(9), 1);
        assert_eq!(s.next_seq(4), 0);

        let a = sub.receive().unwrap().unwrap();
        assert_eq!((a.channel, a.seq, a.dim, a.flags), (3, 0, 2, 0));
        assert_eq!(a.t_meas_ns, t0);
        assert!(a.t_pub_ns >= t0);
        assert_eq!(&a.values[..3], &[1.5, -2.0, 0.0]);
        assert_eq!(a.reserved, [0; 8]);
        let b = sub.receive().unwrap().unwrap();
        assert_eq!((b.channel, b.seq, b.dim), (9, 0, 1));
        let c = sub.receive().unwrap().unwrap();
        assert_eq!((c.channel, c.seq, c.flags), (3, 1, 1));
        assert!(c.has_noise_std());
        assert_eq!(&c.noise_std[..2], &[0.5, 0.25]);
        assert!(sub.receive().unwrap().is_none());
    }

    #[test]
    fn bad_input_is_a_typed_error_and_nothing_is_sent() {
        let p = Prefix::new();
        let (_bus, sub) = ingest(&p);
        let mut s = SensorPublisher::connect("t", &p.0).unwrap();
        let t = monotonic_now_ns();
        let e = |r: Result<u64, SensorError>| r.unwrap_err();
        assert_eq!(e(s.publish(0, t, &[])), SensorError::Dimension { got: 0 });
        assert_eq!(
            e(s.publish(0, t, &[0.0; 9])),
            SensorError::Dimension { got: 9 }
        );
        assert!(matches!(
            e(s.publish(0, t, &[1.0, f64::INFINITY])),
            SensorError::NonFinite { index: 1, .. }
        ));
        assert_eq!(
            e(s.publish_with_std(0, t, &[1.0, 2.0], &[1.0])),
            SensorError::NoiseLength { values: 2, std: 1 }
        );
        assert!(matches!(
            e(s.publish_with_std(0, t, &[1.0, 2.0], &[1.0, 0.0])),
            SensorError::BadNoise { index: 1, .. }
        ));
        assert!(matches!(
            e(s.publish_with_std(0, t, &[1.0], &[f64::NAN])),
            SensorError::BadNoise { index: 0, .. }
        ));
        assert_eq!(e(s.publish(0, 0, &[1.0])), SensorError::ZeroTime);
        assert!(matches!(
            e(s.publish(0, t + 60_000_000_000, &[1.0])),
            SensorError::FutureTime { .. }
        ));
        assert!(sub.receive().unwrap().is_none(), "nothing was sent");
        assert_eq!(s.sent(), 0);
        // Time may repeat but not go back; a refused sample uses no seq.
        assert_eq!(s.publish(0, t, &[1.0]).unwrap(), 0);
        assert_eq!(s.publish(0, t, &[1.0]).unwrap(), 1);
        assert_eq!(
            e(s.publish(0, t - 1, &[1.0])),
            SensorError::TimeBackwards {
                channel: 0,
                t_ns: t - 1,
                last_ns: t
            }
        );
        // Another channel has its own clock history.
        assert_eq!(s.publish(1, t - 1, &[1.0]).unwrap(), 0);
        assert_eq!(s.publish(0, t + 1, &[1.0]).unwrap(), 2);
        assert_eq!(s.sent(), 4);
    }

    #[test]
    fn publish_sample_sends_faults_unchanged() {
        let p = Prefix::new();
        let (_bus, sub) = ingest(&p);
        let mut s = SensorPublisher::connect("t", &p.0).unwrap();
        let mut bad = SensorSample::new(5, 42, 7, &[f64::NAN, f64::NEG_INFINITY]);
        bad.reserved0 = 0xdead;
        s.publish_sample(&bad).unwrap();
        let got = sub.receive().unwrap().unwrap();
        assert!(got.values[0].is_nan() && got.values[1] == f64::NEG_INFINITY);
        assert_eq!((got.channel, got.seq, got.t_meas_ns), (5, 42, 7));
        assert_eq!(got.reserved0, 0xdead);
        assert!(got.t_pub_ns > 0, "publish time stamped");
    }

    #[test]
    fn oversized_values_are_never_silently_truncated() {
        let s = SensorSample::new(0, 0, 1, &[1.0; 9]);
        assert_eq!(s.dim, 9, "dim keeps the true length so ingest rejects it");
        assert_eq!(s.values, [1.0; SENSOR_MAX_DIM]);
    }

    #[test]
    fn wait_for_subscribers_sees_a_late_ingest() {
        let p = Prefix::new();
        let s = SensorPublisher::connect("t", &p.0).unwrap();
        assert_eq!(s.subscribers(), 0);
        assert!(!s.wait_for_subscribers(1, Duration::from_millis(10)));
        let (_bus, _sub) = ingest(&p);
        assert!(s.wait_for_subscribers(1, Duration::from_secs(5)));
    }

    #[test]
    fn the_actuator_wakes_for_each_control_and_sees_the_newest() {
        let p = Prefix::new();
        let cfg = BusConfig {
            prefix: p.0.clone(),
            instance: "t".into(),
        };
        let mut act = ControlSubscriber::connect("t", &p.0).unwrap();
        assert!(act.wait(Duration::from_millis(5)).unwrap().is_none());
        let (ack_tx, ack_rx) = std::sync::mpsc::channel::<()>();
        let producer = std::thread::spawn(move || {
            let bus = Bus::open(&cfg, "control").unwrap();
            let mut pubr = bus.publisher::<Control>().unwrap();
            // Paced: the next control only after the actuator has read one.
            for k in 0..3u64 {
                let mut c = Control {
                    dim: 2,
                    ..Control::default()
                };
                c.header.seq = k;
                c.u[0] = k as f64;
                pubr.publish(&c).unwrap();
                ack_rx.recv().unwrap();
            }
            // A burst: the actuator only needs the newest.
            for k in 3..10u64 {
                let mut c = Control::default();
                c.header.seq = k;
                pubr.publish(&c).unwrap();
            }
            // Keep the publisher alive until the actuator is done.
            let _ = ack_rx.recv();
        });
        let mut seqs = Vec::new();
        while let Some(c) = act.wait(Duration::from_secs(10)).unwrap() {
            seqs.push(c.header.seq);
            if c.header.seq < 3 {
                assert_eq!(c.u[0], c.header.seq as f64);
                ack_tx.send(()).unwrap();
            }
            if c.header.seq == 9 {
                break;
            }
        }
        ack_tx.send(()).unwrap();
        producer.join().unwrap();
        assert_eq!(&seqs[..3], &[0, 1, 2], "every paced control woke it");
        assert_eq!(*seqs.last().unwrap(), 9);
        assert!(seqs.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(act.received(), seqs.len() as u64);
    }
}
