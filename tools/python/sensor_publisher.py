#!/usr/bin/env python3
"""Example beliefbus sensor publisher in Python (iceoryx2 0.10.0).

Modes:
  (default)    simulate the drifting ship (paper 001 eq. 10-11), or follow a
               deterministic circle (--trajectory circle), and publish its
               range/bearing at --rate for --duration seconds; --faults mixes
               in bad samples and a 10x rate burst and reports what it injected
  --pattern N  publish N deterministic samples with every byte set (ABI check)
  --print-abi  print the ctypes layouts as JSON and exit

See README.md here and docs/sensor-abi.md.
"""

import argparse
import json
import math
import random
import sys

import beliefbus_abi as abi


def pattern_sample(k: int) -> abi.SensorSample:
    """Sample k of the ABI pattern: every field distinct and exactly representable.

    tests/sensor_abi.rs recomputes the same values and compares every field.
    """
    s = abi.SensorSample()
    s.seq = k
    s.t_meas_ns = 10**12 + 1000 * k
    s.t_pub_ns = 2 * 10**12 + 1000 * k
    s.channel = 7 + k % 3
    s.dim = 1 + k % abi.SENSOR_MAX_DIM
    s.flags = k % 2
    s.reserved0 = 0xA5A50000 + k
    for j in range(abi.SENSOR_MAX_DIM):
        s.values[j] = k + j / 8.0 - 3.0
        s.noise_std[j] = (k + 1) * 0.5**j
        s.reserved[j] = 0x0102030405060708 * (j + 1) + k
    return s


class Ship:
    """Euler-Maruyama simulation of the drifting ship (crates/beliefbus-core/src/model/ship.rs)."""

    def __init__(self, x0, e=0.3, radius=9.0, wall_gain=50.0, seed=1):
        self.x = list(x0)
        self.e = e
        self.radius = radius
        self.wall_gain = wall_gain
        self.u = [0.0, 0.0]
        self.rng = random.Random(seed)

    def step(self, dt: float) -> None:
        x1, x2, x3, x4 = self.x
        rho = math.hypot(x1, x2)
        f1 = f2 = 0.0
        if rho >= self.radius and x1 * x3 + x2 * x4 >= 0.0:
            f1 = -self.wall_gain * x1 / rho
            f2 = -self.wall_gain * x2 / rho
        sq = self.e * math.sqrt(dt)
        g = self.rng.gauss
        self.x = [
            x1 + x3 * dt + sq * g(0.0, 1.0),
            x2 + x4 * dt + sq * g(0.0, 1.0),
            x3 + (f1 + self.u[0]) * dt + sq * g(0.0, 1.0),
            x4 + (f2 + self.u[1]) * dt + sq * g(0.0, 1.0),
        ]

    def measure(self, range_std: float, bearing_std: float):
        x1, x2 = self.x[0], self.x[1]
        r = math.hypot(x1, x2) + range_std * self.rng.gauss(0.0, 1.0)
        b = math.atan2(x2, x1) + bearing_std * self.rng.gauss(0.0, 1.0)
        b = math.atan2(math.sin(b), math.cos(b))  # wrap to (-pi, pi]
        return [r, b]


def run_pattern(pub: abi.SensorPublisher, n: int) -> None:
    for k in range(n):
        pub.publish_sample(pattern_sample(k))


class Circle:
    """A deterministic target on a circle: x(t) = R (cos wt, sin wt), t from t0.

    Several publishers given the same --t0-ns measure the same target.
    """

    def __init__(self, radius: float, omega: float, t0_ns: int, seed: int):
        self.radius, self.omega, self.t0_ns = radius, omega, t0_ns
        self.x = [radius, 0.0, 0.0, radius * omega]
        self.u = [0.0, 0.0]
        self.rng = random.Random(seed)

    def at(self, t_ns: int) -> None:
        a = self.omega * (t_ns - self.t0_ns) / 1e9
        r, w = self.radius, self.omega
        self.x = [r * math.cos(a), r * math.sin(a), -r * w * math.sin(a), r * w * math.cos(a)]

    measure = Ship.measure


