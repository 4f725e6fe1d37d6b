"""gx2ctl's commands that read a window of recordings and need no gateway: ``export``
and ``plot`` (:mod:`gateway.recording.window`); ``recordings``, ``trials`` and
``dataset`` are :mod:`.recordings`'.

Exit status: 0 written; 1 ("partial") written, but something unreadable was skipped
(a file among others that is empty or not MCAP, a damaged chunk: one line each on
stderr); 2 no file given is a recording, no such node or record in them, a window
that cannot be taken (outside every file, a mark that never occurs, ``--to`` not after
``--from``), or an optional extra not installed (the line says how to install it);
130 interrupted, no table left cut (the tables already whole are named). A file whose
writer was killed is read up to where it ends, with a line saying so: that alone is not
partial.
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
from .progress import ProgressBar

FORMATS = ("csv", "parquet", "mat", "ros2")
"""export's formats (gateway.recording.export.FORMATS, which this module does not import
before a command runs: gx2ctl's start stays light)."""
TIMES = ("live", "refined")
"""--time's choices (gateway.recording.refined.TIMES)."""
FRAMES = ("enu", "ned")
"""--frame's choices (gateway.recording.rep103.FRAMES)."""

if TYPE_CHECKING:
    from gateway.recording.catalogue import Described
    from gateway.recording.reports import Reading
    from gateway.recording.window import Window

WINDOW_HELP = ("--from and --to: ISO 8601 with a zone (2026-11-25T10:00:00Z), seconds from "
               "the recordings' start, or a mark's text (the first such mark)")


def add_window_options(parser: argparse.ArgumentParser, nodes: bool = True) -> None:
    """The options of a window of recordings (docs/recording.md)."""
    group = parser.add_argument_group("window", WINDOW_HELP)
    group.add_argument("--from", dest="start", metavar="WHEN",
                       help="read from this time (held)")
    group.add_argument("--to", dest="stop", metavar="WHEN",
                       help="read up to this time (not held; a mark named is held)")
    group.add_argument("--between-marks", dest="between", nargs=2, metavar=("START", "STOP"),
                       help="each trial from a mark START to the next mark STOP")
    group.add_argument("--trial", type=int, metavar="N",
                       help="only the Nth trial of --between-marks (1 is the first)")
    if nodes:
        group.add_argument("--node", dest="nodes", type=node_address, action="append",
                           default=[], metavar="N", help="only this node (repeatable)")
        group.add_argument("--record", dest="records", action="append", default=[],
                           metavar="NAME", help="only this record (repeatable)")


