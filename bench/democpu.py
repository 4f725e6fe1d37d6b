"""What the demo costs: the CPU share of a core each thread of the gateway takes while
it runs ``config/demo.yaml`` as README starts it (three nodes at 100 Hz on the built-in
simulator, metrics and the live view served, nobody connected).

The simulator runs in the gateway's process (its thread is named ``gx2-sim``), so
``top`` shows the two together; this splits them, from each thread's user and system
ticks in ``/proc/PID/task/TID/stat`` over a span after a warm-up.

    .venv/bin/python bench/democpu.py [--seconds 20] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

from benchutil import gateway_command

ROOT = Path(__file__).resolve().parent.parent
TICKS = os.sysconf("SC_CLK_TCK")


def thread_ticks(pid: int) -> dict[str, int]:
    """Ticks of CPU (user + system) so far, by thread name (threads of one name summed)."""
    ticks: dict[str, int] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # (a thread that ended meanwhile)
            continue
        ticks[name] = ticks.get(name, 0) + int(fields[11]) + int(fields[12])
    return ticks


def one_round(seconds: float, warm: float) -> dict[str, float]:
    gateway = subprocess.Popen([gateway_command(), "--config", "config/demo.yaml"],
                               cwd=ROOT, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    try:
        time.sleep(warm)
        before, started = thread_ticks(gateway.pid), time.monotonic()
        time.sleep(seconds)
        after, span = thread_ticks(gateway.pid), time.monotonic() - started
    finally:
        gateway.terminate()
        gateway.wait(10)
    return {name: (after[name] - before.get(name, 0)) / TICKS / span
            for name in after}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--warm", type=float, default=5.0)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    rounds = [one_round(args.seconds, args.warm) for _ in range(args.rounds)]
    names = sorted({n for r in rounds for n in r}, key=lambda n: -rounds[0].get(n, 0.0))
    print(f"the demo's threads, share of a core over {args.seconds:g} s, "
          f"{args.rounds} rounds")
    for name in names:
        shares = [r.get(name, 0.0) for r in rounds]
        if max(shares) >= 0.001:
            print(f"  {name:<18} " + "  ".join(f"{s:6.1%}" for s in shares))
    totals = [sum(r.values()) for r in rounds]
    sim = [r.get("gx2-sim", 0.0) for r in rounds]
    print(f"  {'all':<18} " + "  ".join(f"{s:6.1%}" for s in totals))
    print(f"  {'all but gx2-sim':<18} " + "  ".join(f"{t - s:6.1%}"
                                                  for t, s in zip(totals, sim, strict=True)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
