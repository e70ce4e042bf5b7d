#!/usr/bin/env python3
"""Example beliefbus sensor publisher in Python (iceoryx2 0.10.0).

Modes:
  (default)    simulate the drifting ship (paper 001 eq. 10-11) and publish
               range/bearing samples at --rate for --duration seconds
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
    """Euler-Maruyama simulation of the drifting ship (src/model/ship.rs)."""

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


def run_ship(args, pub: abi.SensorPublisher) -> dict:
    period_ns = int(round(1e9 / args.rate))
    sample_dt = 1.0 / args.rate
    sigma = 0.03 / math.sqrt(sample_dt) if args.noise_std is None else args.noise_std
    substeps = max(1, int(math.ceil(sample_dt / args.integration_dt)))
    ship = Ship(args.initial_state, seed=args.seed)
    truth = abi.TruthPublisher(pub.node, args.instance) if args.truth else None
    actuator = abi.ControlSubscriber(args.prefix, args.instance, "py-plant") if args.apply_controls else None
    n = int(round(args.duration * args.rate))
    t_next = abi.now_ns() + period_ns
    sent = 0
    for k in range(n):
        # Sleep until the measurement instant (absolute, no drift).
        delay = (t_next - abi.now_ns()) / 1e9
        if delay > 0:
            pub.node.wait(abi.iox2.Duration.from_secs_f64(delay))
        if actuator is not None:
            c = actuator.try_latest()
            if c is not None:
                ship.u = [c.u[0], c.u[1]] if c.dim >= 2 else [0.0, 0.0]
        for _ in range(substeps):
            ship.step(sample_dt / substeps)
        t_meas = abi.now_ns()
        y = ship.measure(sigma, sigma)
        seq = pub.publish(args.channel, t_meas, y)
        sent += 1
        if truth is not None:
            t = abi.Truth(channel=args.channel, dim=4, obs_dim=2, control_dim=2)
            t.header.seq = seq
            t.header.t_valid_ns = t_meas
            for i in range(4):
                t.x[i] = ship.x[i]
            t.u[0], t.u[1] = ship.u
            t.y[0], t.y[1] = y
            truth.publish(t)
        t_next += period_ns
    return {"sent": sent, "final_state": ship.x}


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
            summary = run_ship(args, pub)
    except abi.iox2.NodeWaitFailure:
        summary = {"sent": pub.sent, "interrupted": True}
    summary["service"] = f"beliefbus/{args.instance}/sensor"
    print(json.dumps(summary), flush=True)
    pub.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
