#!/usr/bin/env python3
"""What watching costs: ``gx2ctl top``'s own CPU while it watches a saturated line.

    .venv/bin/python bench/watching.py [--seconds 60]

gx2-sim streams 3 nodes of 0xC2 at 96 Hz (99% of the 115,200-baud line) into the
installed gx2-gateway; ``gx2ctl top`` runs in a real terminal (a tmux pane of 80x24)
and, beside it for comparison, ``gx2ctl tail`` into /dev/null (a subscriber to every
record). Each one's CPU over ``--seconds``, from the kernel's per-thread nanoseconds,
as % of one core; the gateway's own CPU in the same interval is shown beside them.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
from benchutil import cpu_ns, free_port

from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator
from tests.helpers.waiting import wait_for

BIN = Path(sys.executable).parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    if shutil.which("tmux") is None:
        raise SystemExit("watching.py: needs tmux (Debian: apt-get install tmux)")
    work = Path(tempfile.mkdtemp(prefix="gx2-watching-"))
    nodes = [NodeSettings(a, divider=533, stream="accel_angrate") for a in (76, 77, 78)]
    config = {"base_station": {"port": str(work / "gx2")},
              "publish": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
              "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
              "nodes": [{"address": n.address, "stream": "accel_angrate"} for n in nodes]}
    path = work / "nodes.yaml"
    path.write_text(yaml.safe_dump(config))
    socket = f"gx2-watching-{free_port()}"
    sim = Simulator(nodes, link=work / "gx2").start()
    gateway = subprocess.Popen([str(BIN / "gx2-gateway"), "--config", str(path),
                                "--log-level", "WARNING"])
    tail = None
    try:
        time.sleep(6.0)  # started, armed and streaming (a settling period, not a sync)
        pid_file = work / "top.pid"
        command = (f"echo $$ > {pid_file}; exec {shlex.quote(str(BIN / 'gx2ctl'))} "
                   f"--config {shlex.quote(str(path))} top")
        subprocess.run(["tmux", "-L", socket, "-f", "/dev/null", "new-session", "-d",
                        "-x", "80", "-y", "24", command], check=True)
        top = int(wait_for(lambda: pid_file.exists() and pid_file.read_text().strip(), 10,
                           "top's process id"))
        tail = subprocess.Popen([str(BIN / "gx2ctl"), "--config", str(path), "tail"],
                                stdout=subprocess.DEVNULL)
        time.sleep(3.0)  # both subscribed and drawing
        pids = {"gx2ctl top (tmux, 80x24)": top, "gx2ctl tail > /dev/null": tail.pid,
                "gx2-gateway": gateway.pid}
        before = {name: cpu_ns(pid) for name, pid in pids.items()}
        start = time.monotonic()
        time.sleep(args.seconds)
        elapsed = time.monotonic() - start
        used = {name: (cpu_ns(pid) - before[name]) / 1e9 / elapsed * 100
                for name, pid in pids.items()}
        screen = subprocess.run(["tmux", "-L", socket, "capture-pane", "-p"],
                                capture_output=True, text=True, check=True).stdout
    finally:
        subprocess.run(["tmux", "-L", socket, "kill-server"], check=False,
                       capture_output=True)
        if tail is not None:
            tail.terminate()
            tail.wait(10)
        gateway.terminate()
        gateway.wait(10)
        sim.stop()
    print(screen.rstrip())
    print(f"\n3 nodes x 96 Hz of 0xC2 (99% of the line), CPU over {elapsed:.0f} s:")
    print("| process | % of one core |\n|---|---|")
    for name, share in used.items():
        print(f"| {name} | {share:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
