"""The trials the marks define (``gx2ctl trials``): each from a mark START to the next
mark STOP, numbered as ``--between-marks START STOP --trial N`` numbers them
(:func:`.window.trials`), with the trial still open last (its STOP not yet marked: a
recording being made), each with its start mark's fields, the rows of each node and
record in it, and the files it spans."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gateway.common.topics import parse

from .catalogue import Described, Marked
from .reports import Reading
from .window import Reader, Span, Window, _marks, touched

OPEN = 2 ** 64
"""Where a trial not yet closed ends: after anything recorded."""


@dataclass
class Trial:
    number: int
    start_mark: Marked
    stop_mark: Marked | None
    """None: not yet marked (the trial is still open)."""
    nodes: dict[int, dict[str, int]] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)

    @property
    def span(self) -> Span:
        """Its log_time: from its start mark to just after its stop mark."""
        stop = OPEN if self.stop_mark is None else self.stop_mark.log_time + 1
        return (self.start_mark.log_time, stop)

    @property
    def start(self) -> float:
        return self.start_mark.log_time / 1e9

    @property
    def stop(self) -> float | None:
        return None if self.stop_mark is None else self.stop_mark.log_time / 1e9

    @property
    def rows(self) -> int:
        return sum(count for records in self.nodes.values() for count in records.values())

    def json(self) -> dict[str, Any]:
        return {"trial": self.number, "start": self.start, "stop": self.stop,
                "start_mark": self.start_mark.text,
                "stop_mark": None if self.stop_mark is None else self.stop_mark.text,
                "fields": dict(self.start_mark.fields),
                "nodes": {str(node): records for node, records in sorted(self.nodes.items())},
                "files": [str(path) for path in self.files]}


def listed(between: tuple[str, str], marks: list[Marked]) -> list[Trial]:
    """The trials of ``marks`` (in time order), as :func:`.window.trials` finds them,
    and the one still open after them, if any."""
    start, stop = between
    found: list[Trial] = []
    opened: Marked | None = None
    for mark in marks:
        if mark.text == start and opened is None:
            opened = mark
        elif mark.text == stop and opened is not None:
            found.append(Trial(len(found) + 1, opened, mark))
            opened = None
    if opened is not None:
        found.append(Trial(len(found) + 1, opened, None))
    return found


def trials(files: list[Described], between: tuple[str, str], reading: Reading,
           within: Span | None = None) -> list[Trial]:
    """The trials of the catalogued ``files`` (their marks read whole), those that
    start in ``within`` if given, each counted: its rows (a message met twice, once)
    and its files."""
    chosen = [t for t in listed(between, _marks(files))
              if within is None or within[0] <= t.span[0] < within[1]]
    reader = Reader(files, reading)
    for trial in chosen:
        window = Window(trial.span)
        trial.files = [d.path for d in touched(files, window) if d.start is not None]
        for block in reader.blocks(window):
            for channel, count in Counter(block.channel).items():
                where = parse(block.topics[channel])
                if where is not None:
                    records = trial.nodes.setdefault(where[0], {})
                    records[where[1]] = records.get(where[1], 0) + count
        trial.nodes = {node: dict(sorted(records.items()))
                       for node, records in sorted(trial.nodes.items())}
    return chosen
