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

use super::messages::{SensorSample, SENSOR_MAX_DIM};
use super::ports::{Message, Publisher};
use super::{Bus, BusConfig, IpcError};
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

mod actuator;
pub use actuator::ControlSubscriber;

#[cfg(test)]
mod tests;