def add_commands(commands: Any) -> None:
    exporter = commands.add_parser(
        "export", help="write one table per node and record from MCAP recordings, or a "
        "ROS 2 bag",
        description="Write DIR/<address>_<record>.csv (or .parquet, .mat): a row per record, "
        "columns time, host_time, device_time, seq, lqi, rssi, then the record's fields "
        "(vectors as _x/_y/_z, matrices as _11.._33; with --time refined, time_placed "
        "and time_bound_ms after time), and DIR/marks.csv (its header "
        "alone if there are no marks). With --format ros2, DIR is a rosbag2 (metadata.yaml "
        "and one .mcap): sensor_msgs/msg/Imu on /gx2/<node name>/imu, "
        "sensor_msgs/msg/MagneticField on /gx2/<node name>/mag, tf2_msgs/msg/TFMessage "
        "on /tf, in REP-103's frames unless --frame ned. FILE may be a directory of "
        "recordings (read in name order, which is time order). Exit 1 if something "
        "unreadable was skipped (said on stderr).")
    exporter.add_argument("files", nargs="+", metavar="FILE.mcap")
    exporter.add_argument("--out", required=True, metavar="DIR",
                          help="created if missing (ros2: must not exist)")
    exporter.add_argument("--format", dest="form", choices=FORMATS,
                          default="csv", help="csv (default), parquet (needs "
                          "gx2-gateway[parquet]), mat: MATLAB (needs gx2-gateway[mat]), or "
                          "ros2: a rosbag2 directory (needs gx2-gateway[ros2])")
    exporter.add_argument("--frame", choices=FRAMES, default=None,
                          help="ros2: enu (default): REP-103's ENU world and FLU body, "
                          "converted from the device's; ned: the device's own NED world "
                          "and sensor frame")
    exporter.add_argument("--time", choices=TIMES, default="live",
                          help="live (default): time as the gateway gave it while "
                          "recording; refined: placed after the fact from the whole "
                          "recording (the node's floor seen on both sides of a stretch "
                          "whose packets all waited on the line), with columns time_placed "
                          "and time_bound_ms; needs the gateway's own recording (its serial "
                          "reads)")
    exporter.add_argument("--force", action="store_true",
                          help="remove the tables of an earlier export in DIR first, "
                          "every one (without it, export refuses to write over them, as "
                          "record refuses an existing file); ros2: replace an earlier bag "
                          "at DIR")
    add_window_options(exporter)
    plotter = commands.add_parser(
        "plot", help="draw a node's recorded stream to a PNG or a PDF",
        description="One panel per field group against time, units on the axes, the "
        "node's name, rate and losses in the title, gaps left as gaps, marks as "
        "labelled vertical lines. FILE may be a directory of recordings. Needs "
        "gx2-gateway[plot] (matplotlib).")
    plotter.add_argument("file", metavar="FILE.mcap")
    plotter.add_argument("node", type=node_address, metavar="NODE", nargs="?",
                         help="the node (or --node N)")
    plotter.add_argument("--node", dest="node_option", type=node_address, metavar="N",
                         help="the node, as export takes it (or NODE)")
    plotter.add_argument("--record", metavar="R",
                         help="the record to draw (default: the one the node has most of)")
    plotter.add_argument("--out", metavar="FILE.png|FILE.pdf",
                         help="a PNG or a PDF, by its ending (default: "
                         "<address>_<record>.png here)")
    plotter.add_argument("--time", choices=TIMES, default="live",
                         help="the time axis: live (default), time as recorded; refined, "
                         "placed after the fact, as export --time refined places it")
    add_window_options(plotter, nodes=False)


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


def _windows(args: argparse.Namespace, paths: list[Path]
             ) -> tuple[list[Described], list[Window]]:
    """The catalogue of the recordings and the windows asked of them (exit 2 for one
    that cannot be taken)."""
    from gateway.recording.catalogue import catalogue
    from gateway.recording.window import Asked, WindowError, unclosed, windows
    asked = Asked(args.start, args.stop, tuple(args.between) if args.between else None,
                  args.trial, tuple(getattr(args, "nodes", ())),
                  tuple(getattr(args, "records", ())))
    files = catalogue(paths, whole=asked.marked)  # (marks read only when they name it)
    try:
        found = windows(asked, files)
    except WindowError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    if asked.between is not None and (line := unclosed(asked.between, files)):
        print(f"{PROG}: {line}", file=sys.stderr, flush=True)
    return files, found


def _check_held(args: argparse.Namespace, files: list[Described]) -> None:
    """Exit 2 if the files hold none of the nodes and records asked (those the
    catalogue had not counted, a file without summary, counted now)."""
    from gateway.recording.catalogue import describe
    from gateway.recording.window import Asked, WindowError, check_held
    counted = [d if d.counted else describe(d.path) for d in files]
    try:
        check_held(Asked(nodes=tuple(args.nodes), records=tuple(args.records)), counted,
                   known=True)
    except WindowError as error:
        raise CtlError(str(error), Exit.USAGE) from None


def _replace_earlier(outs: list[Path], form: str, force: bool) -> None:
    """An earlier export's tables of this format where this one writes (only the names
    export gives its tables: :func:`~gateway.recording.export.earlier_tables`): exit 2,
    nothing written (issue 43: export replaced them without a word, where record
    refuses an existing file); with ``force`` each is removed before anything is
    written, so the directory never mixes two exports' tables (an earlier export of a
    node not exported now was left beside the new ones)."""
    from gateway.recording.export import earlier_tables
    found = [path for out in outs for path in earlier_tables(out, form)]
    if found and not force:
        more = f" (and {len(found) - 1} more tables)" if len(found) > 1 else ""
        raise CtlError(f"{found[0]} exists{more}: export to a new --out, or give --force "
                       "to replace an earlier export's tables", Exit.USAGE)
    for path in found:
        try:
            path.unlink(missing_ok=True)
        except OSError as error:
            raise CtlError(f"{path}: cannot remove it: {error.strerror or error}",
                           Exit.USAGE) from None


