#!/usr/bin/env python3
"""What the gateway costs while a command waits behind a bias capture (issue 19).

    .venv/bin/python bench/capture_cpu.py [--ms 5000] [--seconds 3]

gx2-sim (one node, 76, streaming 0xC2 at its default rate) behind a pty and the
installed gx2-gateway. The gateway's CPU, from the kernel's per-thread nanoseconds, as
% of one core and as clock ticks per 3 s (what ``top`` and /proc/PID/stat count):

1. idle: streaming, nothing asked, over ``--seconds``;
2. ``gx2ctl bias capture 76 --ms MS`` alone, from the capture reaching the node until
   gx2ctl exits;
3. the same with ``gx2ctl poll 76 accel_angrate`` sent once the capture reached the
   node: the poll waits in the scheduler behind the capture's awaited reply.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
from benchutil import cpu_ns, free_port

from gateway.sim.node import NodeSettings
from gateway.sim.physics import Motion
from gateway.sim.server import Simulator
from tests.helpers.simulated import received
from tests.helpers.waiting import wait_for

BIN = Path(sys.executable).parent
TICKS = os.sysconf("SC_CLK_TCK")


def status(config: Path) -> str:
    ran = subprocess.run([str(BIN / "gx2ctl"), "--config", str(config), "status"],
                         capture_output=True, text=True, check=False)
    return ran.stdout


def capture(sim: Simulator, config: Path, pid: int, ms: int, poll: bool) -> tuple[float, float]:
    """One capture (and a queued poll): the gateway's CPU seconds and the wall seconds
    from the capture reaching the node until gx2ctl exits."""
    ctl = [str(BIN / "gx2ctl"), "--config", str(config)]
    done = len(received(sim, 76, 0xCD))
    running = subprocess.Popen([*ctl, "bias", "capture", "76", "--ms", str(ms)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_for(lambda: len(received(sim, 76, 0xCD)) > done, 10, "the capture to reach 76")
    before, start = cpu_ns(pid), time.monotonic()
    polling = (subprocess.Popen([*ctl, "--timeout", str(ms / 1000 + 5), "poll", "76",
                                 "accel_angrate"], stdout=subprocess.DEVNULL)
               if poll else None)
    if running.wait(ms / 1000 + 20) != 0:
        raise SystemExit("capture_cpu.py: the capture failed")
    used, wall = (cpu_ns(pid) - before) / 1e9, time.monotonic() - start
    if polling is not None and polling.wait(20) != 0:
        raise SystemExit("capture_cpu.py: the poll failed")
    return used, wall


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ms", type=int, default=5000)
    parser.add_argument("--seconds", type=float, default=3.0)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="gx2-capture-cpu-"))
    config = {"base_station": {"port": str(work / "gx2")},
              "publish": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
              "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
              "nodes": [{"address": 76, "stream": "accel_angrate"}]}
    path = work / "nodes.yaml"
    path.write_text(yaml.safe_dump(config))
    sim = Simulator([NodeSettings(76, motion=Motion(yaw_rate=0.0))], link=work / "gx2").start()
    gateway = subprocess.Popen([str(BIN / "gx2-gateway"), "--config", str(path),
                                "--log-level", "WARNING"])
    try:
        wait_for(lambda: "streaming" in status(path), 20, "node 76 streaming")
        before, start = cpu_ns(gateway.pid), time.monotonic()
        time.sleep(args.seconds)  # the interval measured
        rows = {"idle (streaming)": ((cpu_ns(gateway.pid) - before) / 1e9,
                                     time.monotonic() - start)}
        rows[f"bias capture --ms {args.ms}"] = capture(sim, path, gateway.pid, args.ms, False)
        rows[f"bias capture --ms {args.ms} + queued poll"] = capture(
            sim, path, gateway.pid, args.ms, True)
    finally:
        gateway.terminate()
        gateway.wait(10)
        sim.stop()
    print("| gx2-gateway | seconds | % of one core | ticks per 3 s |\n|---|---|---|---|")
    for name, (used, wall) in rows.items():
        print(f"| {name} | {wall:.1f} | {used / wall * 100:.1f} | "
              f"{used / wall * 3 * TICKS:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
