"""beliefbus wire ABI v1 for Python: ctypes structures and connection helpers.

Everything here follows docs/sensor-abi.md; that document is the contract,
this module is one implementation of it (iceoryx2 Python package 0.10.0).

- ``SensorSample``  beliefbus.SensorSample.v1  service beliefbus/<instance>/sensor
- ``Control``       beliefbus.Control.v1       service beliefbus/<instance>/control
- ``Truth``         beliefbus.Truth.v1         service beliefbus/<instance>/truth

``SensorPublisher`` and ``ControlSubscriber`` mirror the Rust API in
crates/beliefbus-ipc/src/sensor_api.rs: they open the services with the pipeline's QoS and
enforce the publisher rules before anything is sent.
"""

import ctypes
import math
import time

import iceoryx2 as iox2

SENSOR_MAX_DIM = 8
MAX_STATE = 8
MAX_OBS = 8
MAX_CONTROL = 4
SENSOR_FLAG_NOISE_STD = 1
DEFAULT_PREFIX = "iox2_beliefbus_"
DEFAULT_INSTANCE = "ship"


class SensorSample(ctypes.Structure):
    """A sensor sample, ABI v1: 232 bytes, alignment 8."""

    _fields_ = [
        ("seq", ctypes.c_uint64),  # 0   per-channel sequence number 0, 1, 2, ...
        ("t_meas_ns", ctypes.c_uint64),  # 8   measurement time, CLOCK_MONOTONIC ns
        ("t_pub_ns", ctypes.c_uint64),  # 16  publish time, CLOCK_MONOTONIC ns
        ("channel", ctypes.c_uint32),  # 24  sensor channel id
        ("dim", ctypes.c_uint32),  # 28  valid entries of values (1..8)
        ("flags", ctypes.c_uint32),  # 32  bit 0: noise_std valid
        ("reserved0", ctypes.c_uint32),  # 36  0
        ("values", ctypes.c_double * SENSOR_MAX_DIM),  # 40
        ("noise_std", ctypes.c_double * SENSOR_MAX_DIM),  # 104
        ("reserved", ctypes.c_uint64 * 8),  # 168 0
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name; must equal the Rust #[type_name]."""
        return "beliefbus.SensorSample.v1"


class Header(ctypes.Structure):
    """The header every pipeline message starts with (24 bytes)."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("t_valid_ns", ctypes.c_uint64),
        ("t_pub_ns", ctypes.c_uint64),
    ]


class Trace(ctypes.Structure):
    """Latency trace of the sensor sample a message derives from (80 bytes)."""

    _fields_ = [
        ("sensor_seq", ctypes.c_uint64),
        ("sensor_channel", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
        ("t_meas_ns", ctypes.c_uint64),
        ("t_sensor_pub_ns", ctypes.c_uint64),
        ("t_ingest_in_ns", ctypes.c_uint64),
        ("t_ingest_out_ns", ctypes.c_uint64),
        ("t_filter_in_ns", ctypes.c_uint64),
        ("t_filter_out_ns", ctypes.c_uint64),
        ("t_control_in_ns", ctypes.c_uint64),
        ("t_control_out_ns", ctypes.c_uint64),
    ]


class Control(ctypes.Structure):
    """A control, ABI v1: 184 bytes, alignment 8."""

    _fields_ = [
        ("header", Header),  # 0
        ("trace", Trace),  # 24
        ("dim", ctypes.c_uint32),  # 104 valid entries of u
        ("status", ctypes.c_uint32),  # 108 0 ok, 1 fallback
        ("u", ctypes.c_double * MAX_CONTROL),  # 112
        ("cost", ctypes.c_double),  # 144
        ("goal", ctypes.c_double * 2),  # 152 active waypoint (x, y)
        ("waypoint_index", ctypes.c_uint32),  # 168
        ("reserved", ctypes.c_uint32),  # 172
        ("waypoints_reached", ctypes.c_uint64),  # 176
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name; must equal the Rust #[type_name]."""
        return "beliefbus.Control.v1"


class Truth(ctypes.Structure):
    """What a simulated plant really did, for evaluation: 200 bytes."""

    _fields_ = [
        ("header", Header),  # 0   seq/t_valid of the sensor sample
        ("channel", ctypes.c_uint32),  # 24
        ("dim", ctypes.c_uint32),  # 28  state dimension
        ("obs_dim", ctypes.c_uint32),  # 32
        ("control_dim", ctypes.c_uint32),  # 36
        ("x", ctypes.c_double * MAX_STATE),  # 40  true state
        ("u", ctypes.c_double * MAX_CONTROL),  # 104 applied control
        ("y", ctypes.c_double * MAX_OBS),  # 136 the published measurement
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name; must equal the Rust #[type_name]."""
        return "beliefbus.Truth.v1"


# Service QoS of each channel (crates/beliefbus-ipc/src/ports.rs). Whoever comes first
# creates the service with these settings; everyone else must ask for no
# more than the existing service offers, so use exactly these.
QOS = {
    "sensor": dict(history=0, max_buffer=256, max_publishers=16, max_subscribers=8, max_nodes=32),
    "control": dict(history=1, max_buffer=256, max_publishers=2, max_subscribers=6, max_nodes=20),
    "truth": dict(history=0, max_buffer=512, max_publishers=2, max_subscribers=4, max_nodes=20),
}


def now_ns() -> int:
    """CLOCK_MONOTONIC now in ns: the clock of every stamp on the wire."""
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


def abi_description() -> dict:
    """Size, alignment, type name and field offsets of each structure."""
    out = {}
    for t in (SensorSample, Control, Truth):
        out[t.__name__] = {
            "type_name": t.type_name(),
            "size": ctypes.sizeof(t),
            "alignment": ctypes.alignment(t),
            "offsets": {name: getattr(t, name).offset for name, _ in t._fields_},
        }
    return out


def open_node(prefix: str, name: str):
    """An iceoryx2 node under the pipeline's shared-memory prefix."""
    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    config = iox2.config.global_config()
    config.global_cfg.prefix = iox2.FileName.new(prefix)
    return iox2.NodeBuilder.new().name(iox2.NodeName.new(name)).config(config).create(
        iox2.ServiceType.Ipc
    )


def open_pubsub(node, instance: str, channel: str, payload):
    """Open (or create) beliefbus/<instance>/<channel> with its QoS."""
    q = QOS[channel]
    return (
        node.service_builder(iox2.ServiceName.new(f"beliefbus/{instance}/{channel}"))
        .publish_subscribe(payload)
        .history_size(q["history"])
        .subscriber_max_buffer_size(q["max_buffer"])
        .enable_safe_overflow(True)
        .max_publishers(q["max_publishers"])
        .max_subscribers(q["max_subscribers"])
        .max_nodes(q["max_nodes"])
        .open_or_create()
    )


def open_event(node, instance: str, channel: str):
    """The event service of the same name (default settings)."""
    return (
        node.service_builder(iox2.ServiceName.new(f"beliefbus/{instance}/{channel}"))
        .event()
        .open_or_create()
    )


class SensorError(ValueError):
    """A sample that breaks the publisher rules; nothing was sent."""


class SensorPublisher:
    """Publishes sensor samples; numbers each channel's samples 0, 1, 2, ..."""

    def __init__(self, prefix: str = DEFAULT_PREFIX, instance: str = DEFAULT_INSTANCE,
                 node_name: str = "py-sensor"):
        self.node = open_node(prefix, node_name)
        self.service = open_pubsub(self.node, instance, "sensor", SensorSample)
        self.publisher = self.service.publisher_builder().create()
        self.notifier = open_event(self.node, instance, "sensor").notifier_builder().create()
        self.next_seq: dict[int, int] = {}
        self.last_t: dict[int, int] = {}
        self.sent = 0

    def subscribers(self) -> int:
        """Subscribers connected now (the pipeline's ingest is one)."""
        return self.service.dynamic_config.number_of_subscribers

    def wait_for_subscribers(self, n: int = 1, timeout_s: float = 10.0) -> bool:
        """Wait until ``n`` subscribers are connected (samples sent earlier are lost)."""
        until = time.monotonic() + timeout_s
        while self.subscribers() < n:
            if time.monotonic() >= until:
                return False
            time.sleep(0.005)
        return True

    def publish(self, channel: int, t_meas_ns: int, values, noise_std=None) -> int:
        """Check and send one sample; returns its sequence number."""
        values = [float(v) for v in values]
        if not 1 <= len(values) <= SENSOR_MAX_DIM:
            raise SensorError(f"a sample carries 1 to {SENSOR_MAX_DIM} values, got {len(values)}")
        for i, v in enumerate(values):
            if not math.isfinite(v):
                raise SensorError(f"value {i} is not finite ({v})")
        if noise_std is not None:
            noise_std = [float(s) for s in noise_std]
            if len(noise_std) != len(values):
                raise SensorError(f"{len(values)} values need {len(values)} noise sigma")
            for i, s in enumerate(noise_std):
                if not (math.isfinite(s) and s > 0.0):
                    raise SensorError(f"noise sigma {i} must be finite and > 0, got {s}")
        if t_meas_ns <= 0:
            raise SensorError("measurement time must be CLOCK_MONOTONIC ns > 0")
        now = now_ns()
        if t_meas_ns > now:
            raise SensorError(f"measurement time {t_meas_ns} is in the future (now {now})")
        if t_meas_ns < self.last_t.get(channel, 0):
            raise SensorError(f"channel {channel}: measurement time goes backwards")
        seq = self.next_seq.get(channel, 0)
        s = SensorSample(seq=seq, t_meas_ns=t_meas_ns, channel=channel, dim=len(values))
        for i, v in enumerate(values):
            s.values[i] = v
        if noise_std is not None:
            s.flags = SENSOR_FLAG_NOISE_STD
            for i, v in enumerate(noise_std):
                s.noise_std[i] = v
        self.publish_sample(s)
        self.next_seq[channel] = seq + 1
        self.last_t[channel] = t_meas_ns
        return seq

    def publish_sample(self, s: SensorSample) -> None:
        """Send ``s`` unchecked (replay, fault injection); stamps t_pub_ns if 0."""
        if s.t_pub_ns == 0:
            s.t_pub_ns = now_ns()
        self.publisher.send_copy(s)
        self.notifier.notify()
        self.sent += 1

    def close(self, linger_s: float = 0.2) -> None:
        """Release the ports and the node (also happens at exit).

        Waits ``linger_s`` first: a subscriber that has not yet mapped this
        publisher's memory cannot read the last samples once it is gone.
        """
        if linger_s > 0 and hasattr(self, "publisher"):
            time.sleep(linger_s)
        for attr in ("notifier", "publisher", "service"):
            if hasattr(self, attr):
                delattr(self, attr)
        if hasattr(self, "node"):
            del self.node


class ControlSubscriber:
    """Receives controls (latest value) for an actuator."""

    def __init__(self, prefix: str = DEFAULT_PREFIX, instance: str = DEFAULT_INSTANCE,
                 node_name: str = "py-actuator"):
        self.node = open_node(prefix, node_name)
        self.service = open_pubsub(self.node, instance, "control", Control)
        self.subscriber = self.service.subscriber_builder().buffer_size(1).create()
        self.listener = open_event(self.node, instance, "control").listener_builder().create()
        self.received = 0

    def try_latest(self):
        """The newest unread control (a ``Control`` copy) or None."""
        latest = None
        while True:
            sample = self.subscriber.receive()
            if sample is None:
                break
            latest = Control.from_buffer_copy(sample.payload().contents)
        if latest is not None:
            self.received += 1
        return latest

    def wait(self, timeout_s: float):
        """Block until a new control arrives or ``timeout_s`` passes (None)."""
        until = time.monotonic() + timeout_s
        while True:
            c = self.try_latest()
            if c is not None:
                return c
            left = until - time.monotonic()
            if left <= 0:
                return None
            self.listener.timed_wait(iox2.Duration.from_secs_f64(left))

    def close(self) -> None:
        """Release the ports and the node (also happens at exit)."""
        for attr in ("listener", "subscriber", "service"):
            if hasattr(self, attr):
                delattr(self, attr)
        if hasattr(self, "node"):
            del self.node


class TruthPublisher:
    """Publishes Truth for evaluation by the launcher (simulated plants only)."""

    def __init__(self, node, instance: str):
        self.service = open_pubsub(node, instance, "truth", Truth)
        self.publisher = self.service.publisher_builder().create()

    def publish(self, t: Truth) -> None:
        if t.header.t_pub_ns == 0:
            t.header.t_pub_ns = now_ns()
        self.publisher.send_copy(t)
