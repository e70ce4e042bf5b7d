#!/usr/bin/env python3
"""Example beliefbus actuator in Python (iceoryx2 0.10.0).

Receives the pipeline's controls on beliefbus/<instance>/control (a
latest-value channel: it always sees the newest control) and "applies" them:
here it prints one line per control, or one JSON object per control with
--json. Stops after --count controls, after --duration seconds, after
--idle seconds without a control, or on Ctrl-C; the last line is a JSON
summary.

See README.md here and docs/sensor-abi.md.
"""

import argparse
import json
import sys
import time

import beliefbus_abi as abi


def control_dict(c: abi.Control) -> dict:
    """Every field of a control, for --json."""
    h, tr = c.header, c.trace
    return {
        "seq": h.seq,
        "t_valid_ns": h.t_valid_ns,
        "t_pub_ns": h.t_pub_ns,
        "trace": {name: getattr(tr, name) for name, _ in abi.Trace._fields_},
        "dim": c.dim,
        "status": c.status,
        "u": list(c.u),
        "cost": c.cost,
        "goal": list(c.goal),
        "waypoint_index": c.waypoint_index,
        "waypoints_reached": c.waypoints_reached,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--prefix", default=abi.DEFAULT_PREFIX, help="shared-memory prefix of the run")
    ap.add_argument("--instance", default=abi.DEFAULT_INSTANCE, help="pipeline instance (run.instance)")
    ap.add_argument("--count", type=int, default=0, help="stop after this many controls (0: no limit)")
    ap.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: no limit)")
    ap.add_argument("--idle", type=float, default=5.0, help="stop after this many seconds without a control")
    ap.add_argument("--json", action="store_true", help="print each control as a JSON object")
    args = ap.parse_args()

    act = abi.ControlSubscriber(args.prefix, args.instance, "py-actuator")
    print(f"listening on beliefbus/{args.instance}/control", file=sys.stderr, flush=True)
    start = time.monotonic()
    latencies_us = []
    try:
        while True:
            wait = args.idle
            if args.duration > 0:
                wait = min(wait, args.duration - (time.monotonic() - start))
                if wait <= 0:
                    break
            c = act.wait(wait)
            if c is None:
                if args.duration > 0 and time.monotonic() - start < args.duration:
                    continue
                break
            now = abi.now_ns()
            if c.header.t_pub_ns:
                latencies_us.append((now - c.header.t_pub_ns) / 1e3)
            if args.json:
                print(json.dumps(control_dict(c)), flush=True)
            else:
                u = ", ".join(f"{v:+.3f}" for v in c.u[: min(c.dim, abi.MAX_CONTROL)])
                print(f"control {c.header.seq}: u = [{u}] status {c.status}", flush=True)
            if args.count and act.received >= args.count:
                break
    except KeyboardInterrupt:
        pass
    latencies_us.sort()
    summary = {"received": act.received}
    if latencies_us:
        summary["control_to_actuator_p50_us"] = latencies_us[len(latencies_us) // 2]
    print(json.dumps({"summary": summary}), flush=True)
    act.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
