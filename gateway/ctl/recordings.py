"""``gx2ctl recordings``: the catalogue of recordings (:mod:`gateway.recording.catalogue`)
as a table for a person, or one JSON line for a script; ``gx2ctl trials``, the trials
their marks define (:mod:`gateway.recording.trials`), likewise; ``gx2ctl dataset``,
recordings converted into a Parquet dataset (:mod:`gateway.recording.dataset`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gateway.common.jsontext import json_line
from gateway.common.protocol import Exit
from gateway.common.timetext import DAY, TIME, at

from .client import CtlError
from .offline import TIMES

if TYPE_CHECKING:
    from gateway.recording.catalogue import Described


def add_commands(commands: Any) -> None:
    """The parsers of ``recordings``, ``trials`` and ``dataset`` (after export's and
    plot's: :func:`.offline.add_commands`)."""
    catalogue = commands.add_parser(
        "recordings", help="list what recordings hold, from their summaries",
        description="Per file, sorted by time: its span, size, stations, nodes and records "
        "with message counts, and marks; overlapping and repeated files said. A finished "
        "file is described from its summary (its messages unread); one without (its "
        "writer killed, cut short, damaged) is read through and says so. Default: the "
        "record directory of the gateway's --config, else the gateway's default record "
        "directory. Exit 1 if a file is damaged, 2 if none is a recording.")
    catalogue.add_argument("paths", nargs="*", metavar="DIR | FILE.mcap")
    # (SUPPRESS: given before the command, as in ``gx2ctl --json status``, it holds too)
    catalogue.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                           help='one line: {"files": [{"path", "start", "end", ...}]}')
    lister = commands.add_parser(
        "trials", help="list the trials the marks define, with their fields and rows",
        description="Each trial from a mark START to the next mark STOP (--between-marks, "
        "default start stop), numbered as export's --trial numbers them, the one not yet "
        "stopped last (its stop null): its start and stop, duration, its start mark's "
        "fields (gx2ctl mark --field), the rows of each node and record in it, and the "
        "files it spans. Default: as recordings. Exit 1 if something unreadable was "
        "skipped, 2 if no file is a recording.")
    lister.add_argument("paths", nargs="*", metavar="DIR | FILE.mcap")
    lister.add_argument("--between-marks", dest="between", nargs=2, default=["start", "stop"],
                        metavar=("START", "STOP"), help="the marks that start and stop a "
                        "trial (default: start stop)")
    lister.add_argument("--from", dest="start", metavar="WHEN",
                        help="only the trials that start at or after this time (as --from)")
    lister.add_argument("--to", dest="stop", metavar="WHEN",
                        help="only the trials that start before this time (as export's --to)")
    lister.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                        help='one line: {"trials": [{"trial", "start", "stop", ...}]}')
    converter = commands.add_parser(
        "dataset", help="convert finished recordings into a Parquet dataset (incremental)",
        description="Convert the finished recordings of RECORDINGS (a directory, or a "
        "file) not yet converted, or changed since, into OUT, partitioned Hive-style by "
        "record, node and day (OUT/record=R/node=N/date=D/ a part per recording), the "
        "columns and types of export --format parquet; and OUT/trials.parquet. A file "
        "being written is left for a later run. Needs gx2-gateway[parquet]. Exit 1 if "
        "something unreadable was skipped (it is tried again next run), 2 if no file is a "
        "recording or OUT holds another directory's recordings (or the other --time), "
        "75 if another run is converting into OUT (it holds OUT/.lock; this one did "
        "nothing).")
    converter.add_argument("recordings", metavar="RECORDINGS")
    converter.add_argument("out", metavar="OUT")
    converter.add_argument("--time", choices=TIMES, default="live",
                           help="live (default): time as recorded; refined: placed after "
                           "the fact from each recording and those around it, with "
                           "time_placed and time_bound_ms (as export --time refined; needs "
                           "the gateway's own recordings). A dataset holds one or the other")


def default_directory(args: argparse.Namespace) -> str:
    """The record directory of the gateway's ``--config`` (exit 2 if it records
    nothing), else the gateway's default one."""
    from gateway.daemon.config import ConfigError, default_record_directory, load_config
    config = getattr(args, "config", None)
    if isinstance(config, list):
        config = config[0] if config else None
    if config is None:
        return default_record_directory()
    try:
        loaded = load_config(config)
    except ConfigError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    if loaded.record is None:
        raise CtlError(f"{config} does not record (no record:): name a directory",
                       Exit.USAGE)
    return loaded.record.directory


def run_recordings(args: argparse.Namespace) -> int:
    from gateway.recording.catalogue import catalogue
    from gateway.recording.files import PARTIAL, RecordingError, usable_files
    given = args.paths or [default_directory(args)]
    try:
        paths = usable_files(given)
    except RecordingError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    files = catalogue(paths, read_writing=False)  # (a file being written: its span)
    if args.json:
        print(json_line({"files": [d.json() for d in files]}), flush=True)
    else:
        for line in (line for d in files for line in lines(d)):
            print(line, flush=True)
    return PARTIAL if any(d.damaged for d in files) else Exit.OK


def _when(stamp: int, day: bool = True) -> str:
    return at(stamp, DAY if day else TIME, zone="")


def _length(seconds: float) -> str:
    hours, rest = divmod(round(seconds), 3600)
    return f"{hours} h {rest // 60:02d} min" if hours else f"{rest // 60} min {rest % 60:02d} s"


