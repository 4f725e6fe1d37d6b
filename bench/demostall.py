#!/usr/bin/env python3
"""The demo as README starts it, stopped for a while: how long until it is all well
again. Run by hand (not in CI):

    python bench/demostall.py --stall 2 --runs 5

config/demo.yaml (its built-in simulator, three nodes at 100 Hz: 93% of the line, a
little radio loss and garbage) on ports of its own, the installed gx2-gateway. Once
the gateway and every node are OK with their clocks locked, it is stopped (SIGSTOP)
for ``--stall`` seconds, as a VM's steal or a slow disk would, then continued; status
is polled every 0.2 s until the gateway and every node are OK and locked again. Each
run prints the seconds from the stall's end to that, and whether the line was said
over capacity meanwhile (before issue 38 it was, for good).
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml
import zmq
from benchutil import Watcher, free_port, gateway_command

REPO = Path(__file__).resolve().parents[1]
POLL_S = 0.2
BOUND_S = 60.0


def all_well(status: dict[str, Any]) -> bool:
    return (status["gateway"]["health"] == "OK"
            and all(n["health"] == "OK" and (n["clock"] or {}).get("locked") is True
                    for n in status["nodes"]))


def until_well(watch: Watcher, bound: float) -> tuple[float | None, bool]:
    """Seconds until all is well (None: not within ``bound``), and whether the line was
    said over capacity meanwhile."""
    start, over = time.monotonic(), False
    while time.monotonic() - start < bound:
        status = watch.status()
        if status is not None:
            over = over or bool(status["link"].get("over_capacity"))
            if all_well(status):
                return time.monotonic() - start, over
        time.sleep(POLL_S)
    return None, over


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stall", type=float, default=2.0)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="gx2-demostall-"))
    config = yaml.safe_load((REPO / "config" / "demo.yaml").read_text())
    publish, control = (f"tcp://127.0.0.1:{free_port()}" for _ in range(2))
    config["publish"]["endpoint"], config["control"]["endpoint"] = publish, control
    for section in ("metrics", "live"):
        config.pop(section, None)
    (work / "demo.yaml").write_text(yaml.safe_dump(config))
    with (work / "gateway.log").open("w") as log:
        gateway = subprocess.Popen([gateway_command(), "--config", str(work / "demo.yaml")],
                                   stdout=log, stderr=subprocess.STDOUT)
    context = zmq.Context()
    watch = Watcher(context, publish, control)
    failed = False
    try:
        settled, _ = until_well(watch, BOUND_S)
        print(f"demo all well {settled:.1f} s after start" if settled is not None
              else "demo never all well before the first stall")
        for run in range(1, args.runs + 1):
            gateway.send_signal(signal.SIGSTOP)
            time.sleep(args.stall)  # (the stall itself)
            gateway.send_signal(signal.SIGCONT)
            seconds, over = until_well(watch, BOUND_S)
            said = "line said over capacity" if over else "line never said over capacity"
            after = f"more than {BOUND_S:g}" if seconds is None else f"{seconds:.1f}"
            print(f"run {run}: {args.stall:g} s stall, all well again after {after} s, "
                  f"{said}", flush=True)
            failed = failed or seconds is None or over
            time.sleep(5.0)  # (quiet between stalls)
    finally:
        gateway.send_signal(signal.SIGCONT)
        gateway.terminate()
        gateway.wait(10)
        context.destroy(linger=0)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
