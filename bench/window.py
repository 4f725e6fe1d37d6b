#!/usr/bin/env python3
"""One minute out of a day of recordings: how long ``gx2ctl export`` takes, and reading
it through the subscriber library (``gateway.client.Recording``, and its
``to_pandas``) (issue 34).

    .venv/bin/python bench/window.py --dir /tmp/gx2-day [--hours 24] [--runs 5]
        [--library-minutes 1]

The recordings: one saturated base station (3 nodes of 0xC2 at 96 Hz, 288 records/s),
its status once a second and a mark every ten minutes, in hourly files as the recorder
makes them (named as it names them, a chunk closed each second as its flush closes
them), written directly with the project's recording writer in simulated time (no
gateway runs for a day). Each node's records as the gateway numbers and times them:
its own ``seq``, its timer 204,800 ticks a sample (wrapping at 2**32) and
``device_time`` that timer unwrapped, in seconds (export counts losses from them).
They are made once into ``--dir`` and kept there: a later run with the same ``--dir``
and ``--hours`` times them again without making them.

Timed: the installed console script, ``gx2ctl export DIR --from X --to X+60s --out
OUT`` with X half an hour into the middle file (a minute inside one file), and again
with X a few seconds before an hour (a minute across two files); the wall time of each
run, from just before the process starts until it exits, as the median and the range
of ``--runs`` runs. Then the minute inside one file (``--library-minutes`` from its
start) read in this process through
``Recording`` (iterated), made a DataFrame (``to_pandas``, pandas imported before
timing), if pandas is installed, and an Arrow table (``to_arrow``), if pyarrow is. The
serial reads a gateway records too are left out: they would double the files' size,
not the minute's chunks (a window read seeks past the rest).
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

from aspp.timing import TICKS_PER_SECOND, TIMER_MODULUS
from gateway.recording.files import MARK, file_name
from gateway.recording.writer import RecordingWriter

START = 1_795_000_000.0
NODES = (11, 12, 13)
RATE = 96
COMPLETE = ".complete-{hours}h-2"
"""Left in ``--dir`` once its files are whole: the next run uses them. (-2: files made
since each node has its own ``seq`` and a timer that agrees with ``device_time``;
before, a ``seq`` shared by the nodes and a timer 6,144 ticks a sample against
204,800 made every row a restart to export's loss counting.)"""
TICKS = TICKS_PER_SECOND // RATE
"""A node's timer ticks between two samples."""


def make_hour(path: Path, first: float) -> None:
    """An hour of the saturated station from UNIX time ``first``, a chunk a second."""
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        sample = round((first - START) * RATE)  # (each node's samples since START)
        for second in range(3600):
            now = first + second
            writer.message("gx2/gateway/status", {"gateway": {"time": now}, "nodes": []})
            if second % 600 == 0:
                text = "start" if second % 1200 == 0 else "stop"
                writer.message(MARK, {"time": now, "host_time": now, "nodes": [],
                                      "text": text})
            for i in range(RATE):
                at = now + i / RATE
                sample += 1
                for node in NODES:
                    ticks = sample * TICKS + node * 1_000_003  # (powered up apart)
                    data = (f'{{"node":{node},"record":"accel_angrate","command":194,'
                            f'"seq":{sample},"host_time":{at + 0.004!r},"time":{at!r},'
                            f'"device_time":{ticks / TICKS_PER_SECOND!r},'
                            f'"timer":{ticks % TIMER_MODULUS},'
                            f'"lqi":200,"rssi":-50,"accel":[0.01,0.02,-1.0],'
                            f'"ang_rate":[0.001,0.002,{i / 1000!r}]}}').encode()
                    writer.message(f"gx2/{node}/accel_angrate",
                                   {"host_time": at + 0.004, "time": at}, data)
            writer.flush()
        writer.finish()


def make(folder: Path, hours: int) -> None:
    done = folder / COMPLETE.format(hours=hours)
    if done.exists():
        return
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("*.mcap"):
        old.unlink()
    began = time.monotonic()
    for hour in range(hours):
        first = START + hour * 3600
        make_hour(folder / file_name(first), first)
        print(f"made hour {hour + 1}/{hours} ({time.monotonic() - began:.0f} s)",
              file=sys.stderr, flush=True)
    done.touch()


def iso(seconds: float) -> str:
    return datetime.fromtimestamp(seconds, UTC).isoformat()


def timed(gx2ctl: str, folder: Path, start: float, runs: int) -> list[float]:
    walls = []
    for _ in range(runs):
        out = Path(tempfile.mkdtemp(prefix="gx2-window-"))
        try:
            began = time.perf_counter()
            ran = subprocess.run([gx2ctl, "export", str(folder), "--from", iso(start),
                                  "--to", iso(start + 60), "--out", str(out)],
                                 capture_output=True, text=True, check=False)
            walls.append(time.perf_counter() - began)
            if ran.returncode != 0:
                sys.exit(f"gx2ctl export failed ({ran.returncode}): {ran.stderr.strip()}")
            rows = sum(int(line.split()[1].replace(",", "")) for line in
                       ran.stdout.splitlines() if line.split()[2:3] == ["rows"])
            if rows != 60 * RATE * len(NODES):
                sys.exit(f"expected {60 * RATE * len(NODES)} rows, exported {rows}")
        finally:
            shutil.rmtree(out, ignore_errors=True)
    return walls


def library(folder: Path, start: float, seconds: float, runs: int
            ) -> dict[str, list[float]]:
    """Seconds to iterate the window through Recording, to make its DataFrame and its
    Arrow table (each made if its library is installed)."""
    from gateway.client import Recording
    made = {}
    for name, method in (("pandas", "to_pandas"), ("pyarrow", "to_arrow")):
        try:  # (imported before timing: its import is not the minute's)
            __import__(name)
            made[method] = []
        except ImportError:
            pass
    timed: dict[str, list[float]] = {"iterated": [], **made}
    wanted = round(seconds * RATE * len(NODES))
    stop = iso(start + seconds)
    for _ in range(runs):
        began = time.perf_counter()
        count = sum(1 for _ in Recording(folder, start=iso(start), stop=stop))
        timed["iterated"].append(time.perf_counter() - began)
        if count != wanted:
            sys.exit(f"expected {wanted} messages, Recording gave {count}")
        for method in made:
            began = time.perf_counter()
            rows = len(getattr(Recording(folder, start=iso(start), stop=stop), method)())
            timed[method].append(time.perf_counter() - began)
            if rows != wanted:
                sys.exit(f"expected {wanted} rows, {method} gave {rows}")
    return timed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, required=True,
                        help="where the recordings are made and kept")
    parser.add_argument("--hours", type=int, default=24)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--library-minutes", type=float, default=1,
                        help="the window read through the library (inside one file)")
    args = parser.parse_args()
    make(args.dir, args.hours)
    gx2ctl = str(Path(sys.executable).parent / "gx2ctl")
    size = sum(p.stat().st_size for p in args.dir.glob("*.mcap"))
    print(f"{args.hours} h of one saturated station: {size / 1e9:.2f} GB in "
          f"{len(list(args.dir.glob('*.mcap')))} files")
    middle = START + (args.hours // 2) * 3600
    for what, start in [("inside one file", middle + 1800),
                        ("across two files", middle - 30)]:
        walls = timed(gx2ctl, args.dir, start, args.runs)
        print(f"export of one minute {what}: {summary(walls)}")
    minutes = args.library_minutes
    rows = round(60 * minutes * RATE) * len(NODES)
    for how, walls in library(args.dir, middle + 1800, 60 * minutes, args.runs).items():
        print(f"Recording of {minutes:g} min inside one file ({rows:,} rows), {how}: "
              f"{summary(walls)}")


def summary(walls: list[float]) -> str:
    return (f"median {statistics.median(walls):.2f} s (min {min(walls):.2f}, "
            f"max {max(walls):.2f}, {len(walls)} runs)")


if __name__ == "__main__":
    main()
