#!/usr/bin/env python3
"""Sample time over many line models in simulated time (issue 32): the distribution,
over the runs, of each run's figures (bench/linemodels.py's Figures: ``time``'s p99
spread, the worst, how far apart the nodes' median errors are, how far a node's error
moves in a minute), against the targets. Run by hand:

    .venv/bin/python bench/sweep.py                       # both models, 200 runs each
    .venv/bin/python bench/sweep.py --model fifo --runs 50 --seconds 90
    PYTHONPATH=/tmp/before .venv/bin/python bench/sweep.py   # another tree's aspp

Two worker processes at most (``--workers``): the runs are independent.
"""

from __future__ import annotations

import argparse
import sys
import time
from multiprocessing import Pool

import linemodels
from linemodels import MODELS, Figures

import aspp.clock

TARGETS = {"p99": (0.2, 0.5), "apart": (0.15, None), "drift": (None, 0.1)}
"""Per figure (ms): the bound 95% of runs must keep, and the one every run must."""


def _one(job: tuple[str, int, float]) -> tuple[int, Figures]:
    model, seed, seconds = job
    return seed, linemodels.run(model, seed, seconds)


def quantile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def held(figures: list[Figures]) -> dict[str, bool]:
    """Whether each target holds over the runs."""
    out = {}
    for name, (most, every) in TARGETS.items():
        values = [getattr(f, name) for f in figures]
        out[name] = ((most is None or quantile(values, 0.95) <= most)
                     and (every is None or max(values) <= every))
    return out


SEEN = 0.05
"""A run whose every stream had at least this share of packets find the line free."""


def report(model: str, results: list[tuple[int, Figures]], title: str = "") -> None:
    figures = [f for _, f in results]
    if not figures:
        return
    print(f"\n{model}{title}: {len(figures)} runs")
    print("| figure (ms) | median | p95 | max | worst seeds |")
    print("|---|---|---|---|---|")
    for name in ("p99", "apart", "worst", "drift"):
        values = [getattr(f, name) for f in figures]
        worst = sorted(results, key=lambda r: -getattr(r[1], name))[:3]
        seeds = ", ".join(f"{seed} ({getattr(f, name):.2f})" for seed, f in worst)
        print(f"| {name} | {quantile(values, 0.5):.3f} | {quantile(values, 0.95):.3f} "
              f"| {max(values):.3f} | {seeds} |")
    print("targets: " + ", ".join(f"{k} {'held' if v else 'NOT held'}"
                                  for k, v in held(figures).items()))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=[*MODELS, "both"], default="both")
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--first", type=int, default=1, help="the first seed")
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    print(f"$ {' '.join(sys.argv)}  (aspp from {aspp.clock.__file__})")
    models = list(MODELS) if args.model == "both" else [args.model]
    start = time.monotonic()
    with Pool(max(1, min(args.workers, 2))) as pool:
        for model in models:
            jobs = [(model, seed, args.seconds)
                    for seed in range(args.first, args.first + args.runs)]
            results = sorted(pool.map(_one, jobs, chunksize=4))
            report(model, results)
            report(model, [r for r in results if r[1].free >= SEEN],
                   f", the runs whose every stream found the line free for {SEEN:.0%} or "
                   "more of its packets")
            report(model, [r for r in results if r[1].free < SEEN],
                   f", the others (a stream with under {SEEN:.0%} free)")
    print(f"\n({time.monotonic() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
