"""gx2ctl's commands that read recordings and need no gateway: ``export`` and ``plot``.

Exit status: 0 written; 2 a file that is missing or not a recording, no such node or
record in it, or an optional extra not installed (the line says how to install it).
A file whose writer was killed is read up to where it breaks, with a warning.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from gateway.common.args import node_address
from gateway.common.protocol import Exit

from . import PROG
from .client import CtlError


def add_commands(commands: Any) -> None:
    exporter = commands.add_parser(
        "export", help="write one table per node and record from MCAP recordings",
        description="Write DIR/<address>_<record>.csv (or .parquet): a row per record, "
        "columns time, host_time, device_time, seq, lqi, rssi, then the record's fields "
        "(vectors as _x/_y/_z, matrices as _11.._33). FILE may be a directory of "
        "recordings (read in name order, which is time order).")
    exporter.add_argument("files", nargs="+", metavar="FILE.mcap")
    exporter.add_argument("--out", required=True, metavar="DIR", help="created if missing")
    exporter.add_argument("--format", dest="form", choices=("csv", "parquet"), default="csv",
                          help="csv (default), or parquet (needs gx2-gateway[parquet])")
    plotter = commands.add_parser(
        "plot", help="draw a node's recorded stream to a PNG",
        description="One panel per field group against time, units on the axes, the "
        "node's name, rate and losses in the title, gaps left as gaps. Needs "
        "gx2-gateway[plot] (matplotlib).")
    plotter.add_argument("file", metavar="FILE.mcap")
    plotter.add_argument("node", type=node_address, metavar="NODE")
    plotter.add_argument("--record", metavar="R",
                         help="the record to draw (default: the one the node has most of)")
    plotter.add_argument("--out", metavar="FILE.png",
                         help="default: <address>_<record>.png here")


def _files(given: list[str]) -> list[Path]:
    from gateway.recording.files import RecordingError, check_readable, recording_files
    try:
        paths = recording_files(given)
        for path in paths:
            check_readable(path)
    except RecordingError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    return paths


def _warn_incomplete(incomplete: list[Path]) -> None:
    for path in dict.fromkeys(incomplete):
        print(f"{PROG}: {path} ends early (its writer was stopped without warning); "
              "read up to there", file=sys.stderr, flush=True)


def run_export(args: argparse.Namespace) -> int:
    from gateway.recording.export import MissingExtra, RecordingError, export
    paths = _files(args.files)
    incomplete: list[Path] = []
    total = sum(path.stat().st_size for path in paths)
    try:
        with ProgressBar(total, sys.stderr.isatty()) as bar:
            written = export(paths, Path(args.out), args.form, bar.advance, incomplete)
    except MissingExtra as error:
        raise CtlError(str(error), Exit.USAGE) from None
    except RecordingError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    except OSError as error:
        raise CtlError(f"{args.out}: {error.strerror or error}", Exit.USAGE) from None
    _warn_incomplete(incomplete)
    if not written:
        raise CtlError(f"no node records in {', '.join(args.files)}", Exit.USAGE)
    for path, table in written:
        print(f"{path}  {table.rows:,} rows")
    return Exit.OK


def run_plot(args: argparse.Namespace) -> int:
    from gateway.recording.export import MissingExtra
    from gateway.recording.plot import draw, picture, records_of
    paths = _files([args.file])
    try:
        record, payloads, name = records_of(paths, args.node, args.record)
        image = picture(args.node, record, payloads, name)
    except ValueError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    out = Path(args.out or f"{args.node}_{record}.png")
    try:
        draw(image, out)
    except MissingExtra as error:
        raise CtlError(str(error), Exit.USAGE) from None
    except OSError as error:
        raise CtlError(f"{out}: {error.strerror or error}", Exit.USAGE) from None
    print(out)
    return Exit.OK


class ProgressBar:
    """rich's progress bar over the bytes of the recordings, on a terminal only (an
    entry advances it by its message's size, a fair share of the file's)."""

    def __init__(self, total: int, terminal: bool) -> None:
        self._progress: Any = None
        self._task: Any = None
        self._total = max(total, 1)
        if terminal:
            from rich.progress import Progress
            self._progress = Progress(transient=True)
            self._task = self._progress.add_task("exporting", total=self._total)

    def advance(self, entry: Any) -> None:
        if self._progress is not None:
            self._progress.advance(self._task, len(entry.data) // 2)

    def __enter__(self) -> ProgressBar:
        if self._progress is not None:
            self._progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.stop()
