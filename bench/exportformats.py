#!/usr/bin/env python3
"""What each export format costs: seconds per million rows, CSV against Parquet
against MATLAB .mat against a ROS 2 bag, and the .mat writer's memory.

    .venv/bin/python bench/exportformats.py [--rows 200000] [--rounds 3]

One recording of ``--rows`` 0xCB records (accel_angrate_mag, 17 columns) of one node
at 100 Hz, written through the recorder's writer; then, interleaved over ``--rounds``,
``export()`` of it in this process to each format (process start excluded; the best
round kept). ``reading`` is the same loop with a writer that keeps nothing: what every
format pays before its own writer (a ROS 2 bag: two messages a row, an Imu and a
MagneticField, each built and serialized by rosbags). The .mat writer holds a table
whole until scipy's ``savemat`` takes it: its peak is measured by tracemalloc in a
round of its own.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gateway.recording import export as exporting
from gateway.recording.reports import Reading
from gateway.recording.rosbag import export_bag
from gateway.recording.writer import RecordingWriter

T0 = 1_795_000_000.0
FORMATS = ("csv", "parquet", "mat", "ros2")


class Nothing(exporting.Writer):
    def __init__(self, path: Path, columns: list[Any]) -> None:
        path.touch()


def recording(path: Path, rows: int) -> Path:
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for i in range(rows):
            at = T0 + i / 100
            writer.message("gx2/76/accel_angrate_mag", {
                "accel": [0.001 * i, 0.002, -1.0], "ang_rate": [0.01, 0.02, 0.03],
                "mag": [0.2, 0.1, 0.4], "timer": i * 196_608, "node": 76,
                "record": "accel_angrate_mag", "command": 0xCB, "seq": i + 1,
                "host_time": at + 0.004, "lqi": 200, "rssi": -50,
                "device_time": i / 100, "time": at})
        writer.finish()
    return path


def once(source: Path, out: Path, form: str) -> float:
    started = time.perf_counter()
    if form == "ros2":
        export_bag([source], out, Reading())
    else:
        exporting.export([source], out, Reading(), form)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=200_000)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as work:
        source = recording(Path(work) / "run.mcap", args.rows)
        exporting.WRITERS["reading"] = Nothing
        best: dict[str, float] = {}
        for round_ in range(args.rounds):
            for form in ("reading", *FORMATS):
                took = once(source, Path(work) / f"{form}-{round_}", form)
                best[form] = min(best.get(form, took), took)
        sizes = {form: sum(p.stat().st_size for p in (Path(work) / f"{form}-0").iterdir())
                 for form in FORMATS}
        tracemalloc.start()
        once(source, Path(work) / "mat-memory", "mat")
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    million = 1e6 / args.rows
    print(f"{args.rows:,} rows of accel_angrate_mag, best of {args.rounds}")
    for form, took in best.items():
        size = f", {sizes[form] / args.rows:.0f} bytes a row" if form in sizes else ""
        print(f"{form:8} {took * million:6.1f} s per million rows "
              f"({(took - best['reading']) * million:5.1f} s its writer){size}")
    print(f"mat      peak memory {peak / args.rows:.0f} bytes a row (tracemalloc)")


if __name__ == "__main__":
    main()
