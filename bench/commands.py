#!/usr/bin/env python3
"""Two shell commands timed side by side, interleaved: A B A B ... in one run.

    .venv/bin/python bench/commands.py --rounds 5 \\
        ".venv/bin/gx2ctl export REC --out /tmp/a --format parquet" \\
        ".venv/bin/gx2ctl export REC --out /tmp/b --format parquet --time refined"

Each round runs A then B, or B then A (alternating, so neither always goes first), each
in a shell of its own; the wall seconds and the CPU seconds (user and system, of the
command and its children) of each run are kept. Prints min / median / max of each, and
the median of the rounds' B/A ratios. A command that fails stops the run with its
output. For what a program costs from its start (imports, start-up and its work), where
bench/ab.py measures the gateway's read path.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time


def timed(command: str) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of one run of ``command`` in a shell."""
    before = os.times()
    start = time.perf_counter()
    ran = subprocess.run(command, shell=True, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - start
    after = os.times()
    if ran.returncode != 0:
        sys.exit(f"commands.py: {command!r} exited {ran.returncode}:\n{ran.stdout}{ran.stderr}")
    cpu = (after.children_user - before.children_user) + \
        (after.children_system - before.children_system)
    return wall, cpu


def spread(values: list[float]) -> str:
    return f"{min(values):.2f} / {statistics.median(values):.2f} / {max(values):.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("a")
    parser.add_argument("b")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--warm", type=int, default=1, help="untimed runs of each first")
    args = parser.parse_args()
    for _ in range(args.warm):
        timed(args.a)
        timed(args.b)
    runs: dict[str, list[tuple[float, float]]] = {"A": [], "B": []}
    for round_ in range(args.rounds):
        for side in ("A", "B") if round_ % 2 == 0 else ("B", "A"):
            runs[side].append(timed(args.a if side == "A" else args.b))
    print(f"$ bench/commands.py --rounds {args.rounds}\n  A: {args.a}\n  B: {args.b}")
    print("| | wall s min / median / max | CPU s min / median / max |")
    print("|---|---|---|")
    for side in ("A", "B"):
        print(f"| {side} | {spread([w for w, _ in runs[side]])} | "
              f"{spread([c for _, c in runs[side]])} |")
    pairs = list(zip(runs["A"], runs["B"], strict=True))
    for label, at in (("wall", 0), ("CPU", 1)):
        ratios = [b[at] / a[at] for a, b in pairs if a[at] > 0]
        print(f"B/A {label}, the median of the rounds: "
              + (f"{statistics.median(ratios):.2f}" if ratios else "-"))


if __name__ == "__main__":
    main()
