#!/usr/bin/env python3
"""Where a Foxglove viewer's cost goes in the gateway, thread by thread. Run by hand:

    python bench/viewer_threads.py             # about a minute

The demo's configuration (three nodes at 100 Hz on the embedded simulator, live view
on) on free ports; a viewer (the tests' independent client) connects and, in turn,
subscribes to every channel or to none, then reads for the window. Printed per round:
each thread's CPU over the window, as a share of one core, from /proc/PID/task/*/stat
(the gateway's own threads and foxglove-sdk's runtime threads by name).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml
from benchutil import free_port

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
from tests.helpers.viewer import Viewer  # noqa: E402  (the tests' independent client)

TICK = os.sysconf("SC_CLK_TCK")


def thread_ticks(pid: int) -> dict[tuple[str, str], int]:
    """(thread id, name) -> user + system clock ticks so far."""
    ticks = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            text = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
        except OSError:
            continue  # (it ended)
        name = text[text.index("(") + 1:text.rindex(")")]
        fields = text[text.rindex(")") + 2:].split()
        ticks[(tid, name)] = int(fields[11]) + int(fields[12])
    return ticks


def connect(url: str, deadline: float) -> Viewer:
    while True:  # (the live view may not listen yet)
        try:
            return Viewer(url)
        except ConnectionRefusedError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def measure(subscribe: bool, seconds: float, settle: float) -> dict[str, float]:
    """Each thread name's share of a core (summed over threads of one name)."""
    work = Path(tempfile.mkdtemp(prefix="gx2-viewer-threads-"))
    config = yaml.safe_load((REPO / "config" / "demo.yaml").read_text())
    live = f"127.0.0.1:{free_port()}"
    config["publish"]["endpoint"] = f"tcp://127.0.0.1:{free_port()}"
    config["control"]["endpoint"] = f"tcp://127.0.0.1:{free_port()}"
    config["metrics"]["endpoint"] = f"127.0.0.1:{free_port()}"
    config["live"]["endpoint"] = live
    (work / "nodes.yaml").write_text(yaml.safe_dump(config))
    gateway = subprocess.Popen([str(Path(sys.executable).parent / "gx2-gateway"), "--config",
                                str(work / "nodes.yaml"), "--log-level", "WARNING"])
    try:
        viewer = connect(f"ws://{live}", time.monotonic() + 30)
        viewer.until(lambda v: len(v.channels) >= len(config["nodes"]), 30, "channels")
        if subscribe:
            viewer.subscribe(*viewer.channels)
        end = time.monotonic() + settle + seconds + 1

        def read() -> None:
            while time.monotonic() < end:
                viewer.read(0.5)
                viewer.messages.clear()
        reader = threading.Thread(target=read)
        reader.start()
        time.sleep(settle)
        before, t0 = thread_ticks(gateway.pid), time.monotonic()
        time.sleep(seconds)
        after, elapsed = thread_ticks(gateway.pid), time.monotonic() - t0
        reader.join()
    finally:
        gateway.terminate()
        gateway.wait(10)
    shares: dict[str, float] = {}
    for key, ticks in after.items():
        used = (ticks - before.get(key, 0)) / TICK / elapsed * 100
        shares[key[1]] = shares.get(key[1], 0.0) + used
    return shares


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--settle", type=float, default=3.0)
    args = parser.parse_args()
    rows = []
    for round_ in range(1, args.rounds + 1):
        for subscribe in (True, False):  # (interleaved)
            shares = measure(subscribe, args.seconds, args.settle)
            rows.append((round_, "every channel" if subscribe else "none", shares))
    names = sorted({name for _, _, shares in rows for name in shares})
    print("\n| round | viewer subscribed to | " + " | ".join(names) + " | total |")
    print("|---|---|" + "---|" * (len(names) + 1))
    for round_, subscribed, shares in rows:
        cells = " | ".join(f"{shares.get(name, 0.0):.1f}%" for name in names)
        print(f"| {round_} | {subscribed} | {cells} | {sum(shares.values()):.1f}% |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
