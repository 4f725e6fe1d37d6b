#!/usr/bin/env python3
"""Live against refined time (aspp.refine), per seed of both line models (issue 46):
each run's p99 of |error - median| and how far apart its nodes' medians are, live and
refined, their medians over the seeds, and the runs refined made better or worse.

    .venv/bin/python bench/refinecompare.py              # 20 seeds a model, 120 s
    .venv/bin/python bench/refinecompare.py --seeds 50 --seconds 300
"""

from __future__ import annotations

import argparse
import statistics
from multiprocessing import Pool

import linemodels
from linemodels import MODELS


def one(job: tuple[str, int, float]) -> tuple[str, int, float, float, float, float]:
    model, seed, seconds = job
    streams = linemodels.feed(MODELS[model](seed, seconds))
    live = linemodels.measure(streams)
    refined = linemodels.measure(linemodels.refined_streams(streams))
    return model, seed, live.p99, refined.p99, live.apart, refined.apart


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=120.0)
    args = parser.parse_args()
    jobs = [(m, s, args.seconds) for m in MODELS for s in range(1, args.seeds + 1)]
    with Pool(2) as pool:
        rows = pool.map(one, jobs)
    for model in MODELS:
        runs = [r for r in rows if r[0] == model]
        worse = [(r[1], round(r[2], 3), round(r[3], 3)) for r in runs
                 if r[3] > r[2] * 1.05 + 0.01]
        better = sum(r[3] < r[2] - 0.01 for r in runs)
        print(f"{model}: p99 median live {statistics.median(r[2] for r in runs):.3f} "
              f"refined {statistics.median(r[3] for r in runs):.3f} ms; apart median live "
              f"{statistics.median(r[4] for r in runs):.3f} refined "
              f"{statistics.median(r[5] for r in runs):.3f} ms; better in {better}, worse "
              f"in {len(worse)} (seed, live, refined): {worse}")


if __name__ == "__main__":
    main()
