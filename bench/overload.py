#!/usr/bin/env python3
"""Sample time on a serial line over capacity (issue 21), measured. Run by hand:

    python bench/overload.py                  # about 100 s
    python bench/overload.py --over 80 --room 15

gx2-sim in this process: nodes 76 and 77 stream ``accel_angrate`` and node 78
``accel_angrate_orientation``, all at 100 Hz: about 135% of what 115200 baud carries,
so the simulated base station's buffer fills and drops, as a real one's would. After
``--over`` seconds node 78 is stopped (``gx2ctl stop 78``) and the line has room; the
run goes on for ``--room`` seconds. The installed gx2-gateway publishes; a subscriber
here keeps nodes 76's and 77's records, and the simulator knows when each was sampled.

Printed, per node: the largest step of ``time - device_time`` between two records (the
promise: at most a sample period, 10 ms, unless the node rebooted); whether ``time``
ever stood still or went back; the error against the true instant while overloaded
(p50 / max) and from 10 s after the line had room (max: the promise is 1 ms); and what
status said while overloaded (the gateway's reasons, each node's lock and drift).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from itertools import pairwise
from pathlib import Path
from typing import Any

import msgpack
import yaml
import zmq
from benchutil import free_port

from gateway.sim.base_station import RADIO_LATENCY
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator

DIVIDER = 512
"""100 Hz."""
NODES = [NodeSettings(76, divider=DIVIDER, stream="accel_angrate", ppm=30.0),
         NodeSettings(77, divider=DIVIDER, stream="accel_angrate", ppm=-20.0),
         NodeSettings(78, divider=DIVIDER, stream="accel_angrate_orientation")]
WATCHED = (76, 77)
SETTLE_S = 10.0
"""Seconds after the line has room from which the estimate must be within 1 ms."""


def script(name: str) -> str:
    return shutil.which(name, path=str(Path(sys.executable).parent)) or name


def ctl(config: Path, *args: str) -> str:
    done = subprocess.run([script("gx2ctl"), "--config", str(config), *args],
                          capture_output=True, text=True, timeout=60)
    return done.stdout + done.stderr


def status(config: Path) -> dict[str, Any]:

    return json.loads(ctl(config, "--json", "status"))


def run(over: float, room: float) -> None:
    work = Path(tempfile.mkdtemp(prefix="gx2-overload-"))
    sim = Simulator(NODES, link=work / "gx2").start()
    publish = f"tcp://127.0.0.1:{free_port()}"
    config = work / "nodes.yaml"
    config.write_text(yaml.safe_dump({
        "base_station": {"port": str(work / "gx2"), "latency_ms": RADIO_LATENCY * 1000},
        "publish": {"endpoint": publish},
        "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
        "metrics": {"endpoint": f"127.0.0.1:{free_port()}"},
        "nodes": [{"address": n.address} for n in NODES]}))
    proc = subprocess.Popen([script("gx2-gateway"), "--config", str(config),
                             "--log-level", "WARNING"], stdout=subprocess.DEVNULL)
    context = zmq.Context()
    sub = context.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    for node in WATCHED:
        sub.setsockopt(zmq.SUBSCRIBE, f"gx2/{node}/accel_angrate".encode())
    sub.connect(publish)
    records: dict[int, list[dict[str, Any]]] = {n: [] for n in WATCHED}
    said: dict[str, Any] = {}
    try:
        start = time.monotonic()
        room_at = None
        while (now := time.monotonic()) - start < over + room:
            if room_at is None and now - start >= over:
                said = status(config)
                print(ctl(config, "stop", "78").strip())
                room_at = time.time()
            if sub.poll(100):
                record = msgpack.unpackb(sub.recv_multipart()[1])
                records[record["node"]].append(record)
        truths = {n: sim.call(lambda station, _, n=n: dict(station.nodes[n].sampled))
                  for n in WATCHED}
        dropped = sim.station.stats.packets_dropped_full
        line = sim.station.stats.bytes_sent / (time.monotonic() - start) / (115200 / 10)
        print(f"(the simulator sent {100 * line:.0f}% of the line's capacity; idle "
              f"{sim.station.stats.line_idle:.1f} s)")
    finally:
        proc.terminate()
        proc.wait(10)
        sim.stop()
        context.destroy(linger=0)
        shutil.rmtree(work, ignore_errors=True)
    shift = statistics.median(time.time() - time.monotonic() for _ in range(9))
    gateway = said.get("gateway", {})
    print(f"\n{over:.0f} s over capacity ({dropped:,} packets dropped by the base station's "
          f"full buffer), then {room:.0f} s with room")
    print(f"status while over: gateway {gateway.get('health')} {gateway.get('reasons')}, "
          f"link over_capacity={said.get('link', {}).get('over_capacity')}")
    print("| node | largest step of time - device_time (ms) | time ever still or back "
          "| error over capacity p50 / max (ms) | error from 10 s after room, max (ms) "
          "| status while over: locked, drift (ppm), reasons |")
    print("|---|---|---|---|---|---|")
    nodes = {n["node"]: n for n in said.get("nodes", [])}
    for node in WATCHED:
        got = [r for r in records[node] if r["timer"] in truths[node]]
        steps = [abs((b["time"] - b["device_time"]) - (a["time"] - a["device_time"]))
                 for a, b in pairwise(got)]
        still = any(b["time"] <= a["time"] for a, b in pairwise(got))
        errors = [(r["host_time"], r["time"] - truths[node][r["timer"]] - shift) for r in got]
        during = [abs(e) for t, e in errors if room_at is not None and t < room_at]
        after = [abs(e) for t, e in errors if room_at is not None and t > room_at + SETTLE_S]
        clock = (nodes.get(node) or {}).get("clock") or {}
        print(f"| {node} | {max(steps) * 1e3:.1f} | {'yes' if still else 'no'} "
              f"| {statistics.median(during) * 1e3:.1f} / {max(during) * 1e3:.1f} "
              f"| {max(after) * 1e3:.3f} | {clock.get('locked')}, {clock.get('drift_ppm')}, "
              f"{(nodes.get(node) or {}).get('reasons')} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--over", type=float, default=80.0,
                        help="seconds over capacity (default 80: past the clock's "
                             "60 s window)")
    parser.add_argument("--room", type=float, default=15.0,
                        help="seconds after node 78 is stopped (default 15)")
    args = parser.parse_args()
    run(args.over, args.room)
    return 0


if __name__ == "__main__":
    sys.exit(main())
