#!/usr/bin/env python3
"""``gx2ctl dataset`` on a day of one saturated station, and DuckDB querying what it
made (issue 44): the time of a first run over the hourly files, of a run after one new
file (what the timer does each time the recorder rotates), and of DuckDB's queries for
one trial of every node and for the hourly RMS per node over the whole dataset.

    .venv/bin/python bench/dataset.py --dir /tmp/gx2-day [--hours 24] [--runs 3]

The recordings are bench/window.py's (3 nodes of 0xC2 at 96 Hz, a mark every ten
minutes, hourly files), made once into ``--dir`` and kept: the same files serve both
benchmarks. The new file, the hour after them, is made in ``--dir`` before the second
run and removed after it. The dataset is made afresh in a temporary folder (``--out``
names one to keep). Timed: the installed console script's wall time, from just before
it starts until it exits; each query's wall time in this process (DuckDB imported and
connected before), the median of ``--runs``. The queries are docs/recording.md's
("Analysing a study": trial 1 of every node, the hourly RMS per node), as written.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from window import START, make, make_hour, summary

from gateway.recording.files import file_name

REPO = Path(__file__).resolve().parents[1]
QUERIES = {"trial 1 of every node": 0, "hourly RMS per node": 1}
"""The docs' queries timed, by their place among the page's SQL blocks."""


def converted(gx2ctl: str, folder: Path, out: Path) -> tuple[float, int, str]:
    """One run: its wall time, the rows it converted, its last line."""
    began = time.perf_counter()
    ran = subprocess.run([gx2ctl, "dataset", str(folder), str(out)], capture_output=True,
                         text=True, check=False)
    wall = time.perf_counter() - began
    if ran.returncode != 0:
        sys.exit(f"gx2ctl dataset failed ({ran.returncode}): {ran.stderr.strip()}")
    lines = ran.stdout.splitlines()
    rows = sum(int(line.split()[-2].replace(",", "")) for line in lines
               if line.endswith(" rows"))
    return wall, rows, lines[-1]


def queries(out: Path) -> dict[str, str]:
    """The docs' SQL, on the dataset in ``out``."""
    page = (REPO / "docs" / "recording.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```sql\n(.*?)```", page[page.index("## Analysing a study"):],
                        re.S)
    return {what: blocks[at].replace("'dataset/", f"'{out}/") for what, at in
            QUERIES.items()}


def queried(sql: str, runs: int) -> tuple[list[float], list[tuple]]:
    import duckdb
    walls, rows = [], []
    for _ in range(runs):
        connection = duckdb.connect()
        began = time.perf_counter()
        rows = connection.sql(sql).fetchall()
        walls.append(time.perf_counter() - began)
        connection.close()
    return walls, rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, required=True,
                        help="where the recordings are made and kept (bench/window.py's)")
    parser.add_argument("--hours", type=int, default=24)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--out", type=Path, help="the dataset, kept (default: a temporary "
                        "folder, removed)")
    args = parser.parse_args()
    try:
        import duckdb  # noqa: F401  (before any run: a missing extra says so at once)
    except ImportError:
        sys.exit("needs DuckDB: pip install 'gx2-gateway[query]'")
    make(args.dir, args.hours)
    gx2ctl = str(Path(sys.executable).parent / "gx2ctl")
    out = args.out or Path(tempfile.mkdtemp(prefix="gx2-dataset-"))
    if args.out:
        shutil.rmtree(out, ignore_errors=True)
    new = args.dir / file_name(START + args.hours * 3600)
    figures: list[tuple[str, str]] = []
    try:
        wall, rows, said = converted(gx2ctl, args.dir, out)
        figures.append((f"gx2ctl dataset, first run: {args.hours} hourly files, "
                        f"{rows:,} rows", f"{wall:.1f} s ({wall / 60:.1f} min, "
                        f"{rows / wall:,.0f} rows/s)"))
        make_hour(new, START + args.hours * 3600)
        wall, rows, said = converted(gx2ctl, args.dir, out)
        figures.append((f"gx2ctl dataset, one new file ({said.split(';')[0]}), "
                        f"{rows:,} rows", f"{wall:.1f} s"))
        parts = list(out.glob("record=*/**/*.parquet"))
        size = sum(p.stat().st_size for p in parts)
        figures.append(("the dataset", f"{len(parts)} parts, {size / 1e9:.2f} GB"))
        for what, sql in queries(out).items():
            walls, result = queried(sql, args.runs)
            figures.append((f"DuckDB, {what} ({len(result)} rows)", summary(walls)))
    finally:
        new.unlink(missing_ok=True)
        if not args.out:
            shutil.rmtree(out, ignore_errors=True)
    width = max(len(what) for what, _ in figures)
    for what, figure in figures:
        print(f"{what:<{width}}  {figure}")
    print(f"command: .venv/bin/python bench/dataset.py --dir {args.dir} --hours "
          f"{args.hours} --runs {args.runs}")


if __name__ == "__main__":
    main()
