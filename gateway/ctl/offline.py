"""gx2ctl's commands that read recordings and need no gateway: ``export`` and ``plot``.

Exit status: 0 written; 1 ("partial") written, but something unreadable was skipped
(a file among others that is empty or not MCAP, a damaged chunk: one line each on
stderr); 2 no file given is a recording, no such node or record in them, or an
optional extra not installed (the line says how to install it); 130 interrupted, no
table left cut (the tables already whole are named). A file whose writer was killed
is read up to where it ends, with a line saying so: that alone is not partial.
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gateway.common.args import node_address
from gateway.common.protocol import Exit

from . import PROG
from .client import CtlError

if TYPE_CHECKING:
    from gateway.recording.reports import Reading


def add_commands(commands: Any) -> None:
    exporter = commands.add_parser(
        "export", help="write one table per node and record from MCAP recordings",
        description="Write DIR/<address>_<record>.csv (or .parquet, .mat): a row per record, "
        "columns time, host_time, device_time, seq, lqi, rssi, then the record's fields "
        "(vectors as _x/_y/_z, matrices as _11.._33), and DIR/marks.csv if there are "
        "marks. FILE may be a directory of recordings (read in name order, which is "
        "time order). Exit 1 if something unreadable was skipped (said on stderr).")
    exporter.add_argument("files", nargs="+", metavar="FILE.mcap")
    exporter.add_argument("--out", required=True, metavar="DIR", help="created if missing")
    exporter.add_argument("--format", dest="form", choices=("csv", "parquet", "mat"),
                          default="csv", help="csv (default), parquet (needs "
                          "gx2-gateway[parquet]), or mat: MATLAB (needs gx2-gateway[mat])")
    plotter = commands.add_parser(
        "plot", help="draw a node's recorded stream to a PNG",
        description="One panel per field group against time, units on the axes, the "
        "node's name, rate and losses in the title, gaps left as gaps, marks as "
        "labelled vertical lines. FILE may be a directory of recordings. Needs "
        "gx2-gateway[plot] (matplotlib).")
    plotter.add_argument("file", metavar="FILE.mcap")
    plotter.add_argument("node", type=node_address, metavar="NODE")
    plotter.add_argument("--record", metavar="R",
                         help="the record to draw (default: the one the node has most of)")
    plotter.add_argument("--out", metavar="FILE.png",
                         help="default: <address>_<record>.png here")


def _files(given: list[str]) -> list[Path]:
    from gateway.recording.files import RecordingError, usable_files
    try:
        return usable_files(given)
    except RecordingError as error:
        raise CtlError(str(error), Exit.USAGE) from None


def _report(reading: Reading) -> int:
    """A line for each file not read whole; the exit status for what was written."""
    from gateway.recording.files import PARTIAL
    for line in reading.lines():
        print(f"{PROG}: {line}", file=sys.stderr, flush=True)
    return PARTIAL if reading.partial else Exit.OK


def run_export(args: argparse.Namespace) -> int:
    from gateway.recording.export import MARKS, MissingExtra, RecordingError, export
    from gateway.recording.reports import Reading
    paths = _files(args.files)
    reading = Reading()
    written: list[Path] = []
    total = sum(path.stat().st_size for path in paths)
    try:
        with ProgressBar(total, sys.stderr.isatty()) as bar:
            tables, marks = export(paths, Path(args.out), reading, args.form, bar.advance,
                                   written)
    except MissingExtra as error:
        raise CtlError(str(error), Exit.USAGE) from None
    except RecordingError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    except OSError as error:
        raise CtlError(f"{args.out}: {error.strerror or error}", Exit.USAGE) from None
    except KeyboardInterrupt:
        whole = ", ".join(str(path) for path in written) if written else "no table"
        raise CtlError(f"interrupted: wrote {whole}; nothing else was left in {args.out}",
                       128 + signal.SIGINT) from None
    status = _report(reading)
    if not tables and not marks:
        raise CtlError(f"no node records in {', '.join(args.files)}", Exit.USAGE)
    for path, table in tables:
        apart = table.losses.apart()
        print(f"{path}  {table.rows:,} rows" + (f" ({apart})" if apart else ""))
    if marks:
        print(f"{Path(args.out) / f'{MARKS}.{args.form}'}  {marks:,} marks")
    return status


def run_plot(args: argparse.Namespace) -> int:
    from gateway.recording.export import MissingExtra
    from gateway.recording.files import RecordingError
    from gateway.recording.plot import draw, picture, records_of
    from gateway.recording.reports import Reading
    paths = _files([args.file])
    reading = Reading()
    try:
        found = records_of(paths, args.node, args.record, reading)
        image = picture(args.node, found.record, found.payloads, found.name, found.marks,
                        found.counts)
    except (ValueError, RecordingError) as error:
        _report(reading)
        raise CtlError(str(error), Exit.USAGE) from None
    out = Path(args.out or f"{args.node}_{found.record}.png")
    try:
        draw(image, out)
    except MissingExtra as error:
        raise CtlError(str(error), Exit.USAGE) from None
    except OSError as error:
        raise CtlError(f"{out}: {error.strerror or error}", Exit.USAGE) from None
    status = _report(reading)
    print(out)
    return status


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
