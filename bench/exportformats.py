#!/usr/bin/env python3
"""What each export format costs: seconds per million rows, CSV against Parquet
against MATLAB .mat against a ROS 2 bag, and the .mat writer's memory; with
``--before TREE``, this tree against another (a checkout of an earlier commit) side by
side.

    .venv/bin/python bench/exportformats.py [--rows 200000] [--rounds 3]
    git worktree add --detach /tmp/before44 COMMIT
    .venv/bin/python bench/exportformats.py --before /tmp/before44 --rows 1000000 --rounds 2

One recording of ``--rows`` 0xCB records (accel_angrate_mag, 17 columns) of one node (or
of ``--nodes`` in turn, a table each) at 100 Hz, written through the recorder's writer;
then, interleaved over ``--rounds``, ``export()`` of it in this process to each format
(process start excluded; the best round kept). ``reading`` is the same loop with a
writer that keeps nothing: what every format pays before its own writer (a ROS 2 bag:
two messages a row, an Imu and a MagneticField, each built and serialized by rosbags).
The .mat writer holds a table whole until scipy's ``savemat`` takes it: its peak is
measured by tracemalloc in a round of its own.

With ``--before``, each export runs in a process of its own, the two trees' in turn
(A B A B, the same file): its seconds (the export alone, not the imports), its CPU
seconds (the process's, the same span: on a machine shared with other work, the wall
clock's seconds move with the others' load and the CPU's much less) and its peak RSS
(the process's, imports included), best of the rounds; a format the other tree's
export does not know (ros2 before it was added) is shown as ``-``.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Any

TREE = (sys.argv[sys.argv.index("--tree") + 1] if "--tree" in sys.argv
        else str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, TREE)  # (another tree's gateway, for --before)

from gateway.recording import export as exporting  # noqa: E402
from gateway.recording.reports import Reading  # noqa: E402
from gateway.recording.writer import RecordingWriter  # noqa: E402

T0 = 1_795_000_000.0
FORMATS = ("csv", "parquet", "mat", "ros2")


class Nothing:
    """A table writer that keeps nothing (any tree's export takes it: add and close)."""

    def __init__(self, path: Path, columns: list[Any]) -> None:
        path.touch()

    def add(self, row: list[Any]) -> None:
        pass

    def close(self) -> None:
        pass


def recording(path: Path, rows: int, nodes: int = 1) -> Path:
    """``rows`` rows of accel_angrate_mag at 100 Hz, from ``nodes`` nodes (76 on) in
    turn, a table each."""
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for row in range(rows):
            i, node = divmod(row, nodes)
            at = T0 + i / 100 + node * 1e-4
            writer.message(f"gx2/{76 + node}/accel_angrate_mag", {
                "accel": [0.001 * i, 0.002, -1.0], "ang_rate": [0.01, 0.02, 0.03],
                "mag": [0.2, 0.1, 0.4], "timer": i * 196_608, "node": 76 + node,
                "record": "accel_angrate_mag", "command": 0xCB, "seq": i + 1,
                "host_time": at + 0.004, "lqi": 200, "rssi": -50,
                "device_time": i / 100, "time": at})
        writer.finish()
    return path


def register_reading() -> None:
    """``reading``: the export with a writer that keeps nothing (a batch at a time in
    a tree that exports so)."""
    exporting.WRITERS["reading"] = Nothing
    try:
        from gateway.recording import columnexport
    except ImportError:
        return  # (a tree before issue 44: row by row only)
    columnexport.BATCH_WRITERS["reading"] = Discard


class Discard:
    def __init__(self, path: Path, schema: Any) -> None:
        path.touch()

    def add(self, table: Any) -> None:
        pass

    def close(self) -> None:
        pass


def child(source: Path, out: Path, form: str) -> None:
    """One export in this process: its seconds and the process's peak RSS, as JSON
    (null: this tree's export has no such format)."""
    register_reading()
    if form != "reading" and form not in exporting.FORMATS:
        print(json.dumps(None))
        return
    cpu = time.process_time()
    took = once(source, out, form)
    cpu = time.process_time() - cpu
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"seconds": took, "cpu": cpu, "rss": peak}))


def side_by_side(args: argparse.Namespace) -> None:
    """This tree against ``--before``, each export in a process of its own, in turn."""
    trees = {"before": str(Path(args.before).resolve()), "after": TREE}
    best: dict[tuple[str, str], dict[str, float] | None] = {}
    with tempfile.TemporaryDirectory() as work:
        source = recording(Path(work) / "run.mcap", args.rows, args.nodes)
        for round_ in range(args.rounds):
            for form in ("reading", *FORMATS):
                for name, tree in trees.items():
                    # (a new directory a round: a bag is never written over)
                    out = Path(work) / f"{name}-{form}-{round_}"
                    ran = subprocess.run(
                        [sys.executable, __file__, "--tree", tree, "--child", form,
                         "--source", str(source), "--out", str(out)],
                        capture_output=True, text=True, check=True, cwd=work)
                    got = json.loads(ran.stdout.splitlines()[-1])
                    kept = best.setdefault((name, form), got)
                    if kept is not None and got is not None:
                        for key in ("seconds", "cpu", "rss"):
                            kept[key] = min(kept[key], got[key])
    print(f"{args.rows:,} rows of accel_angrate_mag ({args.nodes} node"
          f"{'s' if args.nodes > 1 else ''}), best of {args.rounds} interleaved rounds; "
          f"before: {trees['before']}")
    print(f"{'':8} {'before':>22} {'after':>22} {'factor':>7}  CPU s/M before/after "
          f"(factor)  peak RSS before/after")
    for form in ("reading", *FORMATS):
        was, now = best[("before", form)], best[("after", form)]
        if was is None or now is None:
            print(f"{form:8} {_seconds(was, args.rows):>22} {_seconds(now, args.rows):>22}")
            continue
        million = 1e6 / args.rows
        print(f"{form:8} {_seconds(was, args.rows)} {_seconds(now, args.rows)}"
              f" {was['seconds'] / now['seconds']:6.1f}x  {was['cpu'] * million:6.2f} /"
              f" {now['cpu'] * million:5.2f} ({was['cpu'] / now['cpu']:4.1f}x)"
              f"     {was['rss'] / 2**20:5.0f} / {now['rss'] / 2**20:5.0f} MiB")


def _seconds(took: dict[str, float] | None, rows: int) -> str:
    """An export's seconds a million rows and rows a second (``-``: not that tree's)."""
    if took is None:
        return "-"
    return f"{took['seconds'] * 1e6 / rows:6.2f} s/M ({rows / took['seconds']:8,.0f}/s)"


def once(source: Path, out: Path, form: str) -> float:
    started = time.perf_counter()
    if form == "ros2":
        from gateway.recording.rosbag import export_bag  # (not in a tree before it)
        export_bag([source], out, Reading())
    else:
        exporting.export([source], out, Reading(), form)
    return time.perf_counter() - started


def nodes(text: str) -> int:
    """--nodes: a count of at least 1."""
    count = int(text)
    if count < 1:
        raise argparse.ArgumentTypeError(f"at least 1, not {count}")
    return count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=200_000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--nodes", type=nodes, default=1,
                        help="the rows spread over this many nodes, a table each")
    parser.add_argument("--before", help="another tree (a checkout), side by side")
    parser.add_argument("--tree", help=argparse.SUPPRESS)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--source", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.source, args.out, args.child)
        return
    if args.before:
        side_by_side(args)
        return
    with tempfile.TemporaryDirectory() as work:
        source = recording(Path(work) / "run.mcap", args.rows, args.nodes)
        register_reading()
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