# Faults injected by --faults, in turn, and the ingest reason each must get.
FAULTS = [
    ("nan", "non_finite"),
    ("inf", "non_finite"),
    ("dimension", "dimension"),
    ("time_backwards", "time_backwards"),
    ("duplicate", "duplicate"),
    ("unknown_channel", "unknown_channel"),
    ("too_old", "too_old"),
]
UNKNOWN_CHANNEL = 9999
TOO_OLD_NS = 5_000_000_000


def fault_sample(kind: str, channel: int, next_seq: int, last_t: int, values) -> abi.SensorSample:
    """A bad sample right after a good one (last_t, next_seq) on the channel."""
    s = abi.SensorSample(seq=next_seq, t_meas_ns=last_t, channel=channel, dim=len(values))
    for i, v in enumerate(values):
        s.values[i] = v
    if kind == "nan":
        s.values[0] = math.nan
    elif kind == "inf":
        s.values[len(values) - 1] = math.inf
    elif kind == "dimension":
        s.dim = len(values) + 1
    elif kind == "time_backwards":
        s.t_meas_ns = last_t - 1_000_000
    elif kind == "duplicate":
        s.seq = next_seq - 1
    elif kind == "unknown_channel":
        s.channel = UNKNOWN_CHANNEL
        s.seq = next_seq
    elif kind == "too_old":
        s.t_meas_ns = last_t - TOO_OLD_NS
    return s


def sleep_until(node, t_ns: int) -> None:
    """Sleep until CLOCK_MONOTONIC reaches t_ns (never returns early)."""
    while True:
        delay = (t_ns - abi.now_ns()) / 1e9
        if delay <= 0:
            return
        node.wait(abi.iox2.Duration.from_secs_f64(delay))


