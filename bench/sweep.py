#!/usr/bin/env python3
"""Sample time over many line models in simulated time (issue 32): the distribution,
over the runs, of each run's figures (bench/linemodels.py's Figures: ``time``'s p99
spread, the worst, how far apart the nodes' median errors are, how far a node's error
moves in a minute), against the targets: over every run, and split by whether every
stream showed the host its floor in each 10 s (where one did not, the stretch is one
no estimate can place in general: linemodels.behind); then how many of the samples
that were off the floor's WARN covered. Run by hand:

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
from linemodels import FLOOR_UNSEEN_S, GOOD, MODELS, OFF, VISIBLE_BIN, Figures

import aspp.clock

TARGETS = {"p99": (0.2, 0.5), "apart": (0.15, None), "drift": (None, 0.1)}
"""Per figure (ms): the bound 95% of runs must keep, and the one every run must."""


def _one(job: tuple[str, int, float, bool]) -> tuple[int, Figures]:
    model, seed, seconds, refined = job
    streams = linemodels.feed(MODELS[model](seed, seconds))
    if refined:
        streams = linemodels.refined_streams(streams)
    return seed, linemodels.measure(streams)


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


def said(model: str, figures: list[Figures]) -> None:
    """Whether status said when ``time`` was off: the samples off by more than OFF from
    the run's median error at which the clock's floor age was past FLOOR_UNSEEN_S (the
    WARN), against those within GOOD at which it was all the same."""
    off, off_said = sum(f.off for f in figures), sum(f.off_said for f in figures)
    good, good_said = sum(f.good for f in figures), sum(f.good_said for f in figures)
    print(f"\n{model}: of the samples more than {OFF * 1e3:g} ms off, {off_said / max(off, 1):.1%} "
          f"were under a floor-unseen WARN ({off_said} of {off}); of those within "
          f"{GOOD * 1e3:g} ms, {good_said / max(good, 1):.1%} ({good_said} of {good}) "
          f"(after the first {FLOOR_UNSEEN_S:g} s of each stream)")
    bounded = sum(getattr(f, "bounded", 0) for f in figures)
    broken = sum(getattr(f, "bound_broken", 0) for f in figures)
    print(f"{model}: samples given a bound of how late time may be (late_ms) {bounded}, "
          f"later than it {broken}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=[*MODELS, "both"], default="both")
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--first", type=int, default=1, help="the first seed")
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--refined", action="store_true",
                        help="the time placed after the fact from the whole run "
                             "(aspp.refine), not the live one")
    args = parser.parse_args()
    print(f"$ {' '.join(sys.argv)}  (aspp from {aspp.clock.__file__}; "
          f"{'refined after the fact' if args.refined else 'live'} time)")
    models = list(MODELS) if args.model == "both" else [args.model]
    start = time.monotonic()
    with Pool(max(1, min(args.workers, 2))) as pool:
        for model in models:
            jobs = [(model, seed, args.seconds, args.refined)
                    for seed in range(args.first, args.first + args.runs)]
            results = sorted(pool.map(_one, jobs, chunksize=4))
            report(model, results)
            report(model, [r for r in results if r[1].visible >= 1.0],
                   f", the runs where every stream showed the host its floor in each "
                   f"{VISIBLE_BIN:g} s")
            report(model, [r for r in results if r[1].visible < 1.0],
                   f", the others (a stream {VISIBLE_BIN:g} s or more with no floor shown)")
            said(model, [f for _, f in results])
    print(f"\n({time.monotonic() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