def run_export(args: argparse.Namespace) -> int:
    from gateway.recording.reports import Reading
    from gateway.recording.window import Reader, touched
    if args.frame is not None and args.form != "ros2":
        raise CtlError(f"--frame is for --format ros2 (--format {args.form} keeps the "
                       "device's frames, as recorded)", Exit.USAGE)
    if args.time != "live" and args.form == "ros2":
        raise CtlError("--time refined is for the tables (csv, parquet, mat); a ROS 2 bag "
                       "keeps the time as recorded", Exit.USAGE)
    paths = _files(args.files)
    files, chosen = _windows(args, paths)
    if args.form == "ros2":
        return _export_bags(args, paths, files, chosen)
    _refined(args, files)  # (refused before --force removes an earlier export's tables)
    _replace_earlier([Path(args.out) / window.label for window in chosen], args.form,
                     args.force)
    reading = Reading()
    reader = Reader(files, reading)
    found = tables = 0
    for window in chosen:
        out = Path(args.out) / window.label if window.label else Path(args.out)
        total = sum(d.bytes for d in touched(files, window))
        # (one window of nodes asked that holds none of them: no marks.csv alone either)
        alone = len(chosen) == 1 and bool(args.nodes or args.records)
        written, marks = _export_window(args, paths, out, reading, reader.blocks(window),
                                        total, alone, _refined(args, files, window))
        if window.label and written + marks:
            _trial_json(args, files, window, out)
        found += written + marks
        tables += written
    status = _report(reading)
    if not tables and (args.nodes or args.records):
        _check_held(args, files)
    if not found:
        raise CtlError(f"no node records in {', '.join(args.files)}"
                       + (" in that window" if args.start or args.stop or args.between
                          else ""), Exit.USAGE)
    if reader.duplicates:
        print(f"dropped {reader.duplicates:,} duplicate messages, "
              f"{reader.duplicate_records:,} of them records (rows), the rest statuses, "
              "marks and serial reads (met twice: a file given twice, or files that "
              "overlap)")
    return status


def _export_bags(args: argparse.Namespace, paths: list[Path], files: list[Described],
                 chosen: list[Window]) -> int:
    """``--format ros2``: a bag a window (a trial's in its folder under ``--out``), a
    line for each of its topics."""
    from gateway.recording.export import EXTRAS, MissingExtra
    from gateway.recording.files import RecordingError
    from gateway.recording.reports import Reading
    from gateway.recording.rosbag import BagError, NoMessages, check_target, export_bag
    from gateway.recording.rosbag import configured_names as named
    from gateway.recording.window import Reader, touched
    outs = [Path(args.out) / window.label if window.label else Path(args.out)
            for window in chosen]
    try:
        EXTRAS[args.form]()
        for out in outs:  # (all refused before any is written)
            check_target(out, args.force)
    except (MissingExtra, BagError) as error:
        raise CtlError(str(error), Exit.USAGE) from None
    names = named(paths)
    reading = Reading()
    reader = Reader(files, reading)
    bags = 0
    for window, out in zip(chosen, outs, strict=True):
        total = sum(d.bytes for d in touched(files, window))
        try:
            with ProgressBar(total, sys.stderr.isatty()) as bar:
                bag = export_bag(paths, out, reading, args.frame or "enu", bar.advance,
                                 reader.entries(window), names, args.force)
        except NoMessages as error:
            if len(chosen) == 1:
                _report(reading)
                if args.nodes or args.records:
                    _check_held(args, files)  # (a node or record not there: that said)
                raise CtlError(str(error), Exit.USAGE) from None
            print(f"{PROG}: {out}: {error}", file=sys.stderr, flush=True)
            continue
        except (BagError, RecordingError) as error:
            raise CtlError(str(error), Exit.USAGE) from None
        except OSError as error:
            raise CtlError(f"{out}: {error.strerror or error}", Exit.USAGE) from None
        except KeyboardInterrupt:
            raise CtlError(f"interrupted: nothing was left at {out}"
                           + (f" ({bags} whole bags before it)" if bags else ""),
                           128 + signal.SIGINT) from None
        bags += 1
        for topic, (kind, count) in bag.topics.items():
            print(f"{out}  {topic}  {count:,} {kind}")
    status = _report(reading)
    if not bags:
        raise CtlError(f"no bag written from {', '.join(args.files)}: no window gives a "
                       "ROS 2 message", Exit.USAGE)
    return status