def run_stream(args, pub: abi.SensorPublisher) -> dict:
    """Publish the target's measurements on a fixed schedule (+ faults, burst)."""
    period_ns = int(round(1e9 / args.rate))
    sample_dt = 1.0 / args.rate
    sigma = 0.03 / math.sqrt(sample_dt) if args.noise_std is None else args.noise_std
    if args.trajectory == "circle":
        target = Circle(args.radius, args.omega, args.t0_ns or abi.now_ns(), args.seed)
    else:
        target = Ship(args.initial_state, seed=args.seed)
    comps = [c.strip() for c in args.components.split(",")]
    idx = {"range": 0, "bearing": 1}
    truth = abi.TruthPublisher(pub.node, args.instance) if args.truth else None
    actuator = abi.ControlSubscriber(args.prefix, args.instance, "py-plant") if args.apply_controls else None
    n = int(round(args.duration * args.rate))
    burst_at = args.burst_at if args.burst_at is not None else n // 2
    injected: dict[str, int] = {}
    good = 0
    n_fault = 0
    t_prev = abi.now_ns()
    t_next = t_prev + period_ns

    def advance(t_ns: int) -> None:
        if isinstance(target, Circle):
            target.at(t_ns)
        else:
            dt = (t_ns - advance.t) / 1e9
            steps = max(1, int(math.ceil(dt / args.integration_dt)))
            for _ in range(steps):
                target.step(dt / steps)
        advance.t = t_ns

    advance.t = t_prev

    def publish_good(t_meas: int):
        nonlocal good
        sleep_until(pub.node, t_meas)
        if actuator is not None:
            c = actuator.try_latest()
            if c is not None and c.dim >= 2:
                target.u = [c.u[0], c.u[1]]
        advance(t_meas)
        y = target.measure(sigma, sigma)
        values = [y[idx[c]] for c in comps]
        seq = pub.publish(args.channel, t_meas, values)
        good += 1
        if truth is not None:
            t = abi.Truth(channel=args.channel, dim=4, obs_dim=2, control_dim=2)
            t.header.seq = seq
            t.header.t_valid_ns = t_meas
            for i in range(4):
                t.x[i] = target.x[i]
            t.u[0], t.u[1] = target.u
            t.y[0], t.y[1] = y
            truth.publish(t)
        return values

    burst = None
    for k in range(n):
        values = publish_good(t_next)
        last_t = t_next
        if args.faults and (k + 1) % args.fault_every == 0:
            kind, reason = FAULTS[n_fault % len(FAULTS)]
            n_fault += 1
            pub.publish_sample(fault_sample(kind, args.channel, pub.next_seq[args.channel], last_t, values))
            injected[reason] = injected.get(reason, 0) + 1
        if args.faults and k == burst_at and args.burst_len > 0:
            # 10x the rate: valid samples, too many of them.
            spacing = period_ns // 10
            for _ in range(args.burst_len):
                last_t += spacing
                publish_good(last_t)
            burst = {"n": args.burst_len, "spacing_ns": spacing, "start_ns": t_next + spacing}
            t_next = last_t
        t_next += period_ns
    out = {"sent": pub.sent, "good": good, "period_ns": period_ns, "final_state": target.x}
    if args.faults:
        out["injected"] = injected
        out["burst"] = burst
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--prefix", default=abi.DEFAULT_PREFIX, help="shared-memory prefix of the run")
    ap.add_argument("--instance", default=abi.DEFAULT_INSTANCE, help="pipeline instance (run.instance)")
    ap.add_argument("--channel", type=int, default=0, help="sensor channel id")
    ap.add_argument("--rate", type=float, default=100.0, help="samples per second")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds to publish")
    ap.add_argument("--integration-dt", type=float, default=1e-3, help="simulation step (s)")
    ap.add_argument("--initial-state", type=float, nargs=4, default=[3.0, 0.0, 0.0, 0.0])
    ap.add_argument("--noise-std", type=float, default=None, help="range and bearing sigma (default 0.03/sqrt(1/rate))")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--truth", action="store_true", help="also publish Truth for the run's accuracy figures")
    ap.add_argument("--apply-controls", action="store_true", help="apply the pipeline's controls to the ship")
    ap.add_argument("--wait-ingest", type=float, default=10.0, help="seconds to wait for a subscriber (0: don't)")
    ap.add_argument("--trajectory", choices=["ship", "circle"], default="ship",
                    help="ship: simulate the drifting ship; circle: deterministic circle (shared via --t0-ns)")
    ap.add_argument("--radius", type=float, default=5.0, help="circle radius")
    ap.add_argument("--omega", type=float, default=0.3, help="circle angular rate (rad/s)")
    ap.add_argument("--t0-ns", type=int, default=0, help="circle phase origin, CLOCK_MONOTONIC ns (0: now)")
    ap.add_argument("--components", default="range,bearing",
                    help="observation components to publish, in value order (range, bearing)")
    ap.add_argument("--faults", action="store_true",
                    help="inject bad samples (NaN, inf, dimension, time reversal, duplicate, unknown channel, too old) and a 10x rate burst")
    ap.add_argument("--fault-every", type=int, default=5, help="one bad sample after every N good ones")
    ap.add_argument("--burst-at", type=int, default=None, help="good sample index after which the burst comes (default: half way)")
    ap.add_argument("--burst-len", type=int, default=30, help="samples in the 10x rate burst")
    ap.add_argument("--pattern", type=int, default=None, metavar="N", help="publish N ABI pattern samples")
    ap.add_argument("--print-abi", action="store_true", help="print the ctypes layouts as JSON and exit")
    args = ap.parse_args()

    if args.print_abi:
        print(json.dumps(abi.abi_description()))
        return 0
    if not args.rate > 0:
        ap.error("--rate must be > 0")

    pub = abi.SensorPublisher(args.prefix, args.instance, "py-sensor")
    print(f"publisher ready on beliefbus/{args.instance}/sensor (prefix {args.prefix})", file=sys.stderr, flush=True)
    if args.wait_ingest > 0 and not pub.wait_for_subscribers(1, args.wait_ingest):
        print(f"no subscriber on beliefbus/{args.instance}/sensor after {args.wait_ingest} s", file=sys.stderr)
        return 3
    try:
        if args.pattern is not None:
            run_pattern(pub, args.pattern)
            summary = {"sent": args.pattern}
        else:
            summary = run_stream(args, pub)
    except abi.iox2.NodeWaitFailure:
        summary = {"sent": pub.sent, "interrupted": True}
    summary["service"] = f"beliefbus/{args.instance}/sensor"
    print(json.dumps(summary), flush=True)
    pub.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
