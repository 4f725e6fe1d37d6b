"""``gx2ctl status`` of several gateways: each is asked at once (one slow or dead
gateway costs the ``--timeout`` once, not once per gateway), and what each answered is
shown together, one table grouped by gateway then station; a gateway that did not
answer is a line saying so where its nodes would be.

Exit status: the worst of the gateways' (0 each answered; 1 one was not all well
with ``--check``, or sent an error; 3 one did not answer), with one line on stderr
naming those that were not all well.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from gateway.common.jsontext import json_line
from gateway.common.protocol import Exit
from gateway.common.reading import as_map

from . import PROG
from .cells import cell, node_maps
from .client import Client, CtlError
from .statusview import (
    Group,
    heading_lines,
    node_table,
    reason_lines,
    station_maps,
    terminal_width,
    unhealthy,
)
from .where import Gateway


@dataclass(frozen=True)
class Answer:
    """What one gateway answered to ``status``, or why it did not."""

    gateway: Gateway
    result: Mapping[str, Any] | None
    error: CtlError | None = None

    def json(self) -> dict[str, Any]:
        """Its entry in ``{"gateways": [...]}``: the status as one gateway gives it,
        its ``name`` and ``control`` endpoint, and ``error`` (null, or why it is
        missing)."""
        return {**(self.result or {}), "name": self.gateway.name,
                "control": self.gateway.where.control,
                "error": None if self.error is None else str(self.error)}


def ask(gateway: Gateway, timeout: float) -> Answer:
    try:
        with Client(gateway.where.control, timeout, gateway.where.keys) as client:
            return Answer(gateway, client.call("status"))
    except CtlError as error:
        return Answer(gateway, None, error)


def ask_all(named: Sequence[Gateway], timeout: float) -> list[Answer]:
    """Every gateway's answer, asked side by side, in the order given."""
    with ThreadPoolExecutor(max_workers=len(named)) as pool:
        return list(pool.map(lambda gateway: ask(gateway, timeout), named))


def status_lines(answers: Sequence[Answer], now: float, width: int | None) -> list[str]:
    """Each gateway's lines (those above a one-gateway table, under ``== NAME``), then
    one table of every node, grouped by gateway and by station, then why each node
    that is not OK is not."""
    lines: list[str] = []
    groups = []
    for answer in answers:
        title = f"== {answer.gateway.name}"
        if answer.result is None:
            missing = f"{title}: {answer.error}"
            lines.append(missing)
            groups.append(Group(missing, []))
            continue
        lines += [title, *heading_lines(answer.result, now, width)]
        stations = station_maps(answer.result)
        groups.append(Group(title, node_maps(answer.result),
                            stations if len(stations) > 1 else []))
    lines += ["", *node_table(groups, now, width)]
    for answer in answers:
        if answer.result is not None:
            lines += reason_lines(node_maps(answer.result), width,
                                  f"{answer.gateway.name}/")
    return lines


def verdict(answers: Sequence[Answer], check: bool) -> tuple[int, str | None]:
    """The exit status (the worst gateway's) and the line saying why it is not 0."""
    worst, problems = int(Exit.OK), []
    for answer in answers:
        name = answer.gateway.name
        if answer.error is not None:
            worst = max(worst, int(answer.error.status))
            problems.append(f"{name}: {answer.error}")
        elif check and (why := unhealthy(as_map(answer.result))):
            worst = max(worst, int(Exit.NODE_FAILED))
            problems.append(f"{name}: {why}")
    if not problems:
        return worst, None
    return worst, (f"{len(problems)} of {len(answers)} gateways "
                   f"{'not all well' if check else 'did not answer'}: "
                   + "; ".join(problems))


def run_status(named: Sequence[Gateway], timeout: float, as_json: bool, check: bool,
               wide: bool) -> int:
    answers = ask_all(named, timeout)
    if as_json:
        print(json_line({"gateways": [answer.json() for answer in answers]}))
    else:
        print("\n".join(status_lines(answers, time.time(), terminal_width(wide))))
    sys.stdout.flush()
    status, why = verdict(answers, check)
    if why:
        print(f"{PROG}: {cell(why)}", file=sys.stderr, flush=True)
    return status