def _trial_json(args: argparse.Namespace, files: list[Described], window: Window,
                out: Path) -> None:
    """``trial.json`` beside a trial's tables: its number, marks, times and the fields
    of its start mark (as ``gx2ctl trials --json`` gives it, without the counts)."""
    import json
    import os

    from gateway.recording.tables import TEMPORARY
    from gateway.recording.trials import listed
    from gateway.recording.window import _marks
    for trial in listed(tuple(args.between), _marks(files)):
        if trial.span == window.span:
            said = {key: value for key, value in trial.json().items()
                    if key not in ("nodes", "files")}
            hidden = out / TEMPORARY.format(name="trial.json")
            hidden.write_text(json.dumps(said, indent=1) + "\n", encoding="utf-8")
            os.replace(hidden, out / "trial.json")
            print(f"{out / 'trial.json'}  trial {trial.number}", flush=True)
            return


def _refined(args: argparse.Namespace, files: list[Described],
             window: Window | None = None) -> Any:
    """``--time refined``: the window's times placed after the fact (exit 2 for
    recordings that cannot be refined; without a window, only that checked); None for
    ``--time live``."""
    if args.time == "live":
        return None
    from gateway.recording.files import RecordingError
    from gateway.recording.refined import check_refinable, for_window
    try:
        check_refinable(files)
        return None if window is None else for_window(files, window)
    except RecordingError as error:
        raise CtlError(str(error), Exit.USAGE) from None


def _export_window(args: argparse.Namespace, paths: list[Path], out: Path,
                   reading: Reading, blocks: Any, total: int, tables_only: bool = False,
                   refined: Any = None) -> tuple[int, int]:
    """One window's tables written to ``out``, a line each; how many, and how many
    marks."""
    from gateway.recording.export import MARKS, MissingExtra, NoTables, RecordingError, export
    written: list[Path] = []
    try:
        with ProgressBar(total, sys.stderr.isatty()) as bar:
            tables, marks = export(paths, out, reading, args.form, bar.advance,
                                   written, blocks, tables_only, refined)
    except NoTables:
        return 0, 0
    except MissingExtra as error:
        raise CtlError(str(error), Exit.USAGE) from None
    except RecordingError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    except OSError as error:
        raise CtlError(f"{out}: {error.strerror or error}", Exit.USAGE) from None
    except KeyboardInterrupt:
        whole = ", ".join(str(path) for path in written) if written else "no table"
        raise CtlError(f"interrupted: wrote {whole}; nothing else was left in {out}",
                       128 + signal.SIGINT) from None
    for path, table in tables:
        apart = table.losses.apart()
        print(f"{path}  {table.rows:,} rows" + (f" ({apart})" if apart else ""))
    if marks or tables:
        print(f"{out / f'{MARKS}.{args.form}'}  {marks:,} marks")
    return len(tables), marks


def run_plot(args: argparse.Namespace) -> int:
    from gateway.recording.export import MissingExtra
    from gateway.recording.figure import draw, unwritable
    from gateway.recording.files import RecordingError
    from gateway.recording.plot import picture, records_of
    from gateway.recording.reports import Reading
    from gateway.recording.window import Reader
    if args.node is None or args.node_option not in (None, args.node):
        if args.node is not None or args.node_option is None:
            raise CtlError("plot: give one node, as NODE or --node N", Exit.USAGE)
        args.node = args.node_option
    if args.out and unwritable(Path(args.out)):
        raise CtlError(f"--out {unwritable(Path(args.out))}", Exit.USAGE)
    paths = _files([args.file])
    files, chosen = _windows(args, paths)
    if len(chosen) > 1:
        raise CtlError(f"{len(chosen)} trials between those marks: pick one with --trial N",
                       Exit.USAGE)
    refined = _refined(args, files, chosen[0])
    reading = Reading()
    try:
        found = records_of(paths, args.node, args.record, reading,
                           Reader(files, reading).entries(chosen[0]), refined)
        image = picture(args.node, found.record, found.payloads, found.name, found.marks,
                        found.counts, window=chosen[0].span is not None,
                        shows=chosen[0].title)
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

