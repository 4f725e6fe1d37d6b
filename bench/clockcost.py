#!/usr/bin/env python3
"""What ``NodeClock.update`` costs a record, this checkout's against another commit's,
interleaved (A B A B ...) over the same packets, so a busy neighbour slows both.

Run by hand, not in CI:

    .venv/bin/python bench/clockcost.py [--against main] [--rounds 9]

The packets: one node at 100 Hz for 5 minutes, its delays above the floor exponential
(mean 0.3 ms), with stretches of 40 s in which every packet waits behind another
node's (1 to 3.4 ms), one a minute: the path a packet near the floor takes and the one
it does not. Prints each side's best and median microseconds a record, and the median
of the rounds' ratios (this checkout over the other).
"""

from __future__ import annotations

import argparse
import importlib.util
import random
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aspp import clock as this  # noqa: E402

PERIOD = 0.01


def packets(seconds: float = 300.0, seed: int = 1) -> list[tuple[float, float]]:
    rng = random.Random(seed)
    out = []
    for i in range(round(seconds / PERIOD)):
        device = i * PERIOD
        queued = device % 60 >= 20
        delay = rng.uniform(0.001, 0.0034) if queued else rng.expovariate(1 / 0.0003)
        out.append((device, 1000.0 + (1 + 30e-6) * device + 0.003 + delay))
    return out


def other(commit: str):
    """aspp/clock.py as it is at ``commit``, imported beside this checkout's."""
    source = subprocess.run(["git", "show", f"{commit}:aspp/clock.py"], cwd=ROOT,
                            check=True, capture_output=True, text=True).stdout
    spec = importlib.util.spec_from_loader("aspp._clock_other", loader=None)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = "aspp"
    sys.modules[spec.name] = module  # (its dataclass looks its module up)
    exec(compile(source, f"{commit}:aspp/clock.py", "exec"), module.__dict__)
    return module


def per_record(make, pairs: list[tuple[float, float]]) -> float:
    clock = make()
    update = clock.update
    start = time.perf_counter()
    for device, host in pairs:
        update(device, host)
    return (time.perf_counter() - start) / len(pairs) * 1e6


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", default="main", help="the commit to compare with")
    parser.add_argument("--rounds", type=int, default=9)
    args = parser.parse_args()
    before = other(args.against)
    pairs = packets()
    mine: list[float] = []
    theirs: list[float] = []
    for _ in range(args.rounds):
        theirs.append(per_record(before.NodeClock, pairs))
        mine.append(per_record(this.NodeClock, pairs))
    ratio = statistics.median(m / t for m, t in zip(mine, theirs, strict=True))
    print(f"{args.against}: best {min(theirs):.3f} us, median {statistics.median(theirs):.3f}"
          f" us a record")
    print(f"this checkout: best {min(mine):.3f} us, median {statistics.median(mine):.3f}"
          f" us a record")
    print(f"ratio (this / {args.against}), median of {args.rounds} rounds: {ratio:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