def lines(d: Described) -> list[str]:
    """A file: a line of its span, size and stations, then its nodes, marks and notes."""
    if d.start is None or d.end is None:
        span = "no messages"
    else:
        start, end = _when(d.start), _when(d.end)
        if end[:10] == start[:10]:  # (the same day, as shown)
            end = _when(d.end, day=False)
        span = f"{start} to {end} UTC ({_length((d.end - d.start) / 1e9)})"
    head = f"{d.path}  {span}  {d.bytes / 1e6:,.1f} MB"
    if d.stations:
        head += f"  stations {', '.join(d.stations)}"
    out = [head]
    for node, records in d.nodes.items():
        out.append(f"    node {node}: " + ", ".join(
            f"{record} {count:,}" for record, count in records.items()))
    out += [f"    mark {_when(m.log_time)}  {m.text}" + "".join(
        f"  {key}={value}" for key, value in m.fields) for m in d.marks]
    notes = [d.problem] if d.problem else []
    if not d.indexed and not d.problem:
        notes.append(d.how)
    notes += [f"same as {p}" for p in d.same_as]
    notes += [f"overlaps {p}" for p in d.overlaps]
    out += [f"    note: {note}" for note in notes]
    return out


__all__ = ["run_recordings"]


def run_trials(args: argparse.Namespace) -> int:
    """``gx2ctl trials``: each trial of the recordings, a few lines each or one JSON
    line; exit 1 if something unreadable was skipped, 2 if no file is a recording or
    the window cannot be taken."""
    from gateway.recording.catalogue import catalogue
    from gateway.recording.files import PARTIAL, RecordingError, usable_files
    from gateway.recording.reports import Reading
    from gateway.recording.trials import trials
    from gateway.recording.window import Asked, WindowError, windows
    given = args.paths or [default_directory(args)]
    try:
        paths = usable_files(given)
    except RecordingError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    files = catalogue(paths)
    within = None
    if args.start or args.stop:
        try:
            within = windows(Asked(args.start, args.stop, None, None, ()), files)[0].span
        except WindowError as error:
            raise CtlError(str(error), Exit.USAGE) from None
    reading = Reading()
    found = trials(files, tuple(args.between), reading, within)
    for line in dict.fromkeys(reading.lines()):  # (a file read for two trials: once)
        print(f"gx2ctl: {line}", file=sys.stderr, flush=True)
    if args.json:
        print(json_line({"trials": [trial.json() for trial in found]}), flush=True)
    elif not found:
        print(f"no trial from a mark {args.between[0]!r} to a mark {args.between[1]!r}",
              flush=True)
    for trial in found if not args.json else ():
        stop = "(open: no mark yet)" if trial.stop_mark is None else (
            f"to {_when(trial.stop_mark.log_time, day=False)} UTC "
            f"({_length((trial.stop_mark.log_time - trial.start_mark.log_time) / 1e9)})")
        given_fields = "".join(f"  {k}={v}" for k, v in trial.start_mark.fields)
        print(f"trial {trial.number}  {_when(trial.start_mark.log_time)} {stop}  "
              f"{trial.rows:,} rows{given_fields}", flush=True)
        for node, records in trial.nodes.items():
            print(f"    node {node}: " + ", ".join(
                f"{record} {count:,}" for record, count in records.items()), flush=True)
        print("    files: " + ", ".join(str(path) for path in trial.files), flush=True)
    return PARTIAL if reading.partial else Exit.OK


def run_dataset(args: argparse.Namespace) -> int:
    """``gx2ctl dataset RECORDINGS OUT``: the recordings not yet converted, converted (a
    line each); exit 1 if something unreadable was skipped, 2 if no file is a recording,
    OUT holds another directory's recordings or pyarrow is missing, 75 (EX_TEMPFAIL) if
    another run is converting into OUT."""
    from gateway.recording.dataset import BUSY, Busy, OtherRecordings, convert
    from gateway.recording.files import PARTIAL, RecordingError, usable_files
    from gateway.recording.parquetfile import MissingExtra
    from gateway.recording.reports import Reading
    reading = Reading()
    try:
        paths = usable_files([args.recordings])
        done = convert(paths, Path(args.out), reading, lambda line: print(line, flush=True),
                       Path(args.recordings), args.time)
    except (RecordingError, MissingExtra, OtherRecordings) as error:
        raise CtlError(str(error), Exit.USAGE) from None
    except Busy as error:
        raise CtlError(str(error), BUSY) from None
    except OSError as error:
        raise CtlError(f"{error.filename or args.out}: {error.strerror or error}",
                       Exit.USAGE) from None
    for line in dict.fromkeys([*reading.lines(), *done.failed, *done.warnings]):
        print(f"gx2ctl: {line}", file=sys.stderr, flush=True)
    writing = f", {len(done.writing)} being written (left for a later run)" \
        if done.writing else ""
    failed = f", {len(done.failed)} not converted (each said why: tried again next run)" \
        if done.failed else ""
    gone = f", {len(done.gone)} gone (deleted while the run ran)" if done.gone else ""
    gone += f", {len(done.same)} the same as one converted (skipped)" if done.same else ""
    print(f"{len(done.files)} converted, {done.current} up to date{writing}{failed}{gone}; "
          f"{done.trials} trials in {Path(args.out) / 'trials.parquet'}", flush=True)
    return PARTIAL if reading.partial or done.failed else Exit.OK
