#!/usr/bin/env python3
"""NodeClock.update's cost per record, trees side by side, interleaved: each round
runs every tree once, in a fresh process with that tree's aspp first on the path, over
the same pairs (device, arrival) of a line model run (bench/linemodels.py). Run by hand:

    git worktree add --detach /tmp/before main
    .venv/bin/python bench/clockcost.py /tmp/before . --rounds 5
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def once(model: str, seed: int, seconds: float, repeats: int = 5) -> float:
    """Microseconds per update, best of ``repeats``, with the aspp on the path."""
    import linemodels

    from aspp.timing import TimerUnwrapper

    run = linemodels.MODELS[model](seed, seconds)
    streams: dict[tuple[int, int], list[tuple[float, float]]] = {}
    unwrappers: dict[int, TimerUnwrapper] = {}
    for p in run.packets:
        if p.ticks is not None:
            arrival = p.read - p.size * linemodels.BYTE_TIME
            device = unwrappers.setdefault(p.node, TimerUnwrapper()).update(p.ticks, arrival)
            streams.setdefault((p.node, p.segment), []).append((device, arrival))
    return linemodels.update_cost(streams, repeats)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trees", nargs="*", default=["."])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--model", default="gx2sim")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--once", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.once:
        print(f"{once(args.model, args.seed, args.seconds):.3f}")
        return 0
    results: dict[str, list[float]] = {tree: [] for tree in args.trees}
    for _ in range(args.rounds):
        for tree in args.trees:
            env = dict(os.environ, PYTHONPATH=str(Path(tree).resolve()))
            out = subprocess.run([sys.executable, str(HERE / "clockcost.py"), "--once",
                                  "--model", args.model, "--seed", str(args.seed),
                                  "--seconds", str(args.seconds)],
                                 env=env, check=True, capture_output=True, text=True)
            results[tree].append(float(out.stdout))
    print(f"NodeClock.update, us a record ({args.model} seed {args.seed}, "
          f"{args.seconds:.0f} s; {args.rounds} interleaved rounds, best of 5 each)")
    for tree, values in results.items():
        print(f"{tree}: median {statistics.median(values):.2f}, rounds "
              + ", ".join(f"{v:.2f}" for v in values))
    return 0


if __name__ == "__main__":
    sys.exit(main())
